"""Issue 9, smaller things a user meets: an output directory that does not exist, and a
--lat/--lon whose magnetic field disagrees with the one measured."""
import datetime
from pathlib import Path

import numpy as np
import pytest

from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "ferraris.tlog"


def never_called(*args, **kwargs):
    raise AssertionError("should have been refused before this")


def test_missing_param_file_directory_stops_everything_before_work(tmp_path, capsys,
                                                                   monkeypatch):
    """Refused before reading (or recording): the user loses no work, and is told that the JSON
    was not written either (the README says so)."""
    import apmcal.sources

    monkeypatch.setattr(apmcal.sources, "read_log", never_called)
    param_file = tmp_path / "missing" / "new.param"
    json_file = tmp_path / "result.json"
    assert main(["log", str(SAMPLE), "--param-file", str(param_file), "--json", str(json_file),
                 "--quiet"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1
    assert str(param_file) in err[0] and "does not exist" in err[0]
    assert "nothing written" in err[0]
    assert not json_file.exists() and not param_file.parent.exists()


def test_readme_says_what_the_code_does_with_a_missing_output_directory():
    # the README's details live in the user guide
    readme = " ".join((ROOT / "docs" / "guide.md").read_text().split())     # lines joined
    assert "`--json` is written even when `--param-file` fails (" not in readme
    assert "before any reading or recording" in readme


def sphere_samples(radius_mgauss: float, n: int = 600, seed: int = 4) -> np.ndarray:
    """A compass turned through every direction of a field of ``radius_mgauss``, hard iron
    (120, -40, 60) mGauss, 1 mGauss noise."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return radius_mgauss * directions + [120.0, -40.0, 60.0] + rng.normal(0, 1.0, (n, 3))


@pytest.mark.parametrize("measured_over_wmm, warned", [(1.15, False),
                                                       (0.6, True), (1.5, True)])
def test_a_site_whose_field_disagrees_with_the_measured_one_is_warned(measured_over_wmm,
                                                                       warned):
    from apmcal.core.geomag import decimal_year, earth_field_ned
    from apmcal.solvers.magnetometer import calibrate_magnetometer

    lat, lon, when = 5.6037, -0.187, datetime.date(2026, 5, 28)
    wmm = float(np.linalg.norm(earth_field_ned(lat, lon, 0.0, decimal_year(when))[0]))
    fit = calibrate_magnetometer(sphere_samples(measured_over_wmm * wmm), lat, lon, when)
    found = [w for w in fit.warnings if "World Magnetic Model" in w]
    assert bool(found) == warned, fit.warnings
    if warned:
        assert f"{wmm:.0f} mGauss" in found[0] and "--lat/--lon" in found[0]
        assert f"{100 * abs(measured_over_wmm - 1):.0f} % apart" in found[0]
