"""Each injected effect shows up in the simulated raw sensor samples exactly as modelled."""
from __future__ import annotations

import numpy as np
import pytest
from pygeomag import GeoMag
from scipy.spatial.transform import Rotation
from sitl_helpers import G0, only, run

from apmcal.sensor_model.imu import ImuErrorModel
from apmcal.sensor_model.truth import Truth
from apmcal_sim import EFFECTS


def test_effect_names_are_the_canonical_list():
    assert EFFECTS == (
        "acc_bias", "acc_scale", "acc_cross_axis", "acc_misalignment", "gyro_bias",
        "gyro_bias_drift", "gyro_bias_random_walk", "gyro_scale", "gyro_misalignment",
        "g_sensitivity", "acc_noise", "gyro_noise", "temperature_drift", "quantization",
        "lowpass_filter", "scale_nonlinearity", "time_offset", "motion_contamination",
        "earth_rate", "local_gravity", "mag_hard_iron", "mag_soft_iron", "mag_interference",
        "mag_noise", "uniform_noise", "triangle_drift")


def test_all_off_is_ideal_level_sensor():
    _, h = run(only(), 1.0)
    np.testing.assert_allclose(h["raw_acc"], np.tile([0, 0, -G0], (1000, 1)), atol=1e-12)
    np.testing.assert_allclose(h["raw_gyr"], 0.0, atol=1e-15)


def test_acc_bias_moves_mean_by_bias_under_noise():
    tr = only("acc_bias", "acc_noise")
    _, h = run(tr, 10.0)
    sigma = tr.acc_noise * np.sqrt(1000 / 2)            # white noise, one-sided density
    mean = h["raw_acc"].mean(axis=0)
    expect = np.array([0, 0, -G0]) + np.array(tr.acc_bias)
    assert np.all(np.abs(mean - expect) < 5 * sigma / np.sqrt(len(h["t"])))
    assert abs(h["raw_acc"][:, 0].std() / sigma - 1) < 0.05


def test_gyro_bias_and_linear_drift():
    tr = only("gyro_bias", "gyro_bias_drift")
    _, h = run(tr, 20.0)
    for k in range(3):
        slope, icpt = np.polyfit(h["t"], h["raw_gyr"][:, k], 1)
        assert slope == pytest.approx(tr.gyro_bias_drift[k], rel=1e-6)
        assert icpt == pytest.approx(tr.gyro_bias[k], rel=1e-6)


def test_random_walk_increment_variance():
    tr = only("gyro_bias_random_walk")
    _, h = run(tr, 200.0, duration=200.0)
    lag = 1000                                             # 1 s of samples
    inc = h["raw_gyr"][lag::lag] - h["raw_gyr"][:-lag:lag]
    ratio = inc.var() / tr.gyro_bias_random_walk ** 2      # q² per second
    assert 0.8 < ratio < 1.2


def test_quantization_step_sizes():
    _, h = run(only("quantization", "acc_noise", "gyro_noise"), 2.0)
    acc_counts = h["raw_acc"] * 4096 / G0                  # ±8 g → 4096 LSB/g
    gyr_counts = h["raw_gyr"] * 16.4 / (np.pi / 180)       # ±2000 °/s → 16.4 LSB/(°/s)
    np.testing.assert_allclose(acc_counts, np.round(acc_counts), atol=1e-6)
    np.testing.assert_allclose(gyr_counts, np.round(gyr_counts), atol=1e-6)
    assert np.min(np.diff(np.unique(h["raw_acc"][:, 0]))) == pytest.approx(G0 / 4096)
    assert np.min(np.diff(np.unique(h["raw_gyr"][:, 0]))) == pytest.approx(np.radians(1) / 16.4)


def test_earth_rate_projection_at_latitude():
    lat = 48.0
    _, h = run(only("earth_rate", lat=lat), 1.0)
    omega = 7.292115e-5
    expect = omega * np.array([np.cos(np.radians(lat)), 0.0, -np.sin(np.radians(lat))])
    np.testing.assert_allclose(h["raw_gyr"].mean(axis=0), expect, rtol=1e-9, atol=1e-15)


def test_local_gravity_magnitude():
    lat, alt = 60.0, 1500.0
    _, h = run(only("local_gravity", lat=lat, alt=alt), 0.5)
    s2 = np.sin(np.radians(lat)) ** 2                       # Somigliana, worked independently
    g = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999013 * s2)
    g -= 3.086e-6 * alt
    assert np.linalg.norm(h["raw_acc"], axis=1) == pytest.approx(np.full(500, g), rel=1e-12)
    _, h0 = run(only(lat=lat, alt=alt), 0.5)
    assert np.linalg.norm(h0["raw_acc"][0]) == pytest.approx(G0, rel=1e-12)


@pytest.mark.parametrize("freq,expect", [(20.0, None), (60.0, None), (5.0, None)])
def test_lowpass_attenuation(freq, expect):
    fs, fc = 1000.0, 20.0
    m = ImuErrorModel(only("lowpass_filter"), fs)
    t = np.arange(4000) / fs
    x = np.zeros((4000, 3))
    x[:, 0] = np.sin(2 * np.pi * freq * t)
    y = m.accel(t, x)[2000:, 0]
    # bilinear Butterworth order 2: |H| = 1/sqrt(1 + (tan(πf/fs)/tan(πfc/fs))⁴)
    gain = 1 / np.sqrt(1 + (np.tan(np.pi * freq / fs) / np.tan(np.pi * fc / fs)) ** 4)
    assert np.sqrt(2) * y.std() == pytest.approx(gain, rel=0.01)


def test_time_offset_delays_accelerometer():
    tr = only("time_offset")
    _, h = run(tr, 10.0, script="tumble", seed=2, duration=10.0)
    lag = int(round(tr.time_offset * 1000))
    assert lag == 2
    err = {k: np.abs(h["raw_acc"][k:] - h["f_body"][:len(h["t"]) - k]).max() for k in range(5)}
    assert min(err, key=err.get) == lag
    assert err[lag] < 1e-9 < err[0]


def test_acc_matrix_truth_undoes_scale_cross_axis_misalignment():
    tr = only("acc_bias", "acc_scale", "acc_cross_axis", "acc_misalignment")
    _, h = run(tr, 60.0, script="ardupilot6")
    cal = tr.sensor_calibrations()["acc"]
    np.testing.assert_allclose(cal.apply(h["raw_acc"]), h["f_body"], atol=1e-9)
    assert not np.allclose(h["raw_acc"], h["f_body"], atol=1e-3)


def test_gyro_truth_undoes_scale_misalignment_bias_drift():
    tr = only("gyro_bias", "gyro_bias_drift", "gyro_scale", "gyro_misalignment")
    _, h = run(tr, 10.0, script="tumble", duration=10.0)
    cal = tr.sensor_calibrations()["gyr"]
    np.testing.assert_allclose(cal.apply(h["raw_gyr"], h["t"]), h["w_body"], atol=1e-9)


def test_g_sensitivity_and_nonlinearity():
    tr = only("g_sensitivity")
    _, h = run(tr, 0.2)
    np.testing.assert_allclose(h["raw_gyr"][0], np.array(tr.g_sensitivity) @ [0, 0, -G0],
                               rtol=1e-12)
    tr = only("scale_nonlinearity")
    _, h = run(tr, 0.2)
    k2 = tr.scale_nonlinearity["acc"][2]
    assert h["raw_acc"][0, 2] == pytest.approx(-G0 + k2 * G0 ** 2, rel=1e-12)


def test_temperature_warmup_curve_and_coefficients():
    tr = only("temperature_drift")
    _, h = run(tr, 250.0, script="warmup", duration=250.0)
    p = tr.temperature
    k = int(p["tau_s"] * 1000)
    assert h["temp"][k] == pytest.approx(p["ambient_c"] + p["rise_k"] * (1 - np.exp(-1)))
    d_temp = h["temp"][k] - p["ambient_c"]
    np.testing.assert_allclose(h["raw_acc"][k] - [0, 0, -G0], np.array(p["acc_coef"]) * d_temp,
                               atol=1e-12)
    np.testing.assert_allclose(h["raw_gyr"][k], np.array(p["gyro_coef"]) * d_temp, atol=1e-12)


def test_motion_contamination_is_small_and_kinematically_consistent():
    _, h = run(only("motion_contamination"), 20.0)
    tilt = np.degrees(np.arccos(np.clip(-h["f_body"][:, 2] / G0, -1, 1)))
    assert 0.05 < tilt.max() < 2.0                      # small hand-held tilts
    # integrating the true body rate reproduces the attitude (rate and attitude agree)
    r = Rotation.from_matrix(h["rot"][0])
    mid = (h["rate"][1:5001] + h["rate"][:5000]) / 2     # trapezoid: second-order accurate
    for w in mid:
        r = r * Rotation.from_rotvec(w / 1000.0)
    ang = (r.inv() * Rotation.from_matrix(h["rot"][5000])).magnitude()
    assert ang < 1e-6


def test_magnetometer_field_hard_soft_iron_interference():
    lat, lon = 52.0, 10.0
    tr = only(lat=lat)
    v, h = run(tr, 0.2)
    f = GeoMag().calculate(glat=lat, glon=lon, alt=0.0, time=2026.0)
    np.testing.assert_allclose(h["raw_mag"][0], np.array([f.x, f.y, f.z]) * 0.01, rtol=1e-9)
    tr = only("mag_hard_iron", "mag_soft_iron", "mag_interference", lat=lat)
    v, h = run(tr, 0.1)
    v.throttle = 0.5
    v.run_for(0.1)
    h2 = v.history()
    cal = tr.sensor_calibrations()["mag"]
    np.testing.assert_allclose(cal.apply(h["raw_mag"]), h["b_body"], atol=1e-9)
    np.testing.assert_allclose(h2["raw_mag"][-1] - h2["raw_mag"][0],
                               0.5 * np.array(tr.mag_interference), atol=1e-9)


def test_truth_json_roundtrip_and_unknown_effect(tmp_path):
    from apmcal.core.errors import ApmcalError
    from apmcal.solvers.result import SensorCalibration
    tr = Truth.random(7).with_effects(disable=["acc_noise"])
    tr.save(tmp_path / "t.json")
    back = Truth.load(tmp_path / "t.json")
    assert back == tr and not back.on("acc_noise")
    import json
    d = json.loads((tmp_path / "t.json").read_text())
    acc = SensorCalibration.from_dict(d["acc"])
    np.testing.assert_allclose(acc.offset, tr.acc_bias)
    with pytest.raises(ApmcalError):
        tr.with_effects(disable=["acc_bais"])


def test_gyro_and_mag_noise_levels():
    tr = only("gyro_noise", "mag_noise")
    _, h = run(tr, 10.0)
    assert abs(h["raw_gyr"].std(axis=0) / (tr.gyro_noise * np.sqrt(500)) - 1).max() < 0.05
    assert abs(h["raw_mag"].std(axis=0) / tr.mag_noise - 1).max() < 0.05


def test_gyro_scale_nonlinearity_quadratic():
    tr = only("scale_nonlinearity")
    _, h = run(tr, 10.0, script="tumble", duration=10.0)
    w = h["w_body"]
    np.testing.assert_allclose(h["raw_gyr"], w + np.array(tr.scale_nonlinearity["gyro"]) * w ** 2,
                               atol=1e-12)


def test_output_does_not_depend_on_chunking():
    from apmcal_sim.vehicle import SimVehicle
    outs = []
    for chunk in (0.013, 0.5):
        v = SimVehicle(Truth.random(11), "tumble", "3.3", record=True, seed=4, duration=5.0,
                       start_unix=1780000000)   # same WMM date for both
        v.run_for(3.0, chunk=chunk)
        outs.append(v.history())
    for k in ("raw_acc", "raw_gyr", "raw_mag", "acc", "gyr"):
        # equal up to BLAS round-off (1 ulp varies with the block size); noise draws identical
        np.testing.assert_allclose(outs[0][k], outs[1][k], rtol=1e-13, atol=1e-13)


def test_ferraris_script_rotations_are_minus_360_deg_about_each_axis():
    _, h = run(only(), 470.0, script="ferraris")
    from apmcal_sim.motion import ferraris
    secs = {name: (a, b) for name, a, b in ferraris().sections()}
    assert [n for n in secs if n != "transition"] == ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a",
                                                       "x_rot", "y_rot", "z_rot"]
    for k, name in enumerate(("x_rot", "y_rot", "z_rot")):
        a, b = secs[name]
        m = (h["t"] >= a) & (h["t"] < b)
        angle = np.degrees(h["raw_gyr"][m].sum(axis=0) / 1000.0)
        expect = np.zeros(3)
        expect[k] = -360.0
        np.testing.assert_allclose(angle, expect, atol=0.01)
    # during each face hold the accelerometer reads ±g on the named axis (imucal convention)
    for name, (a, b) in secs.items():
        if name.endswith(("_p", "_a")):
            mean = h["raw_acc"][(h["t"] > a) & (h["t"] < b)].mean(axis=0)
            axis = "xyz".index(name[0])
            assert mean[axis] == pytest.approx(G0 if name[2] == "p" else -G0, rel=1e-9)


def test_scaled_pressure_carries_board_temperature():
    from sitl_helpers import messages
    v, h = run(only("temperature_drift"), 0.0)
    v.set_interval("SCALED_PRESSURE", 1.0)
    v.run_for(300.0)
    sp = messages(v, "SCALED_PRESSURE")
    temps = np.array([m.temperature for m in sp]) / 100
    t = np.array([m.time_boot_ms for m in sp]) / 1000
    p = v.truth.temperature
    np.testing.assert_allclose(temps, p["ambient_c"] + p["rise_k"] * (1 - np.exp(-t / p["tau_s"])),
                               atol=0.011)


# ---- throttle profile (motors script) and mag_interference ----------------------------------
def _sections(v):
    return {name: (a, b) for name, a, b in v.motion.sections()}


def _mean(h, key, span, margin=0.5):
    a, b = span
    m = (h["t"] > a + margin) & (h["t"] < b - margin)
    return h[key][m].mean(axis=0), int(m.sum())


def test_only_the_motors_script_runs_the_motors():
    from apmcal_sim import motion
    for name in motion.SCRIPTS:
        script = motion.build(name, seed=1)
        t = np.linspace(0.0, script.duration, 6001)     # the whole script, however long
        thr = script.throttle(t)
        if name in ("motors", "diagnosis"):     # diagnosis = ferraris + the motors section
            assert thr.max() == 1.0 and thr.min() == 0.0
        else:
            assert not thr.any(), name        # exact zeros: other scripts unchanged


def test_motors_script_throttle_profile():
    v, h = run(only(), 61.0, script="motors")
    secs = _sections(v)
    assert list(secs) == ["idle", "throttle_up", "full_throttle", "throttle_down", "idle_end"]
    assert v.motion.duration == 60.0
    for name, level in (("idle", 0.0), ("full_throttle", 1.0), ("idle_end", 0.0)):
        a, b = secs[name]
        assert np.all(h["throttle"][(h["t"] >= a) & (h["t"] < b)] == level), name
    a, b = secs["throttle_up"]                 # linear ramp 0 → 1
    m = (h["t"] >= a) & (h["t"] < b)
    np.testing.assert_allclose(h["throttle"][m], (h["t"][m] - a) / (b - a), atol=1e-12)
    a, b = secs["throttle_down"]
    m = (h["t"] >= a) & (h["t"] < b)
    np.testing.assert_allclose(h["throttle"][m], 1 - (h["t"][m] - a) / (b - a), atol=1e-12)


def test_mag_interference_shifts_the_field_by_interference_times_throttle():
    tr = only("mag_interference", "mag_noise")
    v, h = run(tr, 60.0, script="motors")
    secs = _sections(v)
    idle, n0 = _mean(h, "raw_mag", secs["idle"])
    full, n1 = _mean(h, "raw_mag", secs["full_throttle"])
    tol = 5 * tr.mag_noise * np.sqrt(1 / n0 + 1 / n1)
    i = np.asarray(tr.mag_interference)
    assert np.linalg.norm(i) > 30                               # visible, not a rounding
    np.testing.assert_allclose(full - idle, i * 1.0, atol=tol)
    # over the ramps: raw field = field + i·throttle, slope i per unit throttle
    for k in range(3):
        slope = np.polyfit(h["throttle"], h["raw_mag"][:, k], 1)[0]
        assert slope == pytest.approx(i[k], abs=0.5)
    # the reported field (neutral parameters, COMPASS_MOTCT 0) carries it too
    rep_idle, _ = _mean(h, "mag", secs["idle"])
    rep_full, _ = _mean(h, "mag", secs["full_throttle"])
    np.testing.assert_allclose(rep_full - rep_idle, i, atol=tol)
    # effect off: the same throttle profile leaves the field alone
    v, h = run(only("mag_noise"), 60.0, script="motors")
    idle, _ = _mean(h, "raw_mag", secs["idle"])
    full, _ = _mean(h, "raw_mag", secs["full_throttle"])
    np.testing.assert_allclose(full - idle, 0.0, atol=tol)


@pytest.mark.parametrize("motct,per_unit,sign,expect_factor", [
    (1, 1.0, -1, 0.0),     # COMPASS_MOT = −i per unit throttle: ADDED, cancels the interference
    (2, 20.0, -1, 0.0),    # per amp (current modelled as 20 A × throttle)
    (1, 1.0, +1, 2.0),     # wrong sign doubles it (the firmware adds, never subtracts)
])
def test_compass_mot_compensates_the_interference(motct, per_unit, sign, expect_factor):
    from apmcal_sim.vehicle import SimVehicle
    tr = only("mag_interference")
    v = SimVehicle(tr, "motors", "3.3", record=True, seed=5)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    i = np.asarray(tr.mag_interference)
    v.params.set("COMPASS_MOTCT", motct, save=False)
    for axis, value in zip("XYZ", sign * i / per_unit):
        v.params.set(f"COMPASS_MOT_{axis}", value, save=False)
    v.run_for(60.0)
    h = v.history()
    secs = _sections(v)
    idle, _ = _mean(h, "mag", secs["idle"])
    full, _ = _mean(h, "mag", secs["full_throttle"])
    # float32 parameters: 1e-4 relative
    np.testing.assert_allclose(full - idle, expect_factor * i, atol=1e-3 * np.abs(i).max())
    up = (h["t"] > secs["throttle_up"][0]) & (h["t"] < secs["throttle_up"][1])
    np.testing.assert_allclose(h["mag"][up] - h["b_body"][up],
                               np.outer(h["throttle"][up], expect_factor * i),
                               atol=1e-3 * np.abs(i).max())


def test_sys_status_current_follows_the_throttle():
    from sitl_helpers import messages
    v, _ = run(only(), 0.0, script="motors")
    v.run_for(60.0)
    st = messages(v, "SYS_STATUS")
    cur = np.array([m.current_battery for m in st])       # cA
    t = np.arange(len(st), dtype=float)                   # one per second from t = 0
    np.testing.assert_allclose(cur, np.floor(v.motion.throttle(t) * 2000 + 1e-9), atol=1)
    assert cur.max() == 2000 and cur[0] == 0


# ---- per-axis parameters and any model rate (what the diagnosis twin needs) ------------------
def test_per_axis_noise_gives_per_axis_sigma():
    from sitl_helpers import still
    acc_n, gyr_n, mag_n = [1e-3, 4e-3, 1.6e-2], [2e-5, 1e-4, 5e-4], [1.0, 3.0, 9.0]
    tr = only("acc_noise", "gyro_noise", "mag_noise", acc_noise=acc_n, gyro_noise=gyr_n,
              mag_noise=mag_n)
    h = still(tr, 40.0)
    half = np.sqrt(1000 / 2)
    np.testing.assert_allclose(h["acc"].std(axis=0), np.array(acc_n) * half, rtol=0.03)
    np.testing.assert_allclose(h["gyr"].std(axis=0), np.array(gyr_n) * half, rtol=0.03)
    np.testing.assert_allclose(h["mag"].std(axis=0), mag_n, rtol=0.03)


def test_per_axis_random_walk():
    from sitl_helpers import still
    q = [1e-5, 4e-5, 1.6e-4]
    h = still(only("gyro_bias_random_walk", gyro_bias_random_walk=q), 400.0, fs=100.0)
    inc = h["gyr"][100::100] - h["gyr"][:-100:100]          # 1 s increments: variance q² · 1 s
    np.testing.assert_allclose(inc.var(axis=0) / np.square(q), 1.0, atol=0.2)


def test_scalar_noise_is_bit_identical_to_the_same_value_per_axis():
    from sitl_helpers import still
    a = still(only("acc_noise", "gyro_noise", "mag_noise", "gyro_bias_random_walk"), 1.0)
    tr = only("acc_noise", "gyro_noise", "mag_noise", "gyro_bias_random_walk")
    for name in ("acc_noise", "gyro_noise", "mag_noise", "gyro_bias_random_walk"):
        setattr(tr, name, [getattr(tr, name)] * 3)
    b = still(tr, 1.0)
    for k in ("acc", "gyr", "mag"):
        assert np.array_equal(a[k], b[k]) and a[k].std() > 0


@pytest.mark.parametrize("fs", [50.0, 200.0, 400.0])
def test_noise_density_meaning_at_any_rate(fs):
    from sitl_helpers import still
    tr = only("acc_noise", "gyro_noise")
    h = still(tr, 20000 / fs, fs=fs)
    np.testing.assert_allclose(h["acc"].std(axis=0) / (tr.acc_noise * np.sqrt(fs / 2)), 1.0,
                               atol=0.04)
    np.testing.assert_allclose(h["gyr"].std(axis=0) / (tr.gyro_noise * np.sqrt(fs / 2)), 1.0,
                               atol=0.04)


def _sine_gain(model, sensor, freq, fs, n=4000):
    t = np.arange(n) / fs
    x = np.zeros((n, 3))
    x[:, 0] = np.sin(2 * np.pi * freq * t)
    y = model.accel(t, x) if sensor == "acc" else model.gyro(t, x, np.zeros((n, 3)))
    return np.sqrt(2) * y[n // 2:, 0].std()


def test_lowpass_per_sensor_cutoffs():
    fs = 400.0
    m = ImuErrorModel(only("lowpass_filter", lowpass_hz={"acc": 10.0, "gyro": 60.0}), fs)
    for sensor, fc in (("acc", 10.0), ("gyro", 60.0)):
        gain = 1 / np.sqrt(1 + (np.tan(np.pi * 30.0 / fs) / np.tan(np.pi * fc / fs)) ** 4)
        assert _sine_gain(m, sensor, 30.0, fs) == pytest.approx(gain, rel=0.01), sensor


@pytest.mark.parametrize("cutoff", [25.0, 40.0])
def test_lowpass_at_or_above_nyquist_is_skipped(cutoff):
    fs = 50.0                                              # Nyquist 25 Hz
    tr = only("lowpass_filter", lowpass_hz=cutoff)
    m = ImuErrorModel(tr, fs)                              # no error from scipy's butter
    assert _sine_gain(m, "acc", 7.0, fs) == pytest.approx(1.0, abs=1e-9)
    assert _sine_gain(m, "gyro", 7.0, fs) == pytest.approx(1.0, abs=1e-9)
    # just below Nyquist the filter is applied (and attenuates a 7 Hz tone at a 5 Hz cutoff)
    m = ImuErrorModel(only("lowpass_filter", lowpass_hz={"acc": 5.0, "gyro": cutoff}), fs)
    assert _sine_gain(m, "acc", 7.0, fs) < 0.7
    assert _sine_gain(m, "gyro", 7.0, fs) == pytest.approx(1.0, abs=1e-9)


def test_per_axis_and_per_sensor_parameters_roundtrip_and_are_checked(tmp_path):
    import json

    from apmcal.core.errors import ApmcalError
    tr = Truth.random(2)
    tr.acc_noise, tr.mag_noise, tr.gyro_bias_random_walk = [1e-3, 2e-3, 3e-3], [1, 2, 3], [1e-5] * 3
    tr.lowpass_hz = {"acc": 42.0, "gyro": 98.0}
    tr.save(tmp_path / "t.json")
    assert Truth.load(tmp_path / "t.json") == tr
    d = json.loads((tmp_path / "t.json").read_text())
    for key, bad in (("acc_noise", [1e-3, 2e-3]), ("gyro_noise", "loud"),
                     ("lowpass_hz", {"acc": 20.0}), ("lowpass_hz", -5.0)):
        e = dict(d["effects"], **{key: bad})
        (tmp_path / "bad.json").write_text(json.dumps({"effects": e}))
        with pytest.raises(ApmcalError, match=key):
            Truth.load(tmp_path / "bad.json")


def test_battery_current_constant_is_20_amps_per_unit_throttle():
    from apmcal_sim import FULL_THROTTLE_CURRENT_A
    assert FULL_THROTTLE_CURRENT_A == 20.0
    v, _ = run(only(), 0.0, script="motors")
    t = np.array([0.0, 10.0, 16.25, 27.5, 60.0])
    np.testing.assert_allclose(v.current_at(t), FULL_THROTTLE_CURRENT_A * v.motion.throttle(t))
    assert v.current_at(27.5)[0] == 20.0
