"""``apmcal gap REAL --twin-log TWIN``: the same session recorded again by a simulator set up as
the board's twin takes the simulated twin's place, and the diagnosis says what is left
between the board and that recording. And ``apmcal gap`` on a session too short for the slow
effects says so instead of "nothing to add" (issue 37, finding 7).

Simulated sessions here (the bundled simulator, cheap); ArduPilot's own firmware in
tests/test_gap_firmware.py.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from apmcal.cli import main
from apmcal.core.errors import ApmcalError

ROOT = Path(__file__).resolve().parents[1]


def makelog(out: Path, seconds: float, seed: int, truth: Path | None = None,
            script: str = "warmup", extra=()) -> Path:
    cmd = [sys.executable, "-m", "apmcal_sim.makelog", "--script", script, "--out", str(out),
           "--rate", "25", "--fs", "25", "--duration", str(seconds), "--seed", str(seed),
           *extra]
    if truth is not None:
        cmd += ["--truth", str(truth)]
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=300, capture_output=True)
    return out


@pytest.fixture(scope="module")
def warmups(tmp_path_factory):
    """A warming board (nominal errors and a temperature drift), recorded twice with other
    noise draws (the recorded twin of an exact simulator), and once more without the drift."""
    from apmcal.sensor_model.truth import NOMINAL_EFFECTS, Truth

    out = tmp_path_factory.mktemp("twinlog")
    truth = Truth.random(4).with_effects(disable=["all"],
                                         enable=list(NOMINAL_EFFECTS) + ["temperature_drift"],
                                         prefer="diagnosis")
    truth.save(out / "truth.json")
    flat = truth.with_effects(disable=["temperature_drift"], prefer="diagnosis")
    flat.save(out / "flat.json")
    real = makelog(out / "real.bin", 300, 1, out / "truth.json")
    twin = makelog(out / "twin.bin", 300, 2, out / "truth.json")
    lacking = makelog(out / "lacking.bin", 300, 2, out / "flat.json")
    return out, real, twin, lacking


def gap_json(out: Path, name: str, *argv) -> dict:
    path = out / f"{name}.json"
    assert main(["gap", *map(str, argv), "--json", str(path), "--quiet"]) == 0
    return json.loads(path.read_text())


def test_a_twin_of_the_same_process_leaves_nothing(warmups):
    out, real, twin, _ = warmups
    result = gap_json(out, "same", real, "--twin-log", twin)
    assert result["session"]["twin_log"] == str(twin)
    assert result["selected"] == []
    assert not any(e["significant"] for e in result["effects"])
    assert abs(result["gap"]["heldout"]) < 0.05


def test_a_twin_without_the_drift_shows_it(warmups):
    """The recording lacks the board's temperature drift: that is what is left, with the
    board's coefficients (the twin's own fit takes none)."""
    from apmcal.sensor_model.truth import Truth

    out, real, _, lacking = warmups
    truth = Truth.load(out / "truth.json")
    result = gap_json(out, "lacking", real, "--twin-log", lacking)
    assert result["selected"] == ["temperature_drift"]
    # a gap hundreds of times the one between two recordings of one process, closed by it
    assert result["gap"]["heldout"] > 0.1 and abs(result["after"]["heldout"]) < 0.01
    coef = result["effects"][0]["params"]["gyro_coef"]
    z = (np.array(coef["value"]) - truth.temperature["gyro_coef"]) / np.array(coef["sigma"])
    assert np.all(np.abs(z) < 3), z


def test_a_twin_that_does_not_fit_the_log_is_refused(warmups, tmp_path):
    from apmcal.core.options import Options
    from apmcal.diagnosis.reading import LogReading
    from apmcal.diagnosis.session.twin_log import on_samples_of

    out, real, twin, _ = warmups
    short = makelog(tmp_path / "short.bin", 120, 2, out / "truth.json")
    slow = makelog(tmp_path / "slow.bin", 300, 2, out / "truth.json", extra=["--rate", "10",
                                                                             "--fs", "10"])
    tlog = makelog(tmp_path / "twin.tlog", 300, 2, out / "truth.json")
    session = LogReading(str(real), Options()).session()[0]
    for path, why in ((short, "covers 1"), (slow, "runs at 10"), (tlog, "as integers")):
        other = LogReading(str(path), Options()).session()[0]
        with pytest.raises(ApmcalError, match=why):
            on_samples_of(session, other, str(path))
    done = subprocess.run([sys.executable, "-m", "apmcal", "gap", str(real), "--twin-log",
                           str(short)], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "short.bin" in done.stderr


@pytest.mark.parametrize("seconds, why", [(6, "s of data"), (100, "still piece")])
def test_a_session_too_short_for_the_slow_effects_says_so(tmp_path, seconds, why):
    """Before, a 6-s log was answered "Nothing to add: the simulator matches this board" from
    one hold; the drifts and the random walk need a minute and three still pieces in each half
    (their evidence, and their null sessions', lies across pieces)."""
    from rich.console import Console

    from apmcal.diagnosis.output.advice import NOTHING, SHORT
    from apmcal.diagnosis.output.result import GapResult
    from apmcal.diagnosis.output.summary import print_summary

    log = makelog(tmp_path / "short.bin", seconds, 3, script="onepos",
                  extra=["--disable", "all", "--enable", "nominal"])
    result = gap_json(tmp_path, "short", log)
    short = [e["name"] for e in result["effects"]
             if str(e["not_tested"] or "").startswith("too short")]
    assert {"bias_drift", "triangle_drift", "bias_random_walk"} <= set(short)
    assert any(why in str(e["not_tested"]) for e in result["effects"])
    console = Console(record=True, width=300)
    print_summary(GapResult.load(tmp_path / "short.json"), console)
    first = console.export_text().splitlines()[0]
    assert first.startswith(SHORT) and not first.startswith(NOTHING)


def test_a_still_twin_recorded_longer_is_not_stretched():
    """One still hold from a little after boot to the log's end, the twin recorded 5 s longer
    (as the round trip records it): the hold's end is where each recording stopped, not the
    script's, so the times are not warped (as that end's knot, it stretched the board's
    240 s onto the twin's 245 s and put the board's first samples before the twin's start:
    "the twin log covers 243 s ... record the whole session again" on 3 of 5 SITL warm-ups)."""
    from types import SimpleNamespace

    from apmcal.diagnosis.session.twin_log import twin_times

    def still(seconds: float, hold_from: float):
        t = 2.5 + np.arange(0.0, seconds, 0.04)
        hold = SimpleNamespace(i0=int(np.searchsorted(t, hold_from)), i1=len(t))
        return SimpleNamespace(t=t, holds=[hold])

    real, twin = still(236.0, 9.1), still(243.0, 8.8)
    np.testing.assert_array_equal(twin_times(real, twin), real.t - real.t[0])
