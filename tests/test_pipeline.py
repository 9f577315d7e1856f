"""The joining stage: which recording is calibrated and how it is prepared."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from apmcal.calibration.log import Options, calibrate, calibrate_log, pick_recording, prepare
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import LogContents, ParamChange, Recording
from apmcal.preprocessing.param_changes import after_param_changes, split_at_param_changes
from apmcal.sources import read_log

LOGS = Path(__file__).resolve().parent.parent / "logs"


def _recording(message, columns, instance=0, n=10):
    data = pd.DataFrame({"t": np.arange(n) * 0.1, **{c: np.zeros(n) for c in columns}})
    return Recording(data=data, message=message, instance=instance)


def test_pick_prefers_a_recording_with_gyro_over_accelerometer_alone():
    acc_only = _recording("ACC1", ["acc_x", "acc_y", "acc_z"])
    imu = _recording("IMU", ["acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"])
    contents = LogContents(path="x.bin", format="bin", recordings=[acc_only, imu])
    assert pick_recording(contents, None)[0] is imu


def test_pick_prefers_float_samples_over_int16_telemetry():
    cols = ["acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]
    raw, high = _recording("RAW_IMU", cols), _recording("HIGHRES_IMU", cols)
    contents = LogContents(path="x.tlog", format="tlog", recordings=[raw, high])
    assert pick_recording(contents, None)[0] is high


def test_non_finite_samples_are_dropped_and_counted():
    rec = pick_recording(read_log(LOGS / "ferraris.tlog"), None)[0]
    data = rec.data.copy()
    data.loc[[5, 500, 5000], "gyr_y"] = np.nan
    data.loc[77, "acc_x"] = np.inf
    prepared = prepare(replace(rec, data=data))
    assert len(prepared.raw) == len(rec) - 4
    assert any("4 of" in w and "NaN/inf" in w for w in prepared.warnings)
    assert np.isfinite(prepared.raw.xyz("gyr")).all()
    cal = calibrate(replace(rec, data=data), Options(lat_deg=5.6037, lon_deg=-0.187))
    assert np.isfinite(cal.sensors["gyr"].offset).all()


def test_firmware_option_drives_the_correction_undo():
    """A 3.2 log read as 3.3+ is un-corrected differently: the option must reach prepare()."""
    rec = pick_recording(read_log(LOGS / "ferraris_params32.tlog"), None)[0]
    as_logged = prepare(rec).raw.xyz("acc")
    np.testing.assert_allclose(prepare(rec, "3.2").raw.xyz("acc"), as_logged)
    assert np.abs(prepare(rec, "3.3+").raw.xyz("acc") - as_logged).max() > 1e-3


def _change(time_s, name="INS_ACCOFFS_X"):
    return ParamChange(name, 0.1, 0.2, time_s, "PARAM_VALUE at byte 99")


ACC_COLS = ["acc_x", "acc_y", "acc_z"]
IMU_COLS = ACC_COLS + ["gyr_x", "gyr_y", "gyr_z", "mag_x", "mag_y", "mag_z"]


def test_samples_before_a_change_of_their_own_parameters_are_dropped():
    rec = _recording("RAW_IMU", ACC_COLS, n=100)     # t = 0 .. 9.9 s
    changes = [_change(2.0), _change(5.05, "AHRS_ORIENTATION"), _change(7.0, "COMPASS_OFS_X"),
               _change(8.0, "INS_ACC2OFFS_X"), _change(9.0, "INS_GYROFFS_X")]
    kept, (warning,) = after_param_changes(rec, changes, "x.tlog")
    assert kept.t[0] == pytest.approx(5.1) and len(kept) == 49     # only acc-0 names count
    assert "(AHRS_ORIENTATION, INS_ACCOFFS_X;" in warning and "49 of 100" in warning


def test_changes_of_other_sensors_parameters_drop_nothing():
    rec = _recording("IMU", ACC_COLS, instance=1)
    kept, warnings = after_param_changes(rec, [_change(0.5), _change(0.5, "COMPASS_OFS2_X")],
                                         "x.bin")
    assert kept is rec and warnings == []           # INS_ACCOFFS_X is instance 0's


def test_a_compass_change_costs_the_accelerometer_nothing():
    """RAW_IMU carries all three sensors: a compass upload mid-log splits the compass off and
    cuts only it."""
    imu = _recording("RAW_IMU", IMU_COLS, n=100)
    imu_kept, mag, (warning,) = split_at_param_changes(imu, None,
                                                       [_change(6.0, "COMPASS_OFS_X")], "x.tlog")
    assert len(imu_kept) == 100 and not imu_kept.has("mag") and imu_kept.has("gyr")
    assert mag.sensors == ["mag"] and mag.t[0] == pytest.approx(6.1)
    assert warning.startswith("mag: correction parameters changed")


def test_a_compass_that_cannot_be_kept_loses_only_itself():
    imu = _recording("RAW_IMU", IMU_COLS, n=100)
    imu_kept, mag, (warning,) = split_at_param_changes(imu, None,
                                                       [_change(20.0, "COMPASS_DIA_X")], "x.tlog")
    assert mag is None and len(imu_kept) == 100
    assert warning.startswith("magnetometer not calibrated: COMPASS_DIA_X changed")


def test_param_change_without_a_time_is_refused_naming_the_record():
    rec = _recording("RAW_IMU", ACC_COLS)
    with pytest.raises(ApmcalError) as err:
        after_param_changes(rec, [_change(None)], "x.tlog")
    assert str(err.value).startswith("x.tlog: PARAM_VALUE at byte 99: INS_ACCOFFS_X changed")


def test_param_change_after_the_last_sample_is_refused():
    rec = _recording("RAW_IMU", ACC_COLS)
    with pytest.raises(ApmcalError, match="no samples follow"):
        after_param_changes(rec, [_change(0.85)], "x.tlog")


def test_param_change_in_a_log_that_spans_a_reboot_is_refused():
    """After a reboot the clock restarts: t > change time would keep the wrong boot's samples."""
    rec = _recording("RAW_IMU", ACC_COLS, n=20)
    rec.data["t"] = np.r_[np.arange(10) * 0.1 + 5.0, np.arange(10) * 0.1]    # reboot at sample 10
    with pytest.raises(ApmcalError, match="clock jumps back"):
        after_param_changes(rec, [_change(0.35)], "x.tlog")


def test_calibrate_log_uses_only_samples_after_a_param_change():
    contents = read_log(LOGS / "onepos.tlog")
    rec = pick_recording(contents, None)[0]
    cut = float(rec.t[0] + 0.5 * rec.duration)
    contents.param_changes = [_change(cut, "INS_GYROFFS_Y")]
    cal, _ = calibrate_log(contents)
    assert any("only the" in w and f"t={cut:.3f} s" in w for w in cal.report.warnings)
    expected = calibrate(replace(rec, data=rec.data[rec.data["t"] > cut]))
    np.testing.assert_allclose(cal.sensors["gyr"].offset, expected.sensors["gyr"].offset)


def test_an_accelerometer_change_costs_the_compass_nothing():
    imu = _recording("RAW_IMU", IMU_COLS, n=100)
    imu_kept, mag, (warning,) = split_at_param_changes(imu, None, [_change(6.0)], "x.tlog")
    assert len(mag) == 100 and mag.sensors == ["mag"]
    assert imu_kept.sensors == ["acc", "gyr"] and imu_kept.t[0] == pytest.approx(6.1)
    assert warning.startswith("acc/gyr: correction parameters changed")


def test_a_compass_change_with_a_second_compass_carrying_message_cuts_only_compasses():
    """HIGHRES_IMU is calibrated, RAW_IMU of the same instance is the other compass source: a
    compass change cuts neither message's accelerometer, and the compass calibrated is the IMU's
    own (as without changes)."""
    high, raw = _recording("HIGHRES_IMU", IMU_COLS, n=100), _recording("RAW_IMU", IMU_COLS, n=50)
    imu_kept, mag, warnings = split_at_param_changes(high, raw, [_change(6.0, "COMPASS_OFS_X")],
                                                     "x.tlog")
    assert len(imu_kept) == 100 and imu_kept.sensors == ["acc", "gyr"]
    assert mag.message == "HIGHRES_IMU" and mag.sensors == ["mag"] and len(mag) == 39
    assert len(warnings) == 1
