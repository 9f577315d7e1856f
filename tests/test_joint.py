"""`apmcal log --method joint` ([Chow]) against sitl sessions with known injected errors.

sitl's board frame and the joint method's frame (the accelerometer's: x along its x axis, y in
its xy plane) differ by the rotation Q of the accelerometer triad, which no self-calibration
can see; the truth is brought into the accelerometer frame first (truth matrix = Q·L with L
lower triangular, the "QL" factorisation). Effects the method does not model are switched off
(temperature, tremor, scale non-linearity, gyro random walk and drift, Earth rate, the
accelerometer's time offset, the low-pass filter, and quantization: at 50 Hz sitl's gyro noise
is below its quantization step, so the rounding error is not white).
"""
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from apmcal.cli import main
from apmcal.report.lines import calibration_lines
from apmcal.solvers.result import Calibration

SITE = ["--lat", "5.6037", "--lon", "-0.187"]      # sitl's default home (Accra)
UNMODELLED = ("temperature_drift,motion_contamination,scale_nonlinearity,gyro_bias_random_walk,"
              "earth_rate,gyro_bias_drift,lowpass_filter,time_offset,quantization")
K_SIGMA = 4.0


def make_log(tmp: Path, name: str, script: str, seed: int, seconds: float, *extra) -> Path:
    from apmcal_sim.makelog import main as makelog
    out = tmp / name
    assert makelog(["--script", script, "--out", str(out), "--seed", str(seed), "--rate", "50",
                    "--fs", "50", "--duration", str(seconds), "--disable", UNMODELLED,
                    *extra]) == 0
    return out


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """One hand-held session (60 s, 50 Hz), its truth, and `apmcal log --method joint`'s JSON
    and printed report."""
    tmp = tmp_path_factory.mktemp("joint")
    truth = tmp / "truth.json"
    log = make_log(tmp, "hand.bin", "handheld", 41, 60.0, "--truth-out", str(truth))
    out = tmp / "joint.json"
    capture = tmp / "stdout.txt"
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        status = main(["log", str(log), "--method", "joint", *SITE, "--json", str(out)])
    capture.write_text(buf.getvalue())
    return {"tmp": tmp, "log": log, "truth": json.loads(truth.read_text()), "truth_file": truth,
            "status": status, "est": json.loads(out.read_text()), "stdout": buf.getvalue()}


def accelerometer_frame(truth: dict) -> dict:
    """The injected errors in the accelerometer frame: (offset, matrix) per sensor and the
    g-sensitivity (rad/s per m/s²)."""
    m_acc = np.array(truth["acc"]["matrix"])
    flip = np.fliplr(np.eye(3))
    low = flip @ np.linalg.cholesky(flip @ m_acc.T @ m_acc @ flip).T @ flip
    q = m_acc @ np.linalg.inv(low)
    effects = truth["effects"]
    g_sens = (np.array(effects["g_sensitivity"]) @ q if effects["enabled"]["g_sensitivity"]
              else np.zeros((3, 3)))
    return {"acc": (np.array(truth["acc"]["offset"]), low),
            "gyr": (np.array(truth["gyr"]["offset"]), q.T @ np.array(truth["gyr"]["matrix"])),
            "mag": (np.array(truth["mag"]["offset"]), q.T @ np.array(truth["mag"]["matrix"])),
            "g_sensitivity": g_sens}


def z_scores(estimate, truth, sigma) -> np.ndarray:
    err = np.asarray(estimate, float) - np.asarray(truth, float)
    sigma = np.asarray(sigma, float)
    # entries the model holds at exactly 0 (above the accelerometer's lower triangle) have σ 0
    return np.where(sigma > 0, np.abs(err) / np.where(sigma > 0, sigma, 1), np.abs(err) * 1e12)


def test_cli_prints_the_joint_result(fitted):
    assert fitted["status"] == 0
    text = fitted["stdout"]
    assert "method: joint" in text
    # the fit's internals (conditions per family, [Chow]) go to --verbose and the JSON
    assert "joint ([Chow])" not in text
    cal = Calibration.from_dict(fitted["est"])              # the JSON has the numbers ...
    assert sum(cal.report.joint.conditions.values()) > 0
    lines = calibration_lines(cal.report, cal.sensors)      # ... the report the words
    assert any(line.startswith("joint ([Chow])") for line in lines)
    assert "INS_GYROFFS_X" in text and "COMPASS_OFS_X" in text
    assert "cannot be held by ArduPilot" in text        # what the gyro matrix costs


def assert_within_sigma(est: dict, truth: dict, sensors=("acc", "gyr", "mag")) -> None:
    """Every offset, matrix entry and g-sensitivity of ``est`` within K_SIGMA of ``truth``
    (:func:`accelerometer_frame`)."""
    for sensor in sensors:
        offset, matrix = truth[sensor]
        s = est[sensor]
        z_off = z_scores(s["offset"], offset, s["sigma"]["offset"])
        z_mat = z_scores(s["matrix"], matrix, s["sigma"]["matrix"])
        assert z_off.max() < K_SIGMA, f"{sensor} offset {z_off.round(1)}"
        assert z_mat.max() < K_SIGMA, f"{sensor} matrix {z_mat.round(1)}"
    z_g = z_scores(est["gyr"]["g_sensitivity"], truth["g_sensitivity"],
                   est["gyr"]["sigma"]["g_sensitivity"])
    assert z_g.max() < K_SIGMA, f"g-sensitivity {z_g.round(1)}"


def test_joint_recovers_injected_errors_within_sigma(fitted):
    assert_within_sigma(fitted["est"], accelerometer_frame(fitted["truth"]))


def test_the_check_above_sees_an_ignored_gyro_scale(fitted):
    """Must fail if the gyro scale (or misalignment) were ignored: an identity gyro matrix lies
    far more than K_SIGMA reported σ from the injected one on the diagonal (scale) and off it
    (misalignment), so the recovery test above could not pass with it."""
    est, truth = fitted["est"], accelerometer_frame(fitted["truth"])
    sigma = np.array(est["gyr"]["sigma"]["matrix"])
    z_null = np.abs(np.eye(3) - truth["gyr"][1]) / sigma
    assert np.diag(z_null).max() > 3 * K_SIGMA
    assert (z_null[~np.eye(3, dtype=bool)] > K_SIGMA).any()


def test_joint_beats_the_other_methods_out_of_sample(fitted):
    """[Chow] §5's check on another session of the same board: gyro-integrated orientation
    change between still poses against accelerometer + compass at those poses."""
    from apmcal.calibration.log import Options, calibrate_log
    from apmcal.calibration.validation import check, session
    from apmcal.sources import read_log

    val = make_log(fitted["tmp"], "val.bin", "handheld", 42, 40.0, "--truth",
                   str(fitted["truth_file"]))
    _, _, raw, mag, holds = session(val)
    joint = Calibration.from_dict(fitted["est"])
    ellipsoid, _ = calibrate_log(read_log(fitted["log"]),
                                 Options("ellipsoid", 5.6037, -0.187, 1.0))
    errors = {name: check(cal, raw, mag, holds)[0]
              for name, cal in (("raw", Calibration("raw")), ("ellipsoid", ellipsoid),
                                ("joint", joint))}
    assert errors["joint"] < 0.5 * errors["ellipsoid"] and errors["joint"] < errors["raw"]


def test_auto_picks_the_joint_method_for_hand_held_poses_with_a_compass(fitted):
    """Issue 11 item 3: without --method the session gets the joint accelerometer and gyro,
    and the compass from its own ellipsoid fit (closer to the truth: benchmarks/joint_auto.py)."""
    runs = {}
    for method in ("auto", "ellipsoid"):
        out = fitted["tmp"] / f"{method}.json"
        assert main(["log", str(fitted["log"]), "--method", method, *SITE, "--quiet",
                     "--json", str(out)]) == 0
        runs[method] = json.loads(out.read_text())
    auto, joint = runs["auto"], fitted["est"]
    assert auto["method"] == "joint"
    for sensor, reference in (("acc", joint), ("gyr", joint), ("mag", runs["ellipsoid"])):
        np.testing.assert_allclose(auto[sensor]["offset"], reference[sensor]["offset"])
        np.testing.assert_allclose(auto[sensor]["matrix"], reference[sensor]["matrix"])
    assert not np.allclose(joint["mag"]["offset"], runs["ellipsoid"]["mag"]["offset"])


def test_auto_falls_back_to_the_ellipsoid_when_the_joint_fit_refuses(fitted):
    """A gyro that saw no turns (here: its samples replaced by still noise) fails the joint
    fit's motion check; auto then fits the ellipsoid and says why."""
    from apmcal.calibration.log import Options, calibrate, pick_recording
    from apmcal.sources import read_log

    rec, mag_rec = pick_recording(read_log(fitted["log"]), None)
    data = rec.data.copy()
    data[["gyr_x", "gyr_y", "gyr_z"]] = np.random.default_rng(1).normal(0, 1e-3, (len(data), 3))
    cal = calibrate(dataclasses.replace(rec, data=data), Options("auto", 5.6037, -0.187, 1.0),
                    mag_rec)
    assert cal.method == "ellipsoid"
    assert any(w.startswith("joint calibration not possible") for w in cal.report.warnings)


def handheld_csv_without_compass(tmp_path: Path, seconds: float) -> Path:
    """A sitl hand-held session (50 Hz) as a CSV with accelerometer and gyro columns only."""
    from apmcal.sensor_model.truth import Truth
    from apmcal_sim.vehicle import SimVehicle
    v = SimVehicle(Truth.random(3), "handheld", "3.3", fs=50.0, record=True, seed=3,
                   duration=seconds)
    v.run_for(seconds)
    h = v.history()
    path = tmp_path / "nocompass.csv"
    cols = np.column_stack([h["t"], h["raw_acc"], h["raw_gyr"]])
    np.savetxt(path, cols, delimiter=",", comments="",
               header="t,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z")
    return path


def test_auto_keeps_the_ellipsoid_without_a_compass(tmp_path):
    path = handheld_csv_without_compass(tmp_path, 45.0)
    out = tmp_path / "auto.json"
    assert main(["log", str(path), "--quiet", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["method"] == "ellipsoid"


def test_session_without_compass_calibrates_accelerometer_and_gyro(tmp_path, capsys):
    """A CSV without magnetometer columns: the accelerometer and gyro alone, with a warning."""
    path = handheld_csv_without_compass(tmp_path, 45.0)   # 7+ still poses: an ellipsoid start
    out = tmp_path / "nocompass.json"
    assert main(["log", str(path), "--method", "joint", "--quiet", "--json", str(out)]) == 0
    est = json.loads(out.read_text())
    assert "acc" in est and "gyr" in est and "mag" not in est
    assert any("no compass" in w for w in est["report"]["warnings"])
    assert not est["report"]["joint"]["fallback"]      # the fit itself, not its start
    assert est["schema"] == "apmcal.calibration/2"
    assert "Traceback" not in capsys.readouterr().err


def test_session_without_motion_is_refused_in_one_line(tmp_path, capsys):
    log = make_log(tmp_path, "still.bin", "onepos", 5, 20.0)
    assert main(["log", str(log), "--method", "joint", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "still poses with turns between them" in err


def test_mpu6050_joint_without_compass_beats_raw_on_a_separate_turn(shared_data):
    """Real MPU-6050 (no compass: accelerometer and gyro conditions only, tilt checked):
    fitted on the six-orientation run, checked on the separate 90° turn recording."""
    from apmcal.calibration.log import Options
    from apmcal.calibration.validation import check, fit, session

    s = session(shared_data / "mpu6050" / "example_data_calibration.csv", "mpu6050")
    _, _, raw, _, holds = session(shared_data / "mpu6050" / "imu_90_x_rot.csv", "mpu6050")
    joint = fit("joint", *s, Options("joint"))
    assert check(joint, raw, None, holds)[0] < 0.5 * check(Calibration("raw"), raw, None,
                                                           holds)[0]
