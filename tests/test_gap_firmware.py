"""``apmcal gap`` on logs of ArduPilot's own firmware (SITL 4.7, ``../shared/ardupilot-sitl``),
recorded in the run with known SIM_* injections, through its telemetry log (RAW_IMU: int16
mG / mrad/s truncated toward zero) and its dataflash log (IMU: floats) alike.

- SITL's default gyro drift, held still: the triangle, alone among the slow effects (before:
  the .tlog's staircase — 0-4.4 mrad/s of drift, noise a twenty-fifth of a step — chose the
  temperature polynomial: its level-1 histogram was binned at the models' sub-step offsets).
- A warm-up with SIM_IMUT1_* coefficients and no drift: the temperature drift, with the
  injected coefficients (within 3σ from the dataflash floats).
- Both at once: both (a random walk bends to their sum; before, it was chosen instead).
- SIM_GYR1_RND (which SITL adds only while the motors turn: a quad armed on the ground) with
  the firmware's filters off: uniform noise, from the dataflash log at the loop rate.
- The twin's round trip: the warm-up's twin written as SIM_* parameters, SITL booted with
  them records the session again, and the warm-up diagnosed against that recording leaves no
  effect and no gap (docs/sitl-twin.md; three more configurations in
  benchmarks/gap_sitl_roundtrip.py).

Claims that hold on fewer than ten of ten fresh recordings are marked as known failures with
their measured rate (``known_failure``; docs/gap-trust.md), each beside a test of the part that
holds on all ten.

The sessions are as short as their effects allow: the triangle turns 5 min after boot, and the
.tlog needs two minutes of its fall (its fit of the truncated staircase is biased: the speed
comes out about 12 % high, and with one minute the temperature curve fitted as well).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from firmware_sessions import known_failure

from apmcal.cli import main
from apmcal.diagnosis.output.result import GapResult
from apmcal.diagnosis.session.decimate import FINE_EFFECTS

pytestmark = pytest.mark.ardupilot_sitl

TEMPERATURE = {"SIM_IMUT1_ENABLE": 1, "SIM_IMUT1_TMIN": -10, "SIM_IMUT1_TMAX": 80,
               "SIM_IMUT_TCONST": 100,
               # 1e-6 rad/s and 1e-6 m/s² per K about (TMIN + TMAX)/2: docs/ardupilot-facts.md
               "SIM_IMUT1_GYR1_X": 300, "SIM_IMUT1_GYR1_Y": -200, "SIM_IMUT1_GYR1_Z": 150,
               "SIM_IMUT1_ACC1_X": 3000, "SIM_IMUT1_ACC1_Y": -2000, "SIM_IMUT1_ACC1_Z": 4000}
GYRO_COEF = np.array([300, -200, 150]) * 1e-6       # rad/s per K
ACC_COEF = np.array([3000, -2000, 4000]) * 1e-6     # m/s² per K
DRIFT_SPEED = 0.05                                  # SIM_DRIFT_SPEED's default [°/s per min]
IMU_FAST = 180222 + (1 << 18)       # Copter's default LOG_BITMASK with IMU_FAST: IMU at 400 Hz
SESSIONS = {
    "drift": dict(until=420),
    "warmup": dict(until=240, boot=dict(TEMPERATURE, SIM_DRIFT_SPEED=0)),
    "both": dict(until=400, boot=TEMPERATURE),
    "uniform": dict(until=120, model="quad", motors=True, telemetry_hz=100,
                    boot={"SIM_GYR1_RND": 20, "INS_GYRO_FILTER": 0, "INS_ACCEL_FILTER": 0,
                          "INS_FAST_SAMPLE": 0, "SIM_DRIFT_SPEED": 0, "LOG_BITMASK": IMU_FAST}),
}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """``diagnosed(session, kind)``: the GapResult of ``apmcal gap`` on that session's
    "tlog" or "bin" (each session recorded once, on first use)."""
    from ardupilot_sitl import unavailable_reason

    reason = unavailable_reason()
    if reason:
        pytest.skip(reason)
    from gap_sitl_sessions import record

    root = tmp_path_factory.mktemp("firmware")
    logs, results = {}, {}

    def log(name: str, kind: str) -> Path:
        if name not in logs:
            spec = dict(SESSIONS[name])
            until = spec.pop("until")
            logs[name] = record(root / name, [("until", until)], spec.pop("boot", None), **spec)
        return logs[name].tlog if kind == "tlog" else logs[name].bin

    def get(name: str, kind: str) -> GapResult:
        if (name, kind) not in results:
            path = root / f"{name}-{kind}.json"
            assert main(["gap", str(log(name, kind)), "--json", str(path), "--quiet",
                         "--write-twin", str(root / f"{name}-{kind}.parm")]) == 0
            results[(name, kind)] = GapResult.load(path)
        return results[(name, kind)]

    get.log, get.root = log, root
    return get


def slow(result: GapResult) -> set:
    return set(result.selected) - set(FINE_EFFECTS)


def z_scores(entry: dict, key: str, truth) -> np.ndarray:
    p = entry["params"][key]
    return (np.asarray(p["value"], float) - truth) / np.asarray(p["sigma"], float)


def tlog_known_failure(rate: str, why: str) -> list:
    """Both logs, the .tlog's claim a :func:`known_failure` (its int16 staircase)."""
    return [pytest.param("tlog", marks=known_failure(rate, why)), "bin"]


WALK_JOINS = known_failure("6-7 of 10", "a random walk of q ≈ 0 joins on the dataflash log, by "
                                        "the white level it lowers (fix measured, not merged)")


@pytest.mark.parametrize("kind", tlog_known_failure(
    "0 of 11 test runs", "the two folds place the turn on the staircase's flat top differently "
                         "and the temperature curve wins (docs/gap-trust.md)"))
def test_sitl_default_drift_is_the_triangle(diagnosed, kind):
    """The triangle, not the temperature curve (which the .tlog's staircase once chose), at
    SITL's speed and period."""
    result = diagnosed("drift", kind)
    assert "triangle_drift" in result.selected, result.selected
    assert not slow(result) & {"temperature_drift", "bias_drift"}, result.selected
    speed = result.effect("triangle_drift")["params"]["speed"]
    assert result.effect("triangle_drift")["params"]["drift_time"]["value"] == 5.0
    if kind == "bin":
        assert abs(speed["value"] - DRIFT_SPEED) < 3 * speed["sigma"], speed
    else:   # a fit of the truncated staircase: biased, see docs/gap-trust.md
        assert abs(speed["value"] - DRIFT_SPEED) < 0.2 * DRIFT_SPEED, speed


@WALK_JOINS
def test_sitl_default_drift_is_the_triangle_alone(diagnosed):
    result = diagnosed("drift", "bin")
    assert slow(result) == {"triangle_drift"}, result.selected


@pytest.mark.parametrize("kind", ["tlog", "bin"])
def test_a_warm_up_without_drift_is_the_temperature_drift(diagnosed, kind):
    result = diagnosed("warmup", kind)
    assert "temperature_drift" in result.selected, result.selected
    assert not slow(result) & {"triangle_drift", "bias_drift"}, result.selected
    if kind == "tlog":
        assert slow(result) == {"temperature_drift"}, result.selected
    entry = result.effect("temperature_drift")
    if kind == "bin":
        assert np.all(np.abs(z_scores(entry, "gyro_coef", GYRO_COEF)) < 3)
        assert np.all(np.abs(z_scores(entry, "acc_coef", ACC_COEF)) < 3)
    else:
        gyro = np.asarray(entry["params"]["gyro_coef"]["value"])
        acc = np.asarray(entry["params"]["acc_coef"]["value"])
        np.testing.assert_allclose(gyro, GYRO_COEF, rtol=0.2)
        np.testing.assert_allclose(acc, ACC_COEF, rtol=0.2)


@known_failure("10 of 10 benchmark", "on two test runs' (2026-11-29) the random walk of q ≈ 0 "
                                     "joined, as on the other dataflash logs (WALK_JOINS)")
def test_a_warm_up_without_drift_is_the_temperature_drift_alone(diagnosed):
    result = diagnosed("warmup", "bin")
    assert slow(result) == {"temperature_drift"}, result.selected


@pytest.mark.parametrize("kind", tlog_known_failure(
    "0 of 10 (2 of 6 test runs)", "on the staircase the triangle is not beyond chance on top "
                                  "of the temperature unless the .tlog starts near boot"))
def test_a_warm_up_under_the_drift_is_both(diagnosed, kind):
    result = diagnosed("both", kind)
    assert {"temperature_drift", "triangle_drift"} <= slow(result), result.selected
    if kind == "bin":
        entry = result.effect("temperature_drift")
        assert np.all(np.abs(z_scores(entry, "gyro_coef", GYRO_COEF)) < 3)
        assert np.all(np.abs(z_scores(entry, "acc_coef", ACC_COEF)) < 3)
        speed = result.effect("triangle_drift")["params"]["speed"]
        assert abs(speed["value"] - DRIFT_SPEED) < 3 * speed["sigma"], speed


@WALK_JOINS
def test_a_warm_up_under_the_drift_is_both_alone(diagnosed):
    result = diagnosed("both", "bin")
    assert slow(result) == {"temperature_drift", "triangle_drift"}, result.selected


def test_sitl_motor_noise_is_uniform(diagnosed):
    result = diagnosed("uniform", "bin")
    assert "uniform_noise" in result.selected, result.selected
    assert slow(result) == set(), result.selected


def test_the_twin_round_trip_through_sitl_closes(diagnosed):
    """--write-twin x.parm, SITL booted with it records the same warm-up, and the warm-up
    against that recording: nothing left, and no more gap than the diagnosis promised."""
    from gap_sitl_sessions import record

    from apmcal.ardupilot.paramfile import read_param_file

    result = diagnosed("warmup", "bin")
    values = read_param_file(diagnosed.root / "warmup-bin.parm")
    assert values["SIM_IMUT1_ENABLE"] == 1 and values["SIM_DRIFT_SPEED"] == 0
    np.testing.assert_allclose([values[f"SIM_IMUT1_GYR1_{a}"] for a in "XYZ"],
                               GYRO_COEF * 1e6, rtol=0.02)
    twin = record(diagnosed.root / "warmup-twin",
                  [("until", SESSIONS["warmup"]["until"] + 5)], values)
    out = diagnosed.root / "roundtrip.json"
    assert main(["gap", str(diagnosed.log("warmup", "bin")), "--twin-log", str(twin.bin),
                 "--json", str(out), "--quiet"]) == 0
    again = GapResult.load(out)
    assert again.selected == [] and not any(e["significant"] for e in again.effects)
    assert result.gap["heldout"] > 10     # the board against the simulator before ...
    assert again.gap["heldout"] < max(result.after["heldout"], 0.0) + 0.05   # ... against
