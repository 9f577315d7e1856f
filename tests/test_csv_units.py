"""A CSV file's units: declared in the header (acc_x[g], gyr_x[deg/s], mag_x[uT], [counts]),
or recognised and refused with the fix when they are not m/s², rad/s, mGauss; absurd samples
dropped and counted without changing the method."""
from pathlib import Path

import numpy as np
import pytest

from apmcal.core.errors import ApmcalError
from apmcal.report.session import calibrate
from apmcal.sources import read_log
from apmcal.sources.csv import read_csv
from apmcal.sources.units import require_plausible_units

SAMPLE = Path(__file__).resolve().parents[1] / "logs" / "ferraris.tlog"
G = 9.80665


@pytest.fixture(scope="module")
def session():
    """The bundled six-face session (acc m/s², gyr rad/s, mag mGauss) as plain columns."""
    rec = read_log(SAMPLE).recordings[0]
    return rec.data[["t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z",
                     "mag_x", "mag_y", "mag_z"]].copy()


def write(tmp_path, data, names, name="s.csv"):
    out = data.copy()
    out.columns = names
    path = tmp_path / name
    out.to_csv(path, index=False)
    return path


def names(acc="", gyr="", mag=""):
    return (["t"] + [f"acc_{a}{acc}" for a in "xyz"] + [f"gyr_{a}{gyr}" for a in "xyz"]
            + [f"mag_{a}{mag}" for a in "xyz"])


@pytest.mark.parametrize("sensor, factor, hint", [
    ("acc", 1 / G, "acc_x[g]"),
    ("acc", 16384 / G, "acc_x[counts]"),
    ("gyr", np.degrees(1.0), "gyr_x[deg/s]"),
    ("mag", 0.1, "mag_x[uT]"),
])
def test_undeclared_units_are_refused_with_the_fix(tmp_path, session, sensor, factor, hint):
    data = session.copy()
    cols = [f"{sensor}_{a}" for a in "xyz"]
    data[cols] = data[cols] * factor
    path = write(tmp_path, data, names())
    contents = read_csv(path)
    with pytest.raises(ApmcalError) as err:
        require_plausible_units(contents)
    assert hint in str(err.value) and str(path) in str(err.value)


def test_si_units_pass(tmp_path, session):
    require_plausible_units(read_csv(write(tmp_path, session, names())))


def test_units_declared_in_the_header_are_converted_and_graded_as_si(tmp_path, session):
    """acc in g, gyro in deg/s, compass in µT, declared: the same calibration as in SI."""
    data = session.copy()
    data[["acc_x", "acc_y", "acc_z"]] /= G
    data[["gyr_x", "gyr_y", "gyr_z"]] = np.degrees(data[["gyr_x", "gyr_y", "gyr_z"]])
    data[["mag_x", "mag_y", "mag_z"]] *= 0.1
    declared = read_csv(write(tmp_path, data, names("[g]", "[deg/s]", "[uT]")))
    si = read_csv(write(tmp_path, session, names(), "si.csv"))
    for sensor in ("acc", "gyr", "mag"):
        np.testing.assert_allclose(declared.recordings[0].xyz(sensor), si.recordings[0].xyz(sensor),
                                   rtol=1e-6, atol=1e-6)
    report = calibrate(declared)
    assert report.calibration.method == "ferraris"
    np.testing.assert_allclose(report.calibration.sensors["acc"].offset,
                               calibrate(si).calibration.sensors["acc"].offset, atol=1e-4)


def test_counts_declared_in_the_header_are_not_refused(tmp_path, session):
    data = session.copy()
    data[["acc_x", "acc_y", "acc_z"]] *= 16384 / G
    contents = read_csv(write(tmp_path, data, names("[counts]")))
    require_plausible_units(contents)
    assert any("raw sensor counts" in m for m in contents.messages)


def test_axes_with_different_units_are_refused(tmp_path, session):
    cols = names()
    cols[1] = "acc_x[g]"
    with pytest.raises(ApmcalError, match="different units"):
        read_csv(write(tmp_path, session, cols))


def test_one_absurd_sample_is_dropped_counted_and_changes_nothing(tmp_path, session):
    """One 1e308 in the accelerometer: dropped and said, the method stays six-face."""
    data = session.copy()
    data.loc[len(data) // 2, "acc_x"] = 1e308
    report = calibrate(read_csv(write(tmp_path, data, names())))
    assert report.calibration.method == "ferraris"
    assert any("1 absurd" in w for w in report.calibration.report.warnings), \
        report.calibration.report.warnings
