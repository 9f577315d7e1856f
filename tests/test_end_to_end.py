"""End to end: simulated sessions with known truth through `apmcal log`, compared with the truth.

The simulator (sitl/) writes a log and the errors it injected; apmcal reads the log, undoes the
firmware correction, calibrates, and must land within its own reported uncertainty of the truth.
Effects the methods do not model (temperature warm-up, hand tremor, scale non-linearity, bias
random walk) are switched off here; they are the diagnosis's business.
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
LOGS = ROOT / "logs"
SITE = ["--lat", "5.6037", "--lon", "-0.187"]      # the simulator's default home (Accra)
UNMODELLED = "temperature_drift,motion_contamination,scale_nonlinearity,gyro_bias_random_walk"
K_SIGMA = 4.0


def calibrate(log: Path, tmp_path: Path, *extra) -> dict:
    out = tmp_path / (log.stem + ".json")
    status = main(["log", str(log), "--quiet", "--json", str(out), *extra])
    assert status == 0
    return json.loads(out.read_text())


def make_session(tmp_path: Path, script: str, seed: int, out_name: str) -> tuple[Path, dict]:
    log = tmp_path / out_name
    truth = tmp_path / (out_name + ".truth.json")
    subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", script, "--out", str(log),
                    "--seed", str(seed), "--truth-out", str(truth), "--rate", "50",
                    "--disable", UNMODELLED], check=True, cwd=ROOT, capture_output=True,
                   timeout=300)
    return log, json.loads(truth.read_text())


def gyro_offset_at(truth: dict, t_ref: float) -> np.ndarray:
    """Truth bias b0 + b1·t evaluated at the estimate's reference time."""
    g = truth["gyr"]
    return np.asarray(g["offset"]) + np.asarray(g.get("drift", np.zeros(3))) * (t_ref - g.get("t_ref", 0.0))


def assert_within_sigma(estimate, truth, sigma, what):
    err = np.asarray(estimate) - np.asarray(truth)
    z = np.abs(err) / np.asarray(sigma)
    assert np.all(z < K_SIGMA), f"{what}: error {err} is {z.max():.1f} sigma"


@pytest.fixture(scope="module")
def ferraris_session(tmp_path_factory):
    return make_session(tmp_path_factory.mktemp("ferraris"), "ferraris", 11, "session.tlog")


def test_ferraris_session_recovers_injected_errors(ferraris_session, tmp_path):
    log, truth = ferraris_session
    est = calibrate(log, tmp_path, *SITE, "--method", "ferraris")
    for sensor in ("acc", "mag"):
        assert_within_sigma(est[sensor]["offset"], truth[sensor]["offset"],
                            est[sensor]["sigma"]["offset"], f"{sensor} offset")
        assert_within_sigma(est[sensor]["matrix"], truth[sensor]["matrix"],
                            est[sensor]["sigma"]["matrix"], f"{sensor} matrix")
    gyr = est["gyr"]
    assert_within_sigma(gyr["offset"], gyro_offset_at(truth, gyr["t_ref"]),
                        gyr["sigma"]["offset"], "gyr offset")
    assert_within_sigma(gyr["matrix"], truth["gyr"]["matrix"], gyr["sigma"]["matrix"],
                        "gyr matrix")


def test_sigmas_are_not_inflated_to_pass(ferraris_session, tmp_path):
    """The check above must be able to fail: doing nothing (zero offset, identity matrix) would
    miss the truth by far more than K_SIGMA reported sigmas on every sensor."""
    log, truth = ferraris_session
    est = calibrate(log, tmp_path, *SITE, "--method", "ferraris")
    for sensor in ("acc", "gyr", "mag"):
        for part, null in (("offset", np.zeros(3)), ("matrix", np.eye(3))):
            z = np.abs(np.asarray(truth[sensor][part]) - null) / np.asarray(est[sensor]["sigma"][part])
            assert z.max() > 3 * K_SIGMA, (sensor, part, z.max())


def test_firmware_correction_undone_whatever_params_were_in_force(tmp_path):
    """The bundled session recorded with neutral, 3.2 and 3.3 parameters calibrates the same."""
    neutral = calibrate(LOGS / "ferraris.tlog", tmp_path, *SITE)
    for name in ("ferraris_params32.tlog", "ferraris_params33.tlog"):
        other = calibrate(LOGS / name, tmp_path, *SITE)
        for sensor in ("acc", "gyr", "mag"):
            sigma = np.asarray(neutral[sensor]["sigma"]["offset"])
            diff = np.abs(np.subtract(other[sensor]["offset"], neutral[sensor]["offset"]))
            assert np.all(diff < 2 * sigma), (name, sensor, diff, sigma)


def test_proposed_parameters_follow_the_generation(tmp_path):
    p32 = calibrate(LOGS / "ferraris_params32.tlog", tmp_path, *SITE)["params"]
    p33 = calibrate(LOGS / "ferraris_params33.tlog", tmp_path, *SITE)["params"]
    assert "COMPASS_DIA_X" not in p32 and "COMPASS_DIA_X" in p33      # no DIA/ODI on 3.2
    for axis in "XYZ":
        assert 0.8 <= p32[f"INS_ACCSCAL_{axis}"] <= 1.2
        assert abs(p33[f"INS_ACCOFFS_{axis}"]) <= 3.5


def test_tumble_magnetometer_matches_truth(tmp_path):
    log, truth = make_session(tmp_path, "tumble", 12, "tumble.bin")
    est = calibrate(log, tmp_path, *SITE)
    assert_within_sigma(est["mag"]["offset"], truth["mag"]["offset"],
                        est["mag"]["sigma"]["offset"], "mag offset")
    assert np.abs(np.subtract(est["mag"]["matrix"], truth["mag"]["matrix"])).max() < 0.01


def test_readme_sample_json_layout(tmp_path):
    est = calibrate(LOGS / "ferraris.tlog", tmp_path)
    assert est["method"] == "ferraris"
    for sensor in ("acc", "gyr", "mag"):
        assert np.shape(est[sensor]["offset"]) == (3,)
        assert np.shape(est[sensor]["matrix"]) == (3, 3)
        assert "offset" in est[sensor]["sigma"]
    assert np.shape(est["gyr"]["drift"]) == (3,)
    assert {"INS_ACCOFFS_X", "INS_ACCSCAL_Z", "INS_GYROFFS_Y", "COMPASS_OFS_X"} <= set(est["params"])


def test_one_position_session_withholds_accelerometer_offsets(tmp_path):
    log, truth = make_session(tmp_path, "onepos", 13, "onepos.tlog")
    est = calibrate(log, tmp_path, *SITE)
    assert est["method"] == "static"
    assert not any(name.startswith("INS_ACC") for name in est["params"])
    # One pose: the gyro offset is the hold's mean, so it holds the g-sensitivity response to
    # the level specific force (0, 0, -g) and the Earth rate as well as the bias
    # ([Oppong] §5.2; identifiability report). The misalignment terms neglected here are ~1e-2
    # of a ~3 mrad/s response, hence the 1e-4 rad/s allowance.
    effects = truth["effects"]
    specific_force = np.array([0.0, 0.0, -truth["gravity_ms2"]])
    lat = np.radians(5.6037)
    earth_rate_body = 7.292115e-5 * np.array([np.cos(lat), 0.0, -np.sin(lat)])   # x north, z down
    expected = (gyro_offset_at(truth, est["gyr"].get("t_ref", 30.0))
                + np.asarray(effects["g_sensitivity"]) @ specific_force + earth_rate_body)
    err = np.abs(np.subtract(est["gyr"]["offset"], expected))
    assert np.all(err < K_SIGMA * np.asarray(est["gyr"]["sigma"]["offset"]) + 1e-4), err


def test_compass_scale_in_force_is_undone_and_written_consistently(tmp_path):
    """A 3.3+ vehicle with COMPASS_SCALE 1.2 (and offsets) in force: the firmware reports
    M·1.2·(raw + OFS) (ardupilot-facts.md "How the firmware applies the parameters"); undone,
    the compass offsets land within σ of the injected truth, COMPASS_OFS proposed is minus
    them, and COMPASS_SCALE is set to 0 since the proposed DIA/ODI hold the whole gain.
    Ignoring the scale would miss by 0.2 × (hard iron + OFS), tens of mGauss."""
    log, truth = tmp_path / "scaled.tlog", tmp_path / "scaled.truth.json"
    subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", "tumble",
                    "--out", str(log), "--seed", "12", "--truth-out", str(truth),
                    "--rate", "50", "--firmware", "3.3", "--disable", UNMODELLED,
                    "--set", "COMPASS_SCALE=1.2", "--set", "COMPASS_OFS_X=60",
                    "--set", "COMPASS_OFS_Y=-45", "--set", "COMPASS_OFS_Z=30"],
                   check=True, cwd=ROOT, capture_output=True, timeout=300)
    truth = json.loads(truth.read_text())
    assert truth["params"]["COMPASS_SCALE"] == pytest.approx(1.2)
    est = calibrate(log, tmp_path, *SITE)
    assert_within_sigma(est["mag"]["offset"], truth["mag"]["offset"],
                        est["mag"]["sigma"]["offset"], "mag offset")
    proposed = [est["params"][f"COMPASS_OFS_{a}"] for a in "XYZ"]
    assert_within_sigma(proposed, -np.asarray(truth["mag"]["offset"]),
                        est["mag"]["sigma"]["offset"], "COMPASS_OFS proposed")
    assert est["params"]["COMPASS_SCALE"] == 0.0
    assert np.abs(np.subtract(est["mag"]["matrix"], truth["mag"]["matrix"])).max() < 0.01
