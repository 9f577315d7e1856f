"""Finite numbers on integer telemetry, and the answer in words first.

A warm-up at rest logged as ArduPilot's RAW_IMU (int16 mG, mrad/s, mGauss, truncated toward
zero) whose gyro noise is far below the 1 mrad/s step: most gyro readings never change, so the
twin's cells can have no variance at all. Before the variance floors the result held a held-out
gap of 2070 nats/sample for one candidate (1e+293 on ArduPilot SITL's own telemetry). The
board's one effect besides the nominal model and SITL's uniform noise is a temperature drift,
so the summary must open with what to do about it.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from apmcal.cli import main
from apmcal.diagnosis.output.advice import NOTHING, advice
from apmcal.diagnosis.output.result import GapResult
from apmcal.diagnosis.output.summary import print_summary
from apmcal.diagnosis.scoring.gap import expected_variance_kl, shape_shares, variance_shares
from apmcal.diagnosis.twin.simulate import truncated_reading

ROOT = Path(__file__).resolve().parents[1]


def test_truncated_reading_is_the_log_format_then_its_undoing():
    step = 0.001
    x = np.array([0.0004, -0.0004, 0.0017, -0.0017, 0.0020001, 40.0])
    # trunc: 0, 0, 1, -1, 2, 32767 (saturated) counts; then half a step away from zero
    want = np.array([0.0, 0.0, 0.0015, -0.0015, 0.0025, 32767.5 * step])
    np.testing.assert_allclose(truncated_reading(x, step), want, rtol=0, atol=1e-15)


def test_a_twin_cell_without_variance_costs_a_bounded_amount():
    rng = np.random.default_rng(5)
    real = rng.standard_normal(500) * 1e-4       # below the 1e-3 step: the rounding's own
    twin = np.zeros(500)                          # the twin's reading never changed
    floor = 1e-3 ** 2 / 12
    share, v_r, v_t = variance_shares(real, twin, floor=floor)
    assert np.all(share == 0) and v_r == v_t == floor      # neither resolvable: no information
    real = rng.standard_normal(500) * 1e-2        # ten steps: a real difference
    share, v_r, v_t = variance_shares(real, twin, floor=floor)
    x = v_r / v_t                                 # the floored KL, hand-worked
    assert v_t == floor and v_r == pytest.approx(np.mean(real ** 2))
    assert share.sum() == pytest.approx(0.5 * 500 * (x - 1 - np.log(x))
                                        - expected_variance_kl(500, 500, 500))
    assert np.isfinite(share).all() and share.sum() / 500 < 1e3
    # without the floor the same cell is the overflow the floors are there for
    assert variance_shares(real, twin)[0].sum() > 1e290
    shares = shape_shares(np.round(real / 1e-3) * 1e-3, twin, floor)
    assert np.isfinite(shares).all() and np.max(shares) < 10


def _numbers(x, path=""):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _numbers(v, f"{path}/{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(x, (int, float)) and not isinstance(x, bool):
        yield path, float(x)


@pytest.fixture(scope="module")
def warmup(tmp_path_factory):
    from apmcal.sensor_model.truth import NOMINAL_EFFECTS, Truth

    out = tmp_path_factory.mktemp("int16")
    truth = Truth.random(3).with_effects(
        disable=["all"], enable=list(NOMINAL_EFFECTS) + ["temperature_drift", "uniform_noise"],
        prefer="diagnosis")
    truth.gyro_noise, truth.acc_noise = 2e-6, 2e-4     # gyro σ 4.5 µrad/s: far below 1 mrad/s
    truth.save(out / "truth.json")
    log = out / "warmup.tlog"
    subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", "warmup", "--out",
                    str(log), "--rate", "10", "--duration", "600", "--seed", "3", "--truth",
                    str(out / "truth.json")], check=True, cwd=ROOT, timeout=300)
    assert main(["gap", str(log), "--json", str(out / "gap.json"), "--quiet",
                 "--write-twin", str(out / "twin.parm")]) == 0
    return truth, GapResult.load(out / "gap.json"), json.loads((out / "gap.json").read_text()), out


def test_every_figure_is_finite_and_per_sample_gaps_are_small(warmup):
    _, _, data, _ = warmup
    numbers = list(_numbers(data))
    assert numbers and all(math.isfinite(v) for _, v in numbers)
    per_sample = [(p, v) for p, v in numbers
                  if p.split("/")[-1] in ("total", "heldout", "gap_heldout", "gap_in_sample")
                  or "/breakdown" in p]
    assert len(per_sample) > 20
    assert max(abs(v) for _, v in per_sample) < 1e3, max(per_sample, key=lambda pv: abs(pv[1]))
    ratios = data["gap"]["noise_ratio_heldout"]
    assert set(ratios) == {"acc", "gyr", "mag"}
    assert all(0 < r < 1e6 for bands in ratios.values() for r in bands.values())


def test_the_temperature_drift_is_found_and_the_summary_opens_with_its_action(warmup):
    truth, result, _, _ = warmup
    assert result.selected[0] == "temperature_drift"
    console = Console(record=True, width=300)
    print_summary(result, console)
    first = console.export_text().splitlines()[0]
    assert first.startswith("Calibrate the temperature drift with `apmcal tcal` on a warm-up log")
    # the evidence in physical units: the fitted gyro coefficients in mrad/s per °C and the
    # temperature span, which the injected ones (0.17 mrad/s per °C on x) must match in size
    coef = np.array(result.effect("temperature_drift")["params"]["gyro_coef"]["value"])
    assert abs(coef[0] * 1e3 - truth.temperature["gyro_coef"][0] * 1e3) < 0.03
    assert f"gyro x {coef[0] * 1e3:.2g}" in first and "mrad/s per °C" in first
    lo, hi = result.session["temperature_c"]
    assert f"over {lo:.0f}-{hi:.0f} °C" in first
    assert "simulator: temperature_drift" in first


def test_nothing_selected_says_the_simulator_matches():
    result = GapResult("x.bin", {"duration_s": 100.0, "rate_hz": 50.0, "holds": 6, "moves": 5,
                                 "orientations": 6, "sensors": ["acc", "gyr"]},
                       {"total": 0.001, "heldout": -0.002, "breakdown_heldout": {}},
                       [], [], {"total": 0.001, "heldout": -0.002})
    assert advice(result)[0].startswith(NOTHING)
    console = Console(record=True, width=300)
    print_summary(result, console)
    assert console.export_text().splitlines()[0].startswith(NOTHING)


def test_the_sitl_twin_file_carries_the_fitted_temperature_drift(warmup):
    """--write-twin x.parm end to end: SIM_IMUT1_* from the fitted coefficients, the warm-up
    curve from the log, no drift, and no compass lines (one orientation fits no geometry)."""
    from apmcal.ardupilot.paramfile import read_param_file

    _, result, _, out = warmup
    values = read_param_file(out / "twin.parm")
    assert values["SIM_IMUT1_ENABLE"] == 1 and values["SIM_DRIFT_SPEED"] == 0
    coef = np.array(result.effect("temperature_drift")["params"]["gyro_coef"]["value"])
    fitted = np.array([values[f"SIM_IMUT1_GYR1_{a}"] for a in "XYZ"]) / 1e6
    np.testing.assert_allclose(fitted, coef, rtol=0.05, atol=2e-6)   # refitted on every piece
    lo, hi = result.session["temperature_c"]
    assert abs(values["SIM_IMUT_START"] - lo) < 1.0 and abs(values["SIM_IMUT_END"] - hi) < 2.0
    assert not any(name.startswith("SIM_MAG") for name in values)
