"""Parameters of the simulated vehicle: set / read back / persistence / dropped values, and the
firmware-generation formulas RAW_IMU follows after PARAM_SET (ardupilot-facts.md)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_helpers import messages, only, run

from apmcal_sim.vehicle import SimVehicle


def _set(v, name, value):
    v.handle(mavlink.MAVLink_param_set_message(1, 1, name.encode(), value,
                                                mavlink.MAV_PARAM_TYPE_REAL32))
    return messages(v, "PARAM_VALUE")


def test_param_set_readback_float32_and_persistence(tmp_path):
    path = tmp_path / "eeprom.json"
    v = SimVehicle(only(), generation="3.3", param_file=path)
    v.pop_messages()
    pv = _set(v, "INS_ACCOFFS_X", 0.1234567891)[0]     # _Y and _Z follow (a vector)
    assert pv.param_id == "INS_ACCOFFS_X" and pv.param_type == mavlink.MAV_PARAM_TYPE_REAL32
    assert pv.param_value == np.float32(0.1234567891)
    assert pv.param_count == len(v.params) and v.params.names[pv.param_index] == "INS_ACCOFFS_X"
    v.handle(mavlink.MAVLink_param_request_read_message(1, 1, b"INS_ACCOFFS_X", -1))
    (rd,) = messages(v, "PARAM_VALUE")
    assert rd.param_value == pv.param_value
    v.handle(mavlink.MAVLink_param_request_read_message(1, 1, b"", pv.param_index))
    assert messages(v, "PARAM_VALUE")[0].param_id == "INS_ACCOFFS_X"
    # restart: the value survives (EEPROM), others keep defaults
    v2 = SimVehicle(only(), generation="3.3", param_file=path)
    assert v2.params["INS_ACCOFFS_X"] == np.float32(0.1234567891)
    assert v2.params["INS_ACCSCAL_X"] == 1.0


def test_set_of_a_vectors_first_element_is_answered_with_all_three():
    """ArduPilot's AP_Param::send_parameter (issue 9, ArduCopter 4.7.0-dev SITL): _X set →
    PARAM_VALUE _X, _Y, _Z with the values stored; _Y or _Z set → that element alone."""
    v = SimVehicle(only(), generation="3.3")
    v.pop_messages()
    assert [(m.param_id, m.param_value) for m in _set(v, "COMPASS_OFS_Y", 12.5)] == [
        ("COMPASS_OFS_Y", 12.5)]
    assert [(m.param_id, m.param_value) for m in _set(v, "COMPASS_OFS_X", -3.0)] == [
        ("COMPASS_OFS_X", -3.0), ("COMPASS_OFS_Y", 12.5), ("COMPASS_OFS_Z", 0.0)]
    assert [m.param_id for m in _set(v, "AHRS_ORIENTATION", 2)] == ["AHRS_ORIENTATION"]


def test_stat_counters_count_boots_and_runtime(tmp_path):
    """AP_Stats: STAT_BOOTCNT + 1 at every boot (saved), STAT_RUNTIME saved every 30 s."""
    path = tmp_path / "eeprom.json"
    v = SimVehicle(only(), generation="3.3", param_file=path, fs=100.0)
    assert v.params["STAT_BOOTCNT"] == 1 and v.params["STAT_RUNTIME"] == 0
    v.run_for(29.0)
    assert v.params["STAT_RUNTIME"] == 0
    v.run_for(2.0)
    assert v.params["STAT_RUNTIME"] == 30
    v2 = SimVehicle(only(), generation="3.3", param_file=path, fs=100.0)
    assert v2.params["STAT_BOOTCNT"] == 2 and v2.params["STAT_RUNTIME"] == 30
    assert "STAT_BOOTCNT" not in SimVehicle(only(), generation="3.2").params   # no AP_Stats


@pytest.mark.parametrize("name,value", [("INS_ACCOFFS_X", math.nan), ("INS_ACCOFFS_X", math.inf),
                                        ("INS_ACCOFFS_Q", 1.0), ("COMPASS_DIA_X", 1.1)])
def test_nan_inf_unknown_dropped_silently(tmp_path, name, value):
    v = SimVehicle(only(), generation="3.2", param_file=tmp_path / "p.json")
    v.pop_messages()
    before = v.params.as_dict()
    assert _set(v, name, value) == []          # no answer at all: the GCS sees a timeout
    assert v.params.as_dict() == before        # COMPASS_DIA_* does not exist on 3.2
    assert not (tmp_path / "p.json").exists()


def test_param_request_list_sends_every_param_and_version():
    v = SimVehicle(only(), generation="3.2")
    v.pop_messages()
    v.handle(mavlink.MAVLink_param_request_list_message(1, 1))
    out = v.pop_messages()
    pvs = [m for _, m in out if m.get_type() == "PARAM_VALUE"]
    assert [p.param_index for p in pvs] == list(range(len(v.params)))
    names = {p.param_id for p in pvs}
    assert {"INS_ACCOFFS_X", "INS_ACCSCAL_Z", "INS_GYROFFS_Y", "INS_GYR_CAL", "AHRS_ORIENTATION",
            "COMPASS_OFS_X", "SR0_RAW_SENS"} <= names
    assert not any(n.startswith(("COMPASS_DIA", "INS_ACC2")) for n in names)
    texts = [m.text for _, m in out if m.get_type() == "STATUSTEXT"]
    assert texts == ["ArduCopter V3.2.1 (sitl)"]


def _raw_imu_after(gen, pose, sets, orientation_truth=0, seconds=4.5):
    tr = only("quantization")      # exact ±g ADC counts; RAW_IMU truncated toward zero
    tr.board_orientation = orientation_truth
    v = SimVehicle(tr, "operator", gen)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    v.goto_pose(pose)
    for name, value in sets:
        _set(v, name, value)
    v.set_interval("RAW_IMU", 10)
    v.run_for(seconds)
    return messages(v, "RAW_IMU")[-1]


@pytest.mark.parametrize("gen,expect_mg", [
    # worked by hand from ardupilot-facts.md, raw x = −g nose down, OFFS 0.5, SCAL 1.1:
    ("3.2", int(-(1.1 * 9.80665 + 0.5) * 1000 / 9.80665)),     # scale first: −1150
    ("3.3", int(-(9.80665 + 0.5) * 1.1 * 1000 / 9.80665)),     # offset first: −1156
])
def test_raw_imu_after_param_set_follows_generation(gen, expect_mg):
    m0 = _raw_imu_after(gen, "nosedown", [])
    assert m0.xacc == -1000 and m0.zacc == 0
    m = _raw_imu_after(gen, "nosedown", [("INS_ACCOFFS_X", 0.5), ("INS_ACCSCAL_X", 1.1)])
    assert m.xacc == expect_mg
    assert expect_mg == {"3.2": -1150, "3.3": -1156}[gen]


@pytest.mark.parametrize("gen", ["3.2", "3.3"])
def test_gyro_offsets_and_orientation(gen):
    # INS_GYROFFS is subtracted: a still, error-free gyro then reads −offset
    # (0.02 would give −19: float32(0.02)·1000 = 19.99999 truncates toward zero, as in C)
    m = _raw_imu_after(gen, "level", [("INS_GYROFFS_Y", 0.0205)])
    assert (m.xgyro, m.ygyro, m.zgyro) == (0, -20, 0)
    # board mounted yaw 90 (truth) and AHRS_ORIENTATION=2 set: body values come back level/left
    m = _raw_imu_after(gen, "left", [("AHRS_ORIENTATION", 2)], orientation_truth=2)
    assert (m.xacc, m.yacc, m.zacc) == (0, 1000, 0)          # left side down → acc_y = +g
    m = _raw_imu_after(gen, "left", [], orientation_truth=2)  # orientation not configured
    assert (m.xacc, m.yacc, m.zacc) == (1000, 0, 0)          # board x points where body y is


def test_compass_offsets_added_and_dia_on_33():
    tr = only("quantization")
    _, h = run(tr, 0.1)
    raw = h["raw_mag"][-1]
    m = _raw_imu_after("3.2", "level", [("COMPASS_OFS_X", 100.0)])
    assert m.xmag == int(raw[0] + 100.0)
    m = _raw_imu_after("3.3", "level", [("COMPASS_OFS_X", 100.0), ("COMPASS_DIA_Y", 2.0),
                                         ("COMPASS_ODI_X", 0.5)])
    assert m.ymag == int(0.5 * (raw[0] + 100.0) + 2.0 * raw[1])


def test_boot_gyro_calibration_sets_offsets():
    tr = only("gyro_bias")
    v = SimVehicle(tr, "onepos", "3.3")
    assert v.params["INS_GYR_CAL"] == 1
    v.run_for(1.2)
    offs = [v.params[f"INS_GYROFFS_{a}"] for a in "XYZ"]
    np.testing.assert_allclose(offs, np.float32(tr.gyro_bias), rtol=1e-6)
    v.set_interval("RAW_IMU", 10)
    v.run_for(0.5)
    m = messages(v, "RAW_IMU")[-1]
    assert (m.xgyro, m.ygyro, m.zgyro) == (0, 0, 0)


def test_raw_imu_rounds_instead_of_truncating_when_quantization_off():
    v = SimVehicle(only(), "operator", "3.2")
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    _set(v, "INS_ACCOFFS_X", 0.0098)                  # −0.999 mG: truncates to 0, rounds to −1
    v.set_interval("RAW_IMU", 10)
    v.run_for(0.5)
    assert messages(v, "RAW_IMU")[-1].xacc == -1
    v2 = SimVehicle(only("quantization"), "operator", "3.2")
    v2.params.set("INS_GYR_CAL", 0, save=False)
    v2._boot_gyro = None
    _set(v2, "INS_ACCOFFS_X", 0.0098)
    v2.set_interval("RAW_IMU", 10)
    v2.run_for(0.5)
    assert messages(v2, "RAW_IMU")[-1].xacc == 0


def test_parm_file_persistence_and_bad_file(tmp_path):
    from apmcal.core.errors import ApmcalError
    from apmcal_sim.params_store import ParamStore
    path = tmp_path / "vehicle.parm"
    path.write_text("# saved by a GCS\nINS_ACCSCAL_Z,1.05\nCOMPASS_OFS_X 12.5\nNOT_A_PARAM 3\n")
    store = ParamStore("3.2", path)
    assert store["INS_ACCSCAL_Z"] == np.float32(1.05) and store["COMPASS_OFS_X"] == 12.5
    store.set("INS_ACCOFFS_Y", -0.25)
    assert ParamStore("3.2", path)["INS_ACCOFFS_Y"] == -0.25
    assert "INS_ACCOFFS_Y -0.25\n" in path.read_text()
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ApmcalError, match="bad.json: not a parameter file"):
        ParamStore("3.2", bad)


# ---- compass: COMPASS_ORIENT / COMPASS_EXTERNAL, all-zero COMPASS_DIA, COMPASS_MOT ------------
# Worked by hand: ROTATION_YAW_90 (2) maps (x, y, z) to (−y, x, z), ROTATION_ROLL_180 (8) to
# (x, −y, −z). Rules (sitl/firmware.py compass_rotation, from the firmware sources): 3.2 applies
# COMPASS_ORIENT always, then AHRS_ORIENTATION if internal; 3.3 applies AHRS_ORIENTATION if
# internal, else COMPASS_ORIENT.
@pytest.mark.parametrize("gen,external,expect", [
    ("3.3", 0, [-200.0, 100.0, 300.0]),      # internal: AHRS_ORIENTATION only, ORIENT ignored
    ("3.3", 1, [100.0, -200.0, -300.0]),     # external: COMPASS_ORIENT only
    ("3.2", 0, [200.0, 100.0, -300.0]),      # internal: YAW_90 of ROLL_180 of raw
    ("3.2", 1, [100.0, -200.0, -300.0]),     # external: COMPASS_ORIENT only
])
def test_compass_orient_and_external_rules(gen, external, expect):
    from apmcal_sim.firmware import apply_compass
    p = {"AHRS_ORIENTATION": 2, "COMPASS_ORIENT": 8, "COMPASS_EXTERNAL": external}
    np.testing.assert_allclose(apply_compass(np.array([[100.0, 200.0, 300.0]]), p, gen),
                               [expect], atol=1e-12)


@pytest.mark.parametrize("gen", ["3.2", "3.3"])
def test_external_compass_mounted_apart_from_the_board(gen):
    # board turned yaw 90 (AHRS_ORIENTATION=2 set), external compass mounted upside down
    tr = only(board_orientation=2, compass_orientation=8)
    v = SimVehicle(tr, "onepos", gen, record=True)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    for name, value in (("AHRS_ORIENTATION", 2), ("COMPASS_EXTERNAL", 1), ("COMPASS_ORIENT", 8)):
        _set(v, name, value)
    v.run_for(0.2)
    h = v.history()
    bx, by, bz = h["b_body"][0]
    np.testing.assert_allclose(h["raw_mag"][0], [bx, -by, -bz], atol=1e-9)   # chip frame
    np.testing.assert_allclose(h["mag"], h["b_body"], atol=1e-9)             # ORIENT undoes it
    _set(v, "COMPASS_EXTERNAL", 0)            # now the firmware treats it as internal
    v.run_for(0.1)
    got = v.history()["mag"][-1]
    if gen == "3.3":                          # AHRS_ORIENTATION (yaw 90) of (bx, −by, −bz)
        np.testing.assert_allclose(got, [by, bx, -bz], atol=1e-9)
    else:                                     # yaw 90 of roll 180 of the chip reading
        np.testing.assert_allclose(got, [-by, bx, bz], atol=1e-9)


def test_all_zero_compass_diagonals_mean_ones_with_offdiagonals_kept():
    from apmcal_sim.firmware import apply_compass
    raw = np.array([[100.0, 200.0, 300.0]])
    p = {"COMPASS_OFS_X": 100.0, "COMPASS_DIA_X": 0.0, "COMPASS_DIA_Y": 0.0, "COMPASS_DIA_Z": 0.0,
         "COMPASS_ODI_X": 0.5, "COMPASS_ODI_Y": 0.0, "COMPASS_ODI_Z": 0.0}
    # M = [[1, .5, 0], [.5, 1, 0], [0, 0, 1]] applied to (200, 200, 300)
    np.testing.assert_allclose(apply_compass(raw, p, "3.3"), [[300.0, 300.0, 300.0]])
    # only ALL three zero is special: DIA = (0, 1, 1) is used as it is
    p.update(COMPASS_DIA_Y=1.0, COMPASS_DIA_Z=1.0)
    np.testing.assert_allclose(apply_compass(raw, p, "3.3"), [[100.0, 300.0, 300.0]])


def test_vehicle_resets_all_zero_diagonals_to_one_in_ram(tmp_path):
    tr = only("quantization")
    _, h = run(tr, 0.1)
    raw = h["raw_mag"][-1]
    v = SimVehicle(tr, "operator", "3.3", param_file=tmp_path / "p.json")
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    v.pop_messages()
    for axis in "XYZ":                        # the set itself is stored and answered as 0
        assert _set(v, f"COMPASS_DIA_{axis}", 0.0)[0].param_value == 0.0
    v.set_interval("RAW_IMU", 10)
    v.run_for(0.5)
    m = messages(v, "RAW_IMU")[-1]
    assert (m.xmag, m.ymag, m.zmag) == tuple(int(x) for x in raw)   # not a zero field
    v.handle(mavlink.MAVLink_param_request_read_message(1, 1, b"COMPASS_DIA_Y", -1))
    assert messages(v, "PARAM_VALUE")[0].param_value == 1.0        # firmware set them to 1


@pytest.mark.parametrize("motct,drive", [(1, 0.5), (2, 10.0)])
def test_compass_mot_is_added_and_inside_the_matrix_on_33(motct, drive):
    from apmcal_sim.firmware import apply_compass
    p = {"COMPASS_MOTCT": motct, "COMPASS_MOT_X": 20.0, "COMPASS_MOT_Y": -4.0,
         "COMPASS_MOT_Z": 0.0, "COMPASS_DIA_X": 2.0, "COMPASS_DIA_Y": 1.0, "COMPASS_DIA_Z": 1.0}
    raw = np.array([[100.0, 0.0, 0.0]])
    thr, cur = (drive, 0.0) if motct == 1 else (0.0, drive)   # the other input is ignored
    # 3.3 apply_corrections: mag = M·(raw + OFS + MOT·d), so DIA_X doubles the motor term too
    np.testing.assert_allclose(apply_compass(raw, p, "3.3", thr, cur),
                               [[2 * (100 + 20 * drive), -4 * drive, 0.0]])
    # 3.2: raw + OFS + MOT·d (no matrix)
    np.testing.assert_allclose(apply_compass(raw, p, "3.2", thr, cur),
                               [[100 + 20 * drive, -4 * drive, 0.0]])
    p["COMPASS_MOTCT"] = 0                    # disabled: nothing added whatever the drive
    np.testing.assert_allclose(apply_compass(raw, p, "3.2", 1.0, 50.0), raw)


def test_rotation_the_simulator_does_not_model_is_refused_not_fatal(tmp_path):
    """AHRS_ORIENTATION 38 exists on real firmware but not in the simulator: the set is dropped
    (the ground station reads back the old value) and the vehicle keeps running."""
    from apmcal_sim.params_store import ParamStore

    store = ParamStore("3.3", tmp_path / "p.json")
    assert store.set("AHRS_ORIENTATION", 38) is None
    assert store.set("COMPASS_ORIENT", 2.5) is None
    assert store.get("AHRS_ORIENTATION") == 0.0
    assert store.set("AHRS_ORIENTATION", 2) == 2.0
