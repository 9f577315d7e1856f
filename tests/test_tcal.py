"""`apmcal tcal` (issue 11): ArduPilot's IMU temperature polynomial from a still warm-up log.

The logs come from sitl with its temperature_drift effect (raw += coef·ΔT per sensor axis, a
linear truth: c1 = coef·1e6 in ArduPilot's parameter units, c2 = c3 = 0), at 50 Hz for five
minutes of a fast-warming board; sitl's "3.3" firmware applies INS_TCAL1_* like ArduPilot 4.1+
(sitl/firmware.py ``temperature_correction``), so the written parameters can be checked by the
simulated firmware itself.
"""
from __future__ import annotations

import json
import struct
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from apmcal.ardupilot.paramfile import read_param_file, write_param_file
from apmcal.ardupilot.tcal_params import polynomial
from apmcal.calibration.tcal import calibrate_temperature, tcal_params
from apmcal.cli import main
from apmcal.sensor_model.truth import Truth
from apmcal.sources import read_log
from apmcal_sim.logwriter import HEAD, DataflashWriter
from apmcal_sim.makelog import main as makelog

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ["temperature_drift", "acc_noise", "gyro_noise", "acc_bias", "gyro_bias", "acc_scale",
           "acc_cross_axis", "g_sensitivity", "quantization", "lowpass_filter", "earth_rate",
           "local_gravity"]
Z_MAX = 3.0          # |fit − truth| ≤ 3 reported σ


def warm_log(folder: Path, name: str, seed: int = 3, seconds: float = 300.0,
             rise_k: float = 26.0, tau_s: float = 120.0, cool_start_s: float | None = None,
             board_orientation: int = 0, sets=()) -> tuple[Path, Truth]:
    """A still sitl .bin (3.3 firmware, IMU records with an instance column) of a board warming
    from 22 °C by ``rise_k`` with time constant ``tau_s`` (cooling after ``cool_start_s``)."""
    truth = Truth.random(seed).with_effects(disable=["all"], enable=EFFECTS)
    truth.temperature.update(ambient_c=22.0, rise_k=rise_k, tau_s=tau_s)
    if cool_start_s is not None:
        truth.temperature["cool_start_s"] = cool_start_s
    truth.board_orientation = board_orientation
    truth_path, out = folder / f"{name}.truth.json", folder / f"{name}.bin"
    truth.save(truth_path)
    args = ["--script", "warmup", "--duration", str(seconds), "--fs", "50", "--rate", "50",
            "--firmware", "3.3", "--seed", str(seed), "--truth", str(truth_path),
            "--imu-instance", "--out", str(out)]
    for item in sets:
        args += ["--set", item]
    assert makelog(args) == 0
    return out, truth


def injected(truth: Truth) -> dict[str, np.ndarray]:
    """The truth in ArduPilot's parameter units: rows c1, c2, c3 (X, Y, Z)."""
    t = truth.temperature
    return {s: np.array([np.asarray(t[k]) * 1e6, np.zeros(3), np.zeros(3)])
            for s, k in (("acc", "acc_coef"), ("gyr", "gyro_coef"))}


def assert_matches_truth(fit: dict, truth: Truth) -> None:
    for sensor, expect in injected(truth).items():
        coeffs, sigma = np.array(fit[sensor]["c1_c2_c3_xyz"]), np.array(fit[sensor]["sigma"])
        z = (coeffs - expect) / sigma
        assert np.all(np.abs(z) <= Z_MAX), (sensor, coeffs, expect, sigma)
        # the check has teeth: the slopes are determined to a few % of the injected ones
        assert sigma[0].max() < 0.1 * np.abs(expect[0]).max(), (sensor, sigma[0], expect[0])


# ----------------------------------------------------------------------------- formula, solver
def test_correction_agrees_with_the_simulated_firmware():
    """apmcal's reading of the parameters (what it adds back) and sitl's firmware (what it
    subtracts) agree, clamping to [TMIN, TMAX] and the default CALTEMP −300 included."""
    from apmcal.ardupilot.tcal_params import tcal_from_params
    from apmcal_sim.firmware import temperature_correction

    rng = np.random.default_rng(4)
    temps = np.linspace(-10.0, 80.0, 200)
    for caltemp in (30.0, None):
        params = {"INS_TCAL1_ENABLE": 1.0, "INS_TCAL1_TMIN": 15.0, "INS_TCAL1_TMAX": 55.0}
        for kind in ("ACC", "GYR"):
            for k, scale in ((1, 1000.0), (2, 30.0), (3, 1.0)):
                params.update({f"INS_TCAL1_{kind}{k}_{a}": rng.normal() * scale for a in "XYZ"})
            params[f"INS_{kind}1_CALTEMP"] = -300.0 if caltemp is None else caltemp
        ours = tcal_from_params({k: v for k, v in params.items()
                                 if caltemp is not None or not k.endswith("CALTEMP")}, 0)
        for sensor, kind in (("acc", "ACC"), ("gyr", "GYR")):
            expect = temperature_correction(temps, params, kind)
            assert np.allclose(ours.correction(sensor, temps), expect, rtol=1e-12, atol=1e-15)
            # flat outside [TMIN, TMAX], zero at the calibration temperature
            assert np.allclose(expect[temps <= 15.0], expect[0])
            t_cal = 15.0 if caltemp is None else caltemp
            assert np.allclose(ours.correction(sensor, np.array([t_cal])), 0.0, atol=1e-15)


def test_solver_recovers_a_cubic_with_one_constant_per_orientation():
    from apmcal.solvers.tcal import fit_tcal

    rng = np.random.default_rng(2)
    temp = np.sort(rng.uniform(20.0, 50.0, 300))
    group = (np.arange(300) // 50) % 3          # three orientations, visited twice each
    coeffs = np.array([[500.0, -300.0, 80.0], [12.0, -4.0, 2.0], [0.3, 0.1, -0.2]])
    const = np.array([[0.0, 0.0, -9.8], [9.8, 0.0, 0.0], [0.0, -9.8, 0.0]])
    clean = const[group] + polynomial(coeffs, temp - 35.0)
    fit = fit_tcal(temp, clean, np.full(300, 100.0), group)
    assert np.allclose(fit.coeffs, coeffs, rtol=1e-6, atol=1e-6)
    noisy = clean + rng.standard_normal(clean.shape) * 1e-3
    fit = fit_tcal(temp, noisy, np.full(300, 100.0), group, t_s=np.arange(300) * 2.0)
    z = (fit.coeffs - coeffs) / fit.sigma
    assert np.all(np.abs(z) < 4) and np.all(fit.random_walk == 0)


@pytest.fixture(scope="module")
def warm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tcal")
    return warm_log(folder, "warm")


def test_fit_matches_injected_drift_and_writes_params(warm, tmp_path, capsys):
    log, truth = warm
    param, out = tmp_path / "t.param", tmp_path / "t.json"
    assert main(["tcal", str(log), "--param-file", str(param), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    (fit,) = result["tcal"]
    assert fit["instance"] == 0 and fit["source"] == "IMU"
    assert_matches_truth(fit, truth)
    # TMIN / TMAX: the data's range, as the firmware's learner writes them
    temps = read_log(log).recordings[0].data["temp"]
    assert fit["tmin_c"] == pytest.approx(temps.min(), abs=0.05)
    assert fit["tmax_c"] == pytest.approx(temps.max(), abs=0.05)
    written = read_param_file(param)
    assert written["INS_TCAL1_ENABLE"] == 1 and len(written) == 21
    for k in (1, 2, 3):
        for j, axis in enumerate("XYZ"):
            assert written[f"INS_TCAL1_GYR{k}_{axis}"] == pytest.approx(
                fit["gyr"]["c1_c2_c3_xyz"][k - 1][j], rel=1e-6, abs=1e-9)
    printed = capsys.readouterr().out
    assert "INS_TCAL1_ACC1..3" in printed and "INS_TCAL1_GYR1..3" in printed


def still_drift(path: Path, after_s: float, block_s: float = 10.0) -> dict[str, float]:
    """RMS over axes of the spread (std) of 10 s block means after ``after_s`` [m/s², rad/s]."""
    rec = read_log(path).recordings[0]
    t = rec.t
    keep = t > after_s
    block = ((t[keep] - after_s) // block_s).astype(int)
    out = {}
    for sensor in ("acc", "gyr"):
        x = rec.xyz(sensor)[keep]
        means = np.array([x[block == b].mean(axis=0) for b in np.unique(block)])
        out[sensor] = float(np.sqrt(np.mean(means.std(axis=0) ** 2)))
    return out


def test_written_params_remove_the_drift_from_held_out_data(tmp_path):
    """Fit the heating half, write the .param file, let sitl's firmware apply it (ArduPilot's
    formula) to the same board; the cooling half is held out: its drift must shrink."""
    half = 180.0
    kw = dict(seed=3, seconds=2 * half, rise_k=30.0, tau_s=90.0, cool_start_s=half)
    plain, truth = warm_log(tmp_path, "plain", **kw)
    contents = read_log(plain)
    contents.recordings = [replace(r, data=r.data[r.data["t"] < half].reset_index(drop=True))
                           for r in contents.recordings]
    (result,) = calibrate_temperature(contents)
    assert result.tmax_c > 45.0
    param = tmp_path / "first_half.param"
    write_param_file(param, tcal_params([result]))
    sets = [f"{k}={v!r}" for k, v in read_param_file(param).items()]
    corrected, _ = warm_log(tmp_path, "corrected", sets=sets, **kw)
    before, after = still_drift(plain, half), still_drift(corrected, half)
    # without correction the cooling half drifts (block means spread by > 5e-3 m/s², 3e-4 rad/s)
    assert before["acc"] > 5e-3 and before["gyr"] > 3e-4, before
    for sensor in ("acc", "gyr"):
        assert after[sensor] < 0.1 * before[sensor], (sensor, before, after)
    print("held-out drift before", before, "after", after)


def test_small_temperature_range_is_refused_in_one_line(tmp_path, capsys):
    log, _ = warm_log(tmp_path, "short", seconds=60.0, rise_k=8.0, tau_s=60.0)
    param = tmp_path / "x.param"
    assert main(["tcal", str(log), "--param-file", str(param)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and str(log) in err[0] and "under the 10 °C" in err[0]
    assert not param.exists()


OLD_TCAL = {"INS_TCAL1_ENABLE": 1, "INS_TCAL1_TMIN": 25.0, "INS_TCAL1_TMAX": 40.0,
            "INS_TCAL1_ACC1_X": -3000.0, "INS_TCAL1_ACC1_Y": 2000.0, "INS_TCAL1_ACC1_Z": 1000.0,
            "INS_TCAL1_ACC2_X": 60.0, "INS_TCAL1_ACC3_Z": 6.0, "INS_TCAL1_GYR1_X": 300.0,
            "INS_TCAL1_GYR1_Y": -200.0, "INS_TCAL1_GYR2_Z": 10.0, "INS_TCAL1_GYR3_X": 1.0,
            "INS_ACC1_CALTEMP": 30.0, "INS_GYR1_CALTEMP": 28.0}


def test_calibration_in_force_and_board_rotation_are_undone(tmp_path):
    """The log's samples are already corrected by an old INS_TCAL1 (clamped to 25-40 °C) and
    rotated by AHRS_ORIENTATION 2 (yaw 90°): the fit must still find the sensor-frame truth."""
    sets = [f"{k}={v}" for k, v in OLD_TCAL.items()] + ["AHRS_ORIENTATION=2"]
    log, truth = warm_log(tmp_path, "enabled", seed=7, board_orientation=2, sets=sets)
    out = tmp_path / "t.json"
    assert main(["tcal", str(log), "--json", str(out), "--quiet"]) == 0
    (fit,) = json.loads(out.read_text())["tcal"]
    assert_matches_truth(fit, truth)
    assert any("INS_TCAL1_ENABLE = 1" in n for n in fit["notes"])
    # the old calibration and the rotation are far larger than the σ: ignoring either fails
    sigma = {s: np.array(fit[s]["sigma"]) for s in ("acc", "gyr")}
    assert 3000.0 > 20 * sigma["acc"][0].max() and 6.0 > 5 * sigma["acc"][2].max()
    expect = injected(truth)["acc"][0]
    assert np.abs(expect[0] - expect[1]) > 5 * sigma["acc"][0][:2].max()


def test_telemetry_log_temperature_is_used(tmp_path):
    """A .tlog's RAW_IMU temperature (cdegC): the accelerometer (1 mG steps, noise of several
    steps) is fitted as from a dataflash log; the gyro's 1 mrad/s steps exceed its noise, which
    the result says rather than trusting its σ."""
    truth = Truth.random(3).with_effects(disable=["all"], enable=EFFECTS)
    truth.temperature.update(ambient_c=22.0, rise_k=26.0, tau_s=60.0)
    truth_path, log, out = tmp_path / "t.json", tmp_path / "w.tlog", tmp_path / "fit.json"
    truth.save(truth_path)
    assert makelog(["--script", "warmup", "--duration", "150", "--fs", "50", "--rate", "50",
                    "--firmware", "3.3", "--seed", "3", "--truth", str(truth_path),
                    "--out", str(log)]) == 0
    assert main(["tcal", str(log), "--json", str(out), "--quiet"]) == 0
    (fit,) = json.loads(out.read_text())["tcal"]
    assert fit["source"] == "RAW_IMU"
    expect = injected(truth)["acc"]
    z = (np.array(fit["acc"]["c1_c2_c3_xyz"]) - expect) / np.array(fit["acc"]["sigma"])
    assert np.all(np.abs(z) <= Z_MAX), z
    assert any(n.startswith("gyr: noise below the RAW_IMU step") for n in fit["notes"])
    assert not any(n.startswith("acc:") for n in fit["notes"])


# ----------------------------------------------------------------------------- TCLR records
TCLR_TYPE, TCLR_FORMAT = 140, "<QBBffffI"


def write_tclr_log(path: Path, coeffs: dict, seed: int = 1) -> None:
    """A .bin with a few IMU records and the TCLR records ArduPilot's learner writes
    (AP_InertialSensor_tempcal.cpp ``Learn::add_sample``): every 0.5 °C from 20 to 45 °C, the
    mean of NSamp raw samples; accelerometer means relative to the first."""
    rng = np.random.default_rng(seed)
    temps = np.arange(20.0, 45.01, 0.5)
    nsamp = rng.integers(150, 400, temps.size)
    with DataflashWriter(path, imu_instance=True) as w:
        for us in range(0, 200_000, 20_000):
            w.imu(us, (0.01, 0.0, 0.0), (0.0, 0.0, -9.8), 20.0)
        size = struct.calcsize(TCLR_FORMAT)
        w._record("FMT", TCLR_TYPE, 3 + size, b"TCLR", TCLR_FORMAT[1:].encode(),
                  b"TimeUS,I,SType,Temp,X,Y,Z,NSamp")
        base = {"acc": np.array([0.2, -0.1, -9.8]), "gyr": np.array([0.02, -0.01, 0.005])}
        noise = {"acc": 0.02, "gyr": 5e-4}
        first = None
        for k, (temp, n) in enumerate(zip(temps, nsamp)):
            for stype, sensor in enumerate(("acc", "gyr")):
                v = (base[sensor] + polynomial(coeffs[sensor], np.array([temp - 35.0]))[0]
                     + rng.standard_normal(3) * noise[sensor] / np.sqrt(n))
                if sensor == "acc":
                    first = v if first is None else first
                    v = v - first
                w.f.write(HEAD + bytes([TCLR_TYPE]) + struct.pack(
                    TCLR_FORMAT, 1_000_000 * (k + 1), 0, stype, temp, *v, int(n)))


def test_tclr_records_are_fitted(tmp_path):
    coeffs = {"acc": np.array([[800.0, -500.0, 1500.0], [10.0, -5.0, 3.0], [0.2, -0.1, 0.3]]),
              "gyr": np.array([[-150.0, 40.0, 90.0], [1.0, -0.5, 0.8], [0.02, 0.01, -0.03]])}
    log, out = tmp_path / "tclr.bin", tmp_path / "t.json"
    write_tclr_log(log, coeffs)
    assert main(["tcal", str(log), "--json", str(out), "--quiet"]) == 0
    (fit,) = json.loads(out.read_text())["tcal"]
    assert fit["source"] == "TCLR" and fit["tmin_c"] == 20.0 and fit["tmax_c"] == 45.0
    for sensor, expect in coeffs.items():
        z = (np.array(fit[sensor]["c1_c2_c3_xyz"]) - expect) / np.array(fit[sensor]["sigma"])
        assert np.all(np.abs(z) <= Z_MAX), (sensor, z)
    # the same log, asked for its IMU samples: 0.2 s at one temperature, refused in one line
    assert main(["tcal", str(log), "--records", "imu", "--quiet"]) == 2


# ----------------------------------------------------------------------------- upload
def test_upload_through_the_verified_path(warm, tmp_path):
    from test_live_sitl import free_udp_port, wait_for_boot

    from apmcal.sources.live import VehicleLink

    log, _ = warm
    port = free_udp_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "apmcal_sim", f"udpout:127.0.0.1:{port}", "--script", "onepos",
         "--firmware", "3.3", "--speedup", "1", "--seed", "21",
         "--param-file", str(tmp_path / "sitl-params.json")],     # speedup 1: light on a
        # loaded machine (a vehicle that cannot keep up stops answering)
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_for_boot(tmp_path / "sitl-params.json")
        conn, backup, out = f"udp:127.0.0.1:{port}", tmp_path / "b.param", tmp_path / "t.json"
        assert main(["tcal", str(log), "--upload", conn, "--backup", str(backup), "--json",
                     str(out), "--quiet"]) == 0
        values = json.loads(out.read_text())["params"]
        assert len(values) == 21 and read_param_file(backup)["INS_TCAL1_ENABLE"] == 0
        with VehicleLink(conn) as link:
            for name, value in values.items():
                assert np.float32(link.read_param(name)) == np.float32(value), name
        assert main(["restore", conn, str(backup)]) == 0
        with VehicleLink(conn) as link:
            assert link.read_param("INS_TCAL1_ENABLE") == 0
    finally:
        proc.kill()
        proc.wait(timeout=10)


# ----------------------------------------------------------------------------- peer
def test_agrees_with_ardupilots_tempcal_imu(warm, tmp_path):
    """ArduPilot's own Tools/scripts/tempcal_imu.py (shipped in ardupilot-methodic-configurator):
    an unweighted cubic on 2 s moving averages of every sample; same data, so its coefficients
    must agree with apmcal's within apmcal's reported σ."""
    peer = pytest.importorskip(
        "ardupilot_methodic_configurator.tempcal_imu",
        reason="ardupilot-methodic-configurator not installed (its pinned numpy/matplotlib "
               "and GUI dependencies are not in the test extra; see README)")
    log, _ = warm
    theirs_path, out = tmp_path / "peer.param", tmp_path / "t.json"
    peer.IMUfit(str(log), str(theirs_path), True, False, False, False, None, None)
    theirs = read_param_file(theirs_path)
    assert main(["tcal", str(log), "--json", str(out), "--quiet"]) == 0
    (fit,) = json.loads(out.read_text())["tcal"]
    for sensor, kind in (("acc", "ACC"), ("gyr", "GYR")):
        ours, sigma = np.array(fit[sensor]["c1_c2_c3_xyz"]), np.array(fit[sensor]["sigma"])
        peer_c = np.array([[theirs[f"INS_TCAL1_{kind}{k}_{a}"] for a in "XYZ"]
                           for k in (1, 2, 3)])
        assert np.all(np.abs(ours - peer_c) <= sigma), (sensor, ours, peer_c, sigma)
