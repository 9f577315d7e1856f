"""The firmware correction forwards and backwards (apmcal.ardupilot.firmware, .orientation).

Truth: the formulas of ardupilot-facts.md worked by hand, ArduPilot's own hand-coded axis swaps
for a few rotations (AP_Math vector3.cpp) and the explicit matrix it uses for rotation 38.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from apmcal.ardupilot import firmware as fw
from apmcal.ardupilot.orientation import ROTATIONS, rotation_matrix
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import Recording

H = math.sqrt(0.5)


# ----------------------------------------------------------------------------- rotations
@pytest.mark.parametrize("code", sorted(ROTATIONS))
def test_every_rotation_is_proper(code):
    r = rotation_matrix(code)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize("code, expected", [
    # (x, y, z) = (1, 2, 3) rotated as ArduPilot's Vector3::rotate swaps the axes by hand
    (0, (1, 2, 3)),
    (2, (-2, 1, 3)),                 # YAW_90: x = -y, y = x
    (4, (-1, -2, 3)),                # YAW_180
    (6, (2, -1, 3)),                 # YAW_270
    (8, (1, -2, -3)),                # ROLL_180
    (12, (-1, 2, -3)),               # PITCH_180
    (16, (1, -3, 2)),                # ROLL_90: y = -z, z = y
    (20, (1, 3, -2)),                # ROLL_270
    (24, (3, 2, -1)),                # PITCH_90: x = z, z = -x
    (25, (-3, 2, 1)),                # PITCH_270
    (33, (-2, -3, 1)),               # ROLL_90 then PITCH_270
    (37, (-3, -1, 2)),               # ROLL_90 then YAW_270
    (1, (H * (1 - 2), H * (1 + 2), 3)),  # YAW_45
])
def test_rotation_matches_ardupilot_axis_swaps(code, expected):
    np.testing.assert_allclose(rotation_matrix(code) @ [1, 2, 3], expected, atol=1e-12)


def test_rotation_38_matches_firmware_matrix():
    # the explicit coefficients of ROTATION_ROLL_90_PITCH_68_YAW_293 in AP_Math
    expected = [[0.14303897231223747, 0.36877648650320383, -0.91844638134308709],
                [-0.33213277779664740, -0.85628942146641884, -0.39554550256296522],
                [-0.93232380121551217, 0.36162457008209242, 0.0]]
    np.testing.assert_allclose(rotation_matrix(38), expected, atol=1e-15)


def test_duplicate_rotations_and_custom():
    np.testing.assert_allclose(rotation_matrix(26), rotation_matrix(14), atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(27), rotation_matrix(10), atol=1e-12)
    custom = {"CUSTOM_ROT1_ROLL": 90.0, "CUSTOM_ROT1_PITCH": 0.0, "CUSTOM_ROT1_YAW": 270.0}
    np.testing.assert_allclose(rotation_matrix(101, custom), rotation_matrix(37), atol=1e-12)
    with pytest.raises(ApmcalError, match="CUSTOM_ROT2_ROLL"):
        rotation_matrix(102, custom)
    for bad in (44, 99, 2.5, float("nan")):
        with pytest.raises(ApmcalError, match="AHRS_ORIENTATION"):
            rotation_matrix(bad)


# ----------------------------------------------------------------------------- hand-worked
def _params(orientation=2, instance=0, **extra):
    s = "" if instance == 0 else str(instance + 1)
    p = {"AHRS_ORIENTATION": orientation,
         f"INS_ACC{s}OFFS_X": 0.1, f"INS_ACC{s}OFFS_Y": 0.2, f"INS_ACC{s}OFFS_Z": -0.3,
         f"INS_ACC{s}SCAL_X": 1.1, f"INS_ACC{s}SCAL_Y": 0.9, f"INS_ACC{s}SCAL_Z": 1.0,
         f"INS_GYR{s}OFFS_X": 0.01, f"INS_GYR{s}OFFS_Y": 0.02, f"INS_GYR{s}OFFS_Z": 0.03}
    p.update(extra)
    return p


def test_acc_hand_worked_33():
    # sensor: ((1, 2, 9) - (0.1, 0.2, -0.3)) * (1.1, 0.9, 1.0) = (0.99, 1.62, 9.3); YAW_90 → (-y, x, z)
    out = fw.correct_acc([[1.0, 2.0, 9.0]], _params(), "3.3+")
    np.testing.assert_allclose(out, [[-1.62, 0.99, 9.3]], atol=1e-12)
    np.testing.assert_allclose(fw.uncorrect_acc(out, _params(), "3.3+"), [[1, 2, 9]], atol=1e-12)


def test_acc_hand_worked_32():
    # R raw = (-2, 1, 9); scale first: (-2.2, 0.9, 9.0); then minus offset: (-2.3, 0.7, 9.3)
    out = fw.correct_acc([[1.0, 2.0, 9.0]], _params(), "3.2")
    np.testing.assert_allclose(out, [[-2.3, 0.7, 9.3]], atol=1e-12)
    np.testing.assert_allclose(fw.uncorrect_acc(out, _params(), "3.2"), [[1, 2, 9]], atol=1e-12)


def test_gyr_hand_worked_both_generations():
    raw = [[0.1, 0.2, 0.3]]
    # 3.3+: (0.09, 0.18, 0.27) then YAW_90; 3.2: R raw = (-0.2, 0.1, 0.3) minus offsets
    np.testing.assert_allclose(fw.correct_gyr(raw, _params(), "3.3+"), [[-0.18, 0.09, 0.27]])
    np.testing.assert_allclose(fw.correct_gyr(raw, _params(), "3.2"), [[-0.21, 0.08, 0.27]])


def test_second_instance_uses_its_own_names():
    p = _params(instance=1)
    out = fw.correct_acc([[1.0, 2.0, 9.0]], p, "3.3+", instance=1)
    np.testing.assert_allclose(out, [[-1.62, 0.99, 9.3]], atol=1e-12)
    with pytest.raises(ApmcalError, match="INS_ACCOFFS_X"):
        fw.correct_acc([[1.0, 2.0, 9.0]], p, "3.3+", instance=0)


def _mag_params(**extra):
    p = {"AHRS_ORIENTATION": 0, "COMPASS_OFS_X": -10.0, "COMPASS_OFS_Y": 20.0,
         "COMPASS_OFS_Z": 5.0, "COMPASS_DIA_X": 1.1, "COMPASS_DIA_Y": 0.9, "COMPASS_DIA_Z": 1.0,
         "COMPASS_ODI_X": 0.1, "COMPASS_ODI_Y": 0.0, "COMPASS_ODI_Z": 0.0}
    p.update(extra)
    return p


def test_mag_hand_worked():
    # raw + OFS = (90, 220, 305); M rows (1.1, 0.1, 0), (0.1, 0.9, 0), (0, 0, 1)
    out = fw.correct_mag([[100.0, 200.0, 300.0]], _mag_params(), "3.3+")
    np.testing.assert_allclose(out, [[121.0, 207.0, 305.0]], atol=1e-9)
    np.testing.assert_allclose(fw.uncorrect_mag(out, _mag_params(), "3.3+"),
                               [[100, 200, 300]], atol=1e-9)


def test_mag_scale_multiplies_after_the_offsets_and_only_within_its_bounds():
    """ardupilot-facts.md, current correct_field: mag = M·SCALE·(raw + OFS), SCALE applied only
    within [0.85, 1.4] (the default 0 and any value outside mean none)."""
    # raw + OFS = (90, 220, 305); ×1.2 = (108, 264, 366); M rows (1.1, 0.1, 0), (0.1, 0.9, 0)
    scaled = _mag_params(COMPASS_SCALE=1.2)
    out = fw.correct_mag([[100.0, 200.0, 300.0]], scaled, "3.3+")
    np.testing.assert_allclose(out, [[145.2, 248.4, 366.0]], atol=1e-9)
    np.testing.assert_allclose(fw.uncorrect_mag(out, scaled, "3.3+"), [[100, 200, 300]],
                               atol=1e-9)
    for none in (0.0, 0.5, 1.5):
        np.testing.assert_allclose(
            fw.correct_mag([[100.0, 200.0, 300.0]], _mag_params(COMPASS_SCALE=none), "3.3+"),
            [[121.0, 207.0, 305.0]], atol=1e-9)
    second = {k.replace("OFS_", "OFS2_").replace("DIA_", "DIA2_").replace("ODI_", "ODI2_"): v
              for k, v in _mag_params().items()}           # the second compass's names
    second |= {"COMPASS_SCALE2": 1.2, "COMPASS_SCALE": 1.0, "COMPASS_EXTERN2": 0}
    np.testing.assert_allclose(fw.correct_mag([[100.0, 200.0, 300.0]], second, "3.3+", 1),
                               [[145.2, 248.4, 366.0]], atol=1e-9)
    assert "COMPASS_SCALE2" in fw.correction_param_names("mag", 1)


def test_simulator_and_apmcal_apply_compass_scale_alike():
    from apmcal_sim.firmware import apply_compass

    raw = np.array([[100.0, -200.0, 300.0], [-50.0, 80.0, 410.0]])
    for scale in (0.0, 0.9, 1.2, 1.5):
        p = _mag_params(COMPASS_SCALE=scale, COMPASS_ORIENT=0, COMPASS_EXTERNAL=0)
        np.testing.assert_allclose(apply_compass(raw, p, "3.3"), fw.correct_mag(raw, p, "3.3+"),
                                   atol=1e-9)


def test_mag_absent_diagonals_mean_identity_and_zero_diagonals_mean_ones():
    base = {k: v for k, v in _mag_params().items() if "DIA" not in k and "ODI" not in k}
    np.testing.assert_allclose(fw.correct_mag([[100.0, 200.0, 300.0]], base, "3.2"),
                               [[90.0, 220.0, 305.0]])
    # all-zero DIA is (1, 1, 1) but ODI_X = 0.1 still applies (firmware apply_corrections):
    # M rows (1, 0.1, 0), (0.1, 1, 0), (0, 0, 1) times (90, 220, 305)
    zero = _mag_params(COMPASS_DIA_X=0.0, COMPASS_DIA_Y=0.0, COMPASS_DIA_Z=0.0)
    out = fw.correct_mag([[100.0, 200.0, 300.0]], zero, "3.3+")
    np.testing.assert_allclose(out, [[112.0, 229.0, 305.0]])
    np.testing.assert_allclose(fw.uncorrect_mag(out, zero, "3.3+"), [[100, 200, 300]])


def test_compass_rotation_rules():
    p = {"AHRS_ORIENTATION": 2, "COMPASS_ORIENT": 8, "COMPASS_EXTERNAL": 1}
    r_ahrs, r_orient = rotation_matrix(2), rotation_matrix(8)
    np.testing.assert_allclose(fw.compass_rotation(p, "3.3+"), r_orient)       # external
    np.testing.assert_allclose(fw.compass_rotation(p, "3.2"), r_orient)
    p["COMPASS_EXTERNAL"] = 0
    np.testing.assert_allclose(fw.compass_rotation(p, "3.3+"), r_ahrs)         # internal
    np.testing.assert_allclose(fw.compass_rotation(p, "3.2"), r_ahrs @ r_orient)


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("generation", fw.GENERATIONS)
@pytest.mark.parametrize("orientation", [0, 1, 2, 8, 12, 16, 24, 25, 33, 38, 43])
def test_round_trip_random_params(generation, orientation):
    rng = np.random.default_rng(orientation + 100 * len(generation))
    for instance in (0, 1, 2):
        s = "" if instance == 0 else str(instance + 1)
        p = {"AHRS_ORIENTATION": orientation}
        for a, o, k, g, m, d, od in zip("XYZ", rng.uniform(-3, 3, 3), rng.uniform(0.8, 1.2, 3),
                                         rng.uniform(-0.2, 0.2, 3), rng.uniform(-400, 400, 3),
                                         rng.uniform(0.8, 1.2, 3), rng.uniform(-0.1, 0.1, 3)):
            p |= {f"INS_ACC{s}OFFS_{a}": o, f"INS_ACC{s}SCAL_{a}": k, f"INS_GYR{s}OFFS_{a}": g,
                  f"COMPASS_OFS{s}_{a}": m, f"COMPASS_DIA{s}_{a}": d, f"COMPASS_ODI{s}_{a}": od}
        raw = rng.normal(0, 10, (50, 3))
        for fwd, back in ((fw.correct_acc, fw.uncorrect_acc), (fw.correct_gyr, fw.uncorrect_gyr),
                          (fw.correct_mag, fw.uncorrect_mag)):
            body = fwd(raw, p, generation, instance)
            assert not np.allclose(body, raw)
            np.testing.assert_allclose(back(body, p, generation, instance), raw, atol=1e-9)


def _recording(corrected=False, frame="sensor", firmware=None, params=None, n=20):
    rng = np.random.default_rng(7)
    cols = ["acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z", "mag_x", "mag_y", "mag_z"]
    data = pd.DataFrame(rng.normal(0, 5, (n, 9)), columns=cols)
    data.insert(0, "t", np.arange(n) * 0.01)
    data["temp"] = 25.0
    return Recording(data=data, source="mem", message="IMU", firmware=firmware,
                     params=params or {}, corrected=corrected, frame=frame)


@pytest.mark.parametrize("generation", fw.GENERATIONS)
def test_recording_round_trip(generation):
    params = _params(orientation=16) | _mag_params(AHRS_ORIENTATION=16)
    raw = _recording()
    body = fw.correct(raw, params, generation)
    assert body.corrected and body.frame == "body"
    body.firmware = "ArduCopter V3.2.1" if generation == "3.2" else "ArduCopter V3.6.8"
    back = fw.uncorrect(body)                      # params and generation from the recording
    assert not back.corrected and back.frame == "sensor"
    pd.testing.assert_frame_equal(back.data, raw.data, atol=1e-9, rtol=0)
    # the other generation's formula would not give the raw samples back
    other = "3.3+" if generation == "3.2" else "3.2"
    assert not np.allclose(fw.uncorrect(body, generation=other).xyz("acc"), raw.xyz("acc"))


def test_rotated_but_uncorrected_recording_only_rotates_back():
    raw = _recording()
    body = raw.data.copy()
    r = rotation_matrix(24)
    for s in ("acc", "gyr", "mag"):
        cols = [f"{s}_x", f"{s}_y", f"{s}_z"]
        body[cols] = raw.data[cols].to_numpy() @ r.T
    rec = Recording(data=body, params={"AHRS_ORIENTATION": 24}, frame="body")
    np.testing.assert_allclose(fw.uncorrect(rec).xyz("acc"), raw.xyz("acc"), atol=1e-12)


def test_uncorrect_errors_name_the_parameter():
    params = _params() | _mag_params(AHRS_ORIENTATION=2)
    rec = _recording(corrected=True, frame="body", params=params)
    for name in ("INS_ACCSCAL_Y", "INS_GYROFFS_Z", "COMPASS_OFS_X", "AHRS_ORIENTATION"):
        missing = {k: v for k, v in params.items() if k != name}
        with pytest.raises(ApmcalError, match=f"param {name}"):
            fw.uncorrect(rec, missing, "3.3+")
        with pytest.raises(ApmcalError, match=f"mem: param {name}: parameter is nan"):
            fw.uncorrect(rec, params | {name: float("nan")}, "3.3+")
    with pytest.raises(ApmcalError, match="INS_ACCSCAL_X.*scale is 0"):
        fw.uncorrect(rec, params | {"INS_ACCSCAL_X": 0.0}, "3.3+")
    with pytest.raises(ApmcalError, match="3.2"):
        fw.uncorrect(_recording(corrected=True, params=params), generation="3.2")
    with pytest.raises(ApmcalError, match="raw sensor-frame"):
        fw.correct(rec, params, "3.3+")


def test_sensor_frame_corrected_33_recording():
    params = _params()
    raw = _recording()
    corrected = raw.data.copy()
    corrected[["acc_x", "acc_y", "acc_z"]] = fw.correct_acc(raw.xyz("acc"), params, "3.3+",
                                                            rotate=False)
    rec = Recording(data=corrected[["t", "acc_x", "acc_y", "acc_z"]], params=params,
                    corrected=True, frame="sensor")
    np.testing.assert_allclose(fw.uncorrect(rec, generation="3.3+").xyz("acc"), raw.xyz("acc"),
                               atol=1e-12)


# ----------------------------------------------------------------------------- generation
@pytest.mark.parametrize("text, expected", [
    ("ArduCopter V3.2.1 (36b405fb)", "3.2"),
    ("ArduCopter V3.1.1 (681dafcf)", "3.2"),
    ("APM:Copter V3.3-dev (ae3192b8)", "3.3+"),
    ("ArduCopter V3.6.8 (2f409678)", "3.3+"),
    ("ArduSub V4.1.0 (89639005)", "3.3+"),
    ("ArduPlane V3.10.0-dev (f2b4e06a)", "3.3+"),
    ("ArduPlane V3.2.2", "3.2"),
])
def test_generation_from_version_string(text, expected):
    # version wins over parameters that suggest the other generation
    misleading = {"COMPASS_DIA_X": 1.0} if expected == "3.2" else {"INS_ACCOFFS_X": 0.0}
    assert fw.firmware_generation(misleading, text) == expected


def test_generation_heuristics():
    assert fw.firmware_generation({"COMPASS_DIA_X": 1.0}) == "3.3+"
    assert fw.firmware_generation({"COMPASS_OFFS_MAX": 1800.0}) == "3.3+"
    assert fw.firmware_generation({"INS_ACCOFFS_X": 0.0}) == "3.2"          # APM 2.x table
    assert fw.firmware_generation({"INS_ACCOFFS_X": 0.0, "INS_ACC2OFFS_X": 0.0}) == "3.3+"
    assert fw.firmware_generation({}) == "3.3+"
    assert fw.firmware_generation({}, "unknown thing") == "3.3+"


def test_real_log_params_round_trip(shared_data):
    """Parameters as a real ArduSub 4.1 log carries them (read with pymavlink): the IMU samples
    of that log survive uncorrect → correct, and the board rotation (16, ROLL_90) moves the
    resting gravity vector from body z into sensor −y."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(shared_data / "ardupilot" / "ardusub_small.BIN"))
    params, acc = {}, []
    while (msg := log.recv_match(type=["PARM", "IMU"])) is not None:
        if msg.get_type() == "PARM":
            params[msg.Name] = msg.Value
        elif getattr(msg, "I", 0) == 0:
            acc.append((msg.AccX, msg.AccY, msg.AccZ))
    acc = np.array(acc)
    assert params["AHRS_ORIENTATION"] == 16
    generation = fw.firmware_generation(params, "ArduSub V4.1.0")
    raw = fw.uncorrect_acc(acc, params, generation)
    np.testing.assert_allclose(fw.correct_acc(raw, params, generation), acc, atol=1e-9)
    mean = raw.mean(axis=0)
    assert mean[1] < -9.0 and abs(mean[2]) < 1.0
