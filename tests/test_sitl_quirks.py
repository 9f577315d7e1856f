"""ArduPilot SITL's own sensor quirks (uniform noise, triangle gyro drift), the diagnosis effect
names, the twin inputs (explicit temperature, --twin) and the diagnosis motion script."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import kurtosis
from sitl_helpers import G0, only, still

from apmcal.core.errors import ApmcalError
from apmcal.sensor_model.truth import Truth
from apmcal_sim import DIAGNOSIS_EFFECTS, EFFECTS, NOMINAL_EFFECTS, SIMULATOR_QUIRKS

QUIRKS = ("uniform_noise", "triangle_drift")


# ---- defaults and backwards compatibility ----------------------------------------------------
def test_quirks_are_off_by_default_and_in_random_truths():
    assert SIMULATOR_QUIRKS == QUIRKS and EFFECTS[-2:] == QUIRKS
    for tr in (Truth(), Truth.random(0), Truth.random(41)):
        assert not any(tr.on(q) for q in QUIRKS)
        assert all(tr.on(e) for e in EFFECTS if e not in QUIRKS)
    assert Truth().triangle_drift == {"speed_dps_per_min": 0.05, "time_min": 5.0}
    # "all" is every effect, the quirks included
    assert all(Truth().with_effects(enable=["all"]).on(q) for q in QUIRKS)


# values drawn by the code before the quirks / per-axis parameters were added
RECORDED = {
    1: {"acc_bias": [0.3649764859685425, -0.22426979358276286, 0.33858573533796826],
        "gyro_bias": [-0.021246699962154968, -0.0036107773180749604, 0.0018173327068110952],
        "mag_interference": [22.061998386779546, 114.24039380211089, 56.81357725707312],
        "gyro_coef": [0.00022089375542967959, -0.00015609727108788167, 1.9923983032898456e-05]},
    7: {"acc_bias": [-0.1337365626414355, 0.38722165333133146, 0.157635776469676],
        "gyro_bias": [0.013995163654155915, -0.01169090321451128, -0.017029673175782835],
        "mag_interference": [28.426234476645135, -67.65871383683547, 18.771062307055],
        "gyro_coef": [-0.0004661077343917928, 0.00028277741319822065, -0.0001669507629504754]},
    2024: {"acc_bias": [-0.18804464817976466, 0.3381720539542889, 0.25332594124519386],
           "gyro_bias": [0.04119756634323769, -0.02111421932257821, 0.01425531631939773],
           "mag_interference": [12.704029887308227, -130.07993204338024, -138.06253777462152],
           "gyro_coef": [-8.466347086191497e-05, -0.00030383836904658904,
                         -1.676183101621521e-05]},
}


@pytest.mark.parametrize("seed", sorted(RECORDED))
def test_random_truth_draws_are_unchanged(seed):
    tr, rec = Truth.random(seed), RECORDED[seed]
    assert tr.acc_bias == rec["acc_bias"]                 # exact: same draws in the same order
    assert tr.gyro_bias == rec["gyro_bias"]
    assert tr.mag_interference == rec["mag_interference"]   # the last draw
    assert tr.temperature["gyro_coef"] == rec["gyro_coef"]
    assert tr.acc_noise == 3.9e-3 and tr.gyro_noise == 8.7e-5 and tr.mag_noise == 3.0
    assert tr.lowpass_hz == 20.0 and tr.gyro_bias_random_walk == 2e-5


def test_truth_file_without_the_quirks_loads_with_them_off(tmp_path):
    tr = Truth.random(5).with_effects(enable=["all"])
    tr.save(tmp_path / "new.json")
    d = json.loads((tmp_path / "new.json").read_text())
    for q in QUIRKS:                                      # as written before the quirks existed
        del d["effects"]["enabled"][q]
    del d["effects"]["triangle_drift"]
    (tmp_path / "old.json").write_text(json.dumps(d))
    old = Truth.load(tmp_path / "old.json")
    assert not any(old.on(q) for q in QUIRKS) and old.on("acc_bias")
    assert set(old.enabled) == set(EFFECTS)
    assert old.triangle_drift == {"speed_dps_per_min": 0.05, "time_min": 5.0}
    assert Truth.load(tmp_path / "new.json").on("triangle_drift")


# ---- uniform_noise ---------------------------------------------------------------------------
def test_uniform_noise_keeps_sigma_and_is_uniform():
    tr = only("uniform_noise", "acc_noise", "gyro_noise", "mag_noise")
    h = still(tr, 100.0)
    sig = {"acc": tr.acc_noise * np.sqrt(500.0), "gyr": tr.gyro_noise * np.sqrt(500.0),
           "mag": tr.mag_noise}
    level = {"acc": [0, 0, -G0], "gyr": [0, 0, 0], "mag": [300.0, 0, 200.0]}
    for key, s in sig.items():
        e = h[key] - np.array(level[key])
        np.testing.assert_allclose(e.std(axis=0), s, rtol=0.01)
        np.testing.assert_allclose(kurtosis(e, axis=0, fisher=False), 1.8, atol=0.03)
        assert np.abs(e).max() <= np.sqrt(3) * s            # bounded: half-width √3·σ
        assert np.abs(e).max() > 0.99 * np.sqrt(3) * s      # and reaching it
    # the same truth without the quirk: Gaussian (kurtosis 3, tails beyond √3·σ)
    h = still(only("acc_noise"), 100.0)
    e = h["acc"] - [0, 0, -G0]
    np.testing.assert_allclose(kurtosis(e, axis=0, fisher=False), 3.0, atol=0.1)
    assert np.abs(e).max() > 3 * sig["acc"]


def test_uniform_noise_per_axis_sigma():
    tr = only("uniform_noise", "gyro_noise", gyro_noise=[1e-5, 1e-4, 1e-3])
    h = still(tr, 50.0, fs=400.0)
    np.testing.assert_allclose(h["gyr"].std(axis=0), np.array(tr.gyro_noise) * np.sqrt(200.0),
                               rtol=0.02)
    assert np.all(np.abs(h["gyr"]).max(axis=0) <= np.array(tr.gyro_noise) * np.sqrt(600.0))


# ---- triangle_drift --------------------------------------------------------------------------
def _ardupilot_drift(t_s, speed=0.05, time_min=5.0):
    """AP_InertialSensor_SITL gyro_drift(), written out independently (rad/s)."""
    period = time_min * 2
    minutes = np.fmod(t_s / 60.0, period)
    if minutes < period / 2:
        return minutes * np.radians(speed)
    return (period - minutes) * np.radians(speed)


@pytest.mark.parametrize("t_s,expect_dps", [
    (0.0, 0.0), (60.0, 0.05), (150.0, 0.125),           # rising 0.05 °/s per minute
    (300.0, 0.25),                                      # peak at SIM_DRIFT_TIME = 5 min
    (390.0, 0.175), (540.0, 0.05),                      # falling
    (600.0, 0.0), (630.0, 0.025),                       # period 10 min: starts again
])
def test_triangle_drift_matches_ardupilot(t_s, expect_dps):
    h = still(only("triangle_drift"), 0.01, t0=t_s)
    w = h["gyr"][0]
    assert np.degrees(w) == pytest.approx([expect_dps] * 3, abs=1e-12)   # all three axes
    assert w[0] == w[1] == w[2]
    assert w[0] == pytest.approx(_ardupilot_drift(t_s), abs=1e-15)


def test_triangle_drift_over_a_session_and_parameters():
    tr = only("triangle_drift")
    tr.triangle_drift = {"speed_dps_per_min": 0.2, "time_min": 2.0}
    h = still(tr, 500.0, fs=50.0)
    expect = np.array([_ardupilot_drift(t, 0.2, 2.0) for t in h["t"]])
    np.testing.assert_allclose(h["gyr"], np.repeat(expect[:, None], 3, axis=1), atol=1e-15)
    assert np.degrees(h["gyr"][:, 0].max()) == pytest.approx(0.4, abs=1e-3)
    np.testing.assert_allclose(h["acc"], np.tile([0, 0, -G0], (len(h["t"]), 1)))  # gyro only
    # off (the default): no drift at all
    assert not np.any(still(only(), 10.0, t0=290.0)["gyr"])


def test_triangle_drift_reaches_the_vehicle_messages():
    from sitl_helpers import run
    _, h = run(only("triangle_drift"), 2.0)
    np.testing.assert_allclose(h["raw_gyr"][:, 2], [_ardupilot_drift(t) for t in h["t"]],
                               atol=1e-15)
    assert h["raw_gyr"][-1, 2] > 0


# ---- explicit board temperature (twin) -------------------------------------------------------
def test_explicit_temperature_overrides_the_warmup_curve():
    tr = only("temperature_drift")
    p = tr.temperature
    n = 500
    temp = np.linspace(10.0, 45.0, n)                     # a real log's temperatures [°C]
    h = still(tr, n / 50.0, fs=50.0, temperature=temp)
    dt = temp - p["ambient_c"]
    np.testing.assert_allclose(h["acc"] - [0, 0, -G0], np.outer(dt, p["acc_coef"]), atol=1e-12)
    np.testing.assert_allclose(h["gyr"], np.outer(dt, p["gyro_coef"]), atol=1e-15)
    # without it: the warm-up curve
    h = still(tr, n / 50.0, fs=50.0)
    curve = p["rise_k"] * (1 - np.exp(-h["t"] / p["tau_s"]))
    np.testing.assert_allclose(h["gyr"], np.outer(curve, p["gyro_coef"]), atol=1e-15)
    # temperature_drift off: the explicit series changes nothing
    h = still(only(), n / 50.0, fs=50.0, temperature=temp)
    assert not np.any(h["gyr"]) and np.all(h["acc"] == [0, 0, -G0])


# ---- diagnosis effect names ------------------------------------------------------------------
def test_diagnosis_names_and_mapping():
    assert list(DIAGNOSIS_EFFECTS) == [
        "temperature_drift", "bias_drift", "bias_random_walk", "g_sensitivity", "cross_axis",
        "gyro_scale", "scale_nonlinearity", "earth_rate", "local_gravity", "quantization",
        "lowpass_filter", "time_offset", "motion_contamination", "mag_interference",
        "uniform_noise", "triangle_drift"]
    special = {"bias_drift": ("gyro_bias_drift",), "bias_random_walk": ("gyro_bias_random_walk",),
               "cross_axis": ("acc_cross_axis",), "gyro_scale": ("gyro_scale", "gyro_misalignment")}
    for name, switches in DIAGNOSIS_EFFECTS.items():
        assert switches == special.get(name, (name,)), name
        assert set(switches) <= set(EFFECTS)
    assert NOMINAL_EFFECTS == ("acc_bias", "acc_scale", "gyro_bias", "acc_noise", "gyro_noise",
                               "mag_hard_iron", "mag_soft_iron", "mag_noise")


def _on(tr):
    return {e for e in EFFECTS if tr.on(e)}


def test_with_effects_accepts_diagnosis_names():
    tr = Truth().with_effects(disable=["all"], enable=["bias_drift", "cross_axis",
                                                       "bias_random_walk", "triangle_drift"])
    assert _on(tr) == {"gyro_bias_drift", "acc_cross_axis", "gyro_bias_random_walk",
                       "triangle_drift"}
    tr = Truth().with_effects(disable=["bias_drift", "cross_axis"])
    assert _on(tr) == set(EFFECTS) - {"gyro_bias_drift", "acc_cross_axis"} - set(QUIRKS)
    # "gyro_scale" is in both vocabularies: the sitl switch unless the diagnosis is preferred
    assert _on(Truth().with_effects(disable=["all"], enable=["gyro_scale"])) == {"gyro_scale"}
    tr = Truth().with_effects(disable=["all"], enable=["gyro_scale"], prefer="diagnosis")
    assert _on(tr) == {"gyro_scale", "gyro_misalignment"}
    with pytest.raises(ApmcalError) as err:
        Truth().with_effects(enable=["bias_drfit"])
    assert "gyro_bias_drift" in str(err.value) and "bias_random_walk" in str(err.value)


def test_cli_accepts_diagnosis_names():
    from apmcal_sim.__main__ import parse_args
    from apmcal_sim.cli_common import make_truth
    tr = make_truth(parse_args(["--disable", "all", "--enable", "bias_drift,cross_axis"]))
    assert _on(tr) == {"gyro_bias_drift", "acc_cross_axis"}
    tr = make_truth(parse_args(["--disable", "bias_random_walk,mag_interference"]))
    assert not tr.on("gyro_bias_random_walk") and not tr.on("mag_interference")
    with pytest.raises(ApmcalError, match="diagnosis names"):
        make_truth(parse_args(["--enable", "no_such_effect"]))


# ---- --twin ----------------------------------------------------------------------------------
def _twin_file(tmp_path):
    tr = Truth.random(6).with_effects(disable=["all"], enable=["acc_bias", "uniform_noise",
                                                               "acc_noise", "triangle_drift"])
    tr.acc_noise, tr.lowpass_hz = [1e-3, 2e-3, 3e-3], {"acc": 30.0, "gyro": 40.0}
    path = tmp_path / "twin.json"
    tr.save(path, extra={"twin": {"source": "flight.bin", "fs_hz": 200.0, "effects": ["x"]}})
    return tr, path


def test_twin_option_loads_a_twin_file_with_extra_keys(tmp_path, capsys):
    from apmcal_sim.__main__ import parse_args
    from apmcal_sim.cli_common import make_truth
    tr, path = _twin_file(tmp_path)
    assert "twin" in json.loads(path.read_text())
    assert make_truth(parse_args(["--twin", str(path)])) == tr
    assert make_truth(parse_args(["--truth", str(path)])) == tr
    twin = make_truth(parse_args(["--twin", str(path), "--disable", "triangle_drift"]))
    assert twin.on("uniform_noise") and not twin.on("triangle_drift")
    assert capsys.readouterr().out == ""


def test_makelog_twin_equals_truth_and_refuses_both(tmp_path, capsys):
    from apmcal_sim.makelog import main as makelog
    _, path = _twin_file(tmp_path)
    args = ["--script", "onepos", "--duration", "3", "--seed", "2"]
    assert makelog(args + ["--twin", str(path), "--out", str(tmp_path / "a.tlog")]) == 0
    assert makelog(args + ["--truth", str(path), "--out", str(tmp_path / "b.tlog")]) == 0
    assert makelog(args + ["--out", str(tmp_path / "c.tlog")]) == 0
    a = (tmp_path / "a.tlog").read_bytes()
    assert a == (tmp_path / "b.tlog").read_bytes() != (tmp_path / "c.tlog").read_bytes()
    assert capsys.readouterr().out == ""
    with pytest.raises(SystemExit) as ex:
        makelog(args + ["--twin", str(path), "--truth", str(path), "--out",
                        str(tmp_path / "d.tlog")])
    assert ex.value.code == 2 and "not allowed with" in capsys.readouterr().err
    assert not (tmp_path / "d.tlog").exists()


def test_sitl_cli_twin_help_and_exclusion(capsys):
    from apmcal_sim.__main__ import parse_args
    with pytest.raises(SystemExit):
        parse_args(["--help"])
    assert "apmcal gap --write-twin" in " ".join(capsys.readouterr().out.split())
    with pytest.raises(SystemExit) as ex:
        parse_args(["--twin", "a.json", "--truth", "b.json"])
    assert ex.value.code == 2


# ---- the diagnosis motion script -------------------------------------------------------------
def test_diagnosis_script_faces_rotations_and_throttle_ramp():
    from apmcal_sim import motion
    assert "diagnosis" in motion.SCRIPTS
    m = motion.build("diagnosis", duration=10.0)     # shorter than the session: no effect
    secs = [(n, a, b) for n, a, b in m.sections() if n != "transition"]
    assert [s[0] for s in secs] == ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a", "x_rot", "y_rot",
                                    "z_rot"] + ["corner"] * 8 + [
                                    "idle", "throttle_up", "full_throttle", "throttle_down",
                                    "idle_end"]
    ferraris = motion.ferraris()
    assert m.sections()[:len(ferraris.sections())] == ferraris.sections()
    spans = {n: (a, b) for n, a, b in secs}
    corners = [(a, b) for n, a, b in secs if n == "corner"]
    assert all(b - a == 10.0 for a, b in corners)
    # gravity along each of the eight (±1, ±1, ±1)/√3 in the body frame, once
    ups = {tuple(np.sign(np.round(m.evaluate(np.array([a + 5.0]))[0][0].T @ [0, 0, -1], 9)))
           for a, _ in corners}
    assert len(ups) == 8
    for a, _ in corners:
        up = m.evaluate(np.array([a + 5.0]))[0][0].T @ [0, 0, -1]
        np.testing.assert_allclose(np.abs(up), 1 / np.sqrt(3), atol=1e-9)
    assert spans["idle_end"][1] - spans["idle"][0] == 60.0
    assert m.duration == pytest.approx(ferraris.duration + 8 * (3.0 + 10.0) + 3.0 + 60.0)
    assert spans["idle"][1] - spans["idle"][0] == 5.0 == spans["idle_end"][1] - spans["idle_end"][0]
    assert spans["full_throttle"][1] - spans["full_throttle"][0] == 5.0
    longer = motion.build("diagnosis", duration=700.0)     # padded with a still hold
    assert longer.duration == pytest.approx(700.0)
    assert longer.sections()[-1][0] == "still"
    assert longer.sections()[:-1] == m.sections()
    fs = 200.0
    for k, name in enumerate(("x_rot", "y_rot", "z_rot")):   # −360° about x, y, z
        a, b = spans[name]
        t = np.arange(a * fs, b * fs) / fs
        _, rate, _ = m.evaluate(t)
        expect = np.zeros(3)
        expect[k] = -360.0
        np.testing.assert_allclose(np.degrees(rate.sum(axis=0) / fs), expect, atol=1e-6)
    # the motors section: level, still, throttle 0 → 1 → 0 with a linear ramp
    a, b = spans["idle"][0], spans["idle_end"][1]
    t = np.arange(a * fs, b * fs) / fs
    rot, rate, _ = m.evaluate(t)
    np.testing.assert_allclose(rot, np.broadcast_to(np.eye(3), rot.shape), atol=1e-12)
    assert not rate.any()
    thr = m.throttle(t)
    assert thr.min() == 0.0 and thr.max() == 1.0
    a, b = spans["throttle_up"]
    up = (t >= a) & (t < b)
    np.testing.assert_allclose(thr[up], (t[up] - a) / (b - a), atol=1e-12)
    assert not m.throttle(np.arange(0, spans["idle"][0], 0.5)).any()   # still during Ferraris


def test_diagnosis_script_drives_the_compass_interference():
    from sitl_helpers import run
    tr = only("mag_interference")
    v, _ = run(tr, 0.0, script="diagnosis")
    spans = {n: (a, b) for n, a, b in v.motion.sections()}
    v.run_for(spans["full_throttle"][1] - 1.0, chunk=1.0)   # record=True: all samples kept
    h = v.history()
    full = (h["t"] > spans["full_throttle"][0] + 0.5)
    idle = (h["t"] > spans["idle"][0] + 0.5) & (h["t"] < spans["idle"][1] - 0.5)
    np.testing.assert_allclose(h["raw_mag"][full].mean(axis=0) - h["raw_mag"][idle].mean(axis=0),
                               tr.mag_interference, atol=1e-9)
