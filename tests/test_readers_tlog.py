"""The .tlog reader against pymavlink (real logs) and against hand-built packets (units, v1/v2,
signed frames, instances)."""
from __future__ import annotations

import struct

import numpy as np
import pymavlink_ref as ref
import pytest
from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav2

from apmcal.core.errors import ApmcalError
from apmcal.sources import read_log
from apmcal.sources.tlog import read_tlog_messages

TLOGS = ["ardupilot/sitl_vtol.tlog", "ardupilot/ardusub_small.tlog"]


def frame(msg, mav, t_us: int) -> bytes:
    """One tlog frame: 8-byte big-endian timestamp then the packed MAVLink packet."""
    return struct.pack(">Q", t_us) + msg.pack(mav)


def v2(signed: bool = False):
    m = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    if signed:
        m.signing.secret_key = bytes(range(32))
        m.signing.sign_outgoing = True
        m.signing.timestamp = 1
    return m


@pytest.mark.parametrize("name", TLOGS)
def test_matches_pymavlink(shared_data, name):
    path = shared_data / name
    contents = read_log(path)
    msgs = ref.pymavlink_messages(path, ref.TLOG_READ + ["PARAM_VALUE"])
    n = ref.compare(contents, ref.tlog_expected(msgs))
    assert n > 1000
    assert contents.params == ref.expected_params(msgs)
    assert contents.format == "tlog"
    for r in contents.recordings:
        assert r.corrected and r.frame == "body"
        assert r.params == contents.params and r.firmware == contents.firmware


@pytest.mark.parametrize("name", TLOGS)
def test_raw_fields_match_pymavlink(shared_data, name):
    """Every decoded field (not only the ones turned into columns) equals pymavlink's."""
    path = shared_data / name
    dec, _, _ = read_tlog_messages(path, ["RAW_IMU", "SCALED_IMU2", "PARAM_VALUE"])
    msgs = ref.pymavlink_messages(path, ["RAW_IMU", "SCALED_IMU2", "PARAM_VALUE"])
    for mtype, arr in dec.items():
        ms = [m for m in msgs if m.get_type() == mtype]
        assert len(arr) == len(ms) > 0
        for field in arr.dtype.names:
            want = [getattr(m, field) for m in ms]
            have = arr[field]
            if have.dtype.kind == "S":
                have = [v.decode() for v in have]
            np.testing.assert_array_equal(have, want, err_msg=f"{mtype}.{field}")


def test_firmware_and_vehicle(shared_data):
    sitl = read_log(shared_data / "ardupilot/sitl_vtol.tlog")
    assert (sitl.vehicle, sitl.firmware) == ("ArduPlane", "ArduPlane V3.10.0-dev")
    sub = read_log(shared_data / "ardupilot/ardusub_small.tlog")
    assert (sub.vehicle, sub.firmware) == ("ArduSub", "ArduSub V4.1.1")
    assert any("ArduSub V4.1.1 BETA5" in m for m in sub.messages)


def test_ardusub_all_zero_imu2_is_not_data(shared_data):
    """ArduSub's SCALED_IMU2 acc/gyro are all zero: no zero-filled acc/gyr columns survive."""
    sub = read_log(shared_data / "ardupilot/ardusub_small.tlog")
    imu2 = [r for r in sub.recordings if r.message == "SCALED_IMU2"]
    for r in imu2:
        assert not r.has("acc") and not r.has("gyr")
        assert r.has("mag") and np.abs(r.xyz("mag")).max() > 0
    raw = next(r for r in sub.recordings if r.message == "RAW_IMU")
    assert raw.sensors == ["acc", "gyr", "mag"] and "temp" in raw.data
    assert 20 < raw.data["temp"].median() < 60      # cdegC → °C
    assert abs(np.linalg.norm(raw.xyz("acc"), axis=1).mean() - 9.8) < 0.3


def test_units_by_hand(tmp_path):
    """1000 mG = 9.80665 m/s², 1000 mrad/s = 1 rad/s, 2500 cdegC = 25 °C, 0.5 Gauss = 500 mGauss."""
    m = v2()
    data = frame(mav2.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3), m, 1)
    data += frame(mav2.MAVLink_raw_imu_message(2_000_000, 1000, -1000, 0, 1000, 0, -500,
                                               300, 0, -300, 0, 2500), m, 2)
    data += frame(mav2.MAVLink_scaled_imu3_message(1500, 0, 0, -1000, 1, 2, 3, 4, 5, 6, 0), m, 3)
    data += frame(mav2.MAVLink_highres_imu_message(3_000_000, 0.5, 0, -9.8, 0.25, 0, 0,
                                                   0.5, 0, 0, 0, 0, 0, 31.5, 0xFFFF, 1), m, 4)
    p = tmp_path / "units.tlog"
    p.write_bytes(data)
    c = read_log(p)
    rec = {(r.message, r.instance): r for r in c.recordings}
    raw = rec[("RAW_IMU", 0)].data.iloc[0]
    assert raw.t == 2.0 and raw.acc_x == pytest.approx(9.80665, abs=1e-12)
    assert raw.acc_y == pytest.approx(-9.80665) and raw.gyr_x == pytest.approx(1.0)
    assert raw.gyr_z == pytest.approx(-0.5) and raw.mag_x == 300 and raw.temp == pytest.approx(25.0)
    s3 = rec[("SCALED_IMU3", 2)]
    assert s3.data.t.iloc[0] == 1.5 and "temp" not in s3.data  # temperature 0 = not filled
    assert s3.data.acc_z.iloc[0] == pytest.approx(-9.80665)
    hr = rec[("HIGHRES_IMU", 1)].data.iloc[0]
    assert hr.mag_x == pytest.approx(500.0) and hr.acc_z == pytest.approx(-9.8, abs=1e-6)
    assert hr.temp == pytest.approx(31.5) and hr.t == 3.0
    assert c.vehicle == "ArduCopter" and c.bytes_skipped == 0


def test_mavlink1_and_signed_v2_frames(tmp_path):
    """v1 packets (no extensions) and signed v2 packets (13 signature bytes) are framed right."""
    m1, m2s = mav1.MAVLink(None, srcSystem=1, srcComponent=1), v2(signed=True)
    data = b""
    for i in range(20):
        data += frame(mav1.MAVLink_raw_imu_message(i * 1000, i, 0, -1000, 0, 0, 0, 1, 2, 3), m1, i)
        data += frame(mav2.MAVLink_raw_imu_message(i * 1000 + 500, i, 0, -1000, 0, 0, 0, 1, 2, 3,
                                                   0, 0), m2s, i)
    p = tmp_path / "mixed.tlog"
    p.write_bytes(data)
    c = read_log(p)
    assert c.bytes_skipped == 0
    (r,) = c.recordings
    assert len(r) == 40 and np.all(np.diff(r.t) > 0)
    np.testing.assert_allclose(r.data.acc_z, -9.80665)


def test_no_imu_tlog_is_an_error(tmp_path):
    m = v2()
    data = b"".join(frame(mav2.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3), m, i)
                    for i in range(5))
    p = tmp_path / "noimu.tlog"
    p.write_bytes(data)
    with pytest.raises(ApmcalError, match=r"no IMU messages \(found: HEARTBEAT\)") as e:
        read_log(p)
    assert "\n" not in str(e.value) and str(p) in str(e.value)


def test_nan_param_value_is_kept_out(tmp_path):
    m = v2()
    data = frame(mav2.MAVLink_param_value_message(b"COMPASS_MOT_X", float("nan"), 9, 2, 0), m, 1)
    data += frame(mav2.MAVLink_param_value_message(b"INS_ACCOFFS_X", 0.25, 9, 2, 1), m, 2)
    data += frame(mav2.MAVLink_raw_imu_message(1, 0, 0, -1000, 0, 0, 0, 1, 2, 3, 0, 0), m, 3)
    p = tmp_path / "nan.tlog"
    p.write_bytes(data)
    c = read_log(p)
    assert c.params == {"INS_ACCOFFS_X": 0.25}
    assert any("COMPASS_MOT_X" in w and "nan" in w for w in c.messages)


def test_dispatch_by_content_not_extension(shared_data, tmp_path):
    """A tlog named .bin is read as a tlog, a dataflash log named .tlog as dataflash."""
    t = tmp_path / "really_a_tlog.bin"
    t.write_bytes((shared_data / "ardupilot/sitl_vtol.tlog").read_bytes())
    b = tmp_path / "really_a_bin.tlog"
    b.write_bytes((shared_data / "ardupilot/pixhawk1_copter368.bin").read_bytes())
    assert read_log(t).format == "tlog" and read_log(b).format == "bin"


# --- calibration parameters changed while the IMU samples were being recorded ----------------

def _param(name: str, value: float, index: int = 0):
    return mav2.MAVLink_param_value_message(name.encode(), value, 9, 4, index)


def _raw_imu(t_s: float):
    return mav2.MAVLink_raw_imu_message(int(t_s * 1e6), 0, 0, -1000, 0, 0, 0, 1, 2, 3, 0, 0)


def test_param_change_after_imu_start_is_reported(tmp_path):
    """Written with the simulator's TlogWriter. Only a calibration parameter that takes a new
    float32 value after the first IMU message counts: not identical repeats of the list (ground
    stations re-request it), not a change before the samples, not a non-calibration parameter."""
    from apmcal_sim.logwriter import TlogWriter

    m = v2()
    listing = {"INS_ACCOFFS_X": 0.1, "COMPASS_OFS_Y": -12.5, "AHRS_ORIENTATION": 0.0,
               "SYSID_THISMAV": 1.0}
    p = tmp_path / "change.tlog"
    unix0 = 1.7e9
    where = {}
    with TlogWriter(p) as w:
        for i, (k, v) in enumerate(listing.items()):
            w.write(unix0, _param(k, v, i).pack(m))
        w.write(unix0, _param("INS_ACCSCAL_Z", 1.0).pack(m))
        w.write(unix0, _param("INS_ACCSCAL_Z", 1.01).pack(m))      # before the samples: fine
        for k in range(1, 11):
            t = float(k)
            w.write(unix0 + t, _raw_imu(t).pack(m))
            if k == 3:   # the GCS downloads the list again: identical values are no change
                for i, (name, v) in enumerate(listing.items()):
                    w.write(unix0 + t, _param(name, v, i).pack(m))
            if k == 5:
                w.write(unix0 + t, _param("SYSID_THISMAV", 2.0).pack(m))   # not calibration
                where["x"] = w.f.tell()
                w.write(unix0 + t, _param("INS_ACCOFFS_X", 0.25).pack(m))
            if k == 8:
                where["y"] = w.f.tell()
                w.write(unix0 + t, _param("COMPASS_OFS_Y", 30.0).pack(m))
    c = read_log(p)
    assert [(ch.name, ch.old, ch.new, ch.time_s, ch.where) for ch in c.param_changes] == [
        ("INS_ACCOFFS_X", float(np.float32(0.1)), 0.25, 5.0, f"PARAM_VALUE at byte {where['x']}"),
        ("COMPASS_OFS_Y", -12.5, 30.0, 8.0, f"PARAM_VALUE at byte {where['y']}"),
    ]
    assert "INS_ACCOFFS_X changed from 0.1 to 0.25 at t=5.000 s (PARAM_VALUE at byte" in str(
        c.param_changes[0])
    assert c.params["INS_ACCOFFS_X"] == 0.25 and c.params["SYSID_THISMAV"] == 2.0  # last value
    assert c.params["INS_ACCSCAL_Z"] == pytest.approx(1.01)


def test_no_param_change_in_real_tlogs(shared_data):
    """In both real sessions the parameter list arrives after the IMU stream has started, some
    names more than once (sitl_vtol: 1147 PARAM_VALUE for 1053 names): no change is reported."""
    for name in TLOGS:
        assert read_log(shared_data / name).param_changes == []


@pytest.mark.parametrize("unix0, expected", [(1.7e9, 1.7e9), (12.5, None), (5e9, None)])
def test_start_time_from_the_first_frame_only_when_a_plausible_date(tmp_path, unix0, expected):
    """The ground station's clock of the first frame dates the recording (WMM field); a clock
    never set (seconds since boot) or a timestamp beyond 2100 is no date."""
    from apmcal_sim.logwriter import TlogWriter

    p = tmp_path / "clock.tlog"
    with TlogWriter(p) as w:
        for k in range(1, 4):
            w.write(unix0 + k, _raw_imu(float(k)).pack(v2()))
    assert read_log(p).start_unix_s == (None if expected is None else pytest.approx(expected + 1))


def test_start_time_of_a_real_session(shared_data):
    assert read_log(shared_data / "ardupilot" / "ardusub_small.tlog").start_unix_s == \
        pytest.approx(1683220541.055, abs=1e-3)      # 2023-05-04 17:15:41 UTC


def test_raw_imu_without_temperature_gets_the_barometers_interpolated(tmp_path):
    """APM 2.x RAW_IMU carries no temperature: SCALED_PRESSURE's (cdegC) is interpolated to the
    IMU sample times on the boot clock, NaN outside the barometer's samples, with a note."""
    from apmcal_sim.logwriter import TlogWriter

    p = tmp_path / "baro.tlog"
    with TlogWriter(p) as w:
        for k in range(6):                 # barometer at 0, 2, 4 s; IMU at 1, 3, 5 s
            if k % 2 == 0:
                temp_cdeg = {0: 2500, 2: 2600, 4: 2800}[k]
                w.write(1.7e9 + k, mav2.MAVLink_scaled_pressure_message(
                    k * 1000, 1013.0, 0.0, temp_cdeg).pack(v2()))
            else:
                w.write(1.7e9 + k, _raw_imu(float(k)).pack(v2()))
    c = read_log(p)
    (rec,) = c.recordings
    np.testing.assert_array_equal(rec.data["temp"].to_numpy(), [25.5, 27.0, np.nan])
    assert any("RAW_IMU[0] temp is the barometer's" in m for m in c.messages)


def test_barometer_temperature_is_not_attached_across_a_clock_restart(tmp_path):
    """Barometer times 1, 2, 3, then a reboot (0.5, 1.5), then 4 s: a time no longer says which
    boot a sample belongs to, so no temperature is attached (a note says why), as in the
    pymavlink reference."""
    from apmcal_sim.logwriter import TlogWriter

    p = tmp_path / "reboot.tlog"
    with TlogWriter(p) as w:
        for k, (t, temp_c) in enumerate([(1, 30), (2, 30), (3, 30), (0.5, 20), (1.5, 20),
                                         (4, 34)]):
            w.write(1.7e9 + k, mav2.MAVLink_scaled_pressure_message(
                int(t * 1000), 1013.0, 0.0, temp_c * 100).pack(v2()))
        w.write(1.7e9 + 7, _raw_imu(1.2).pack(v2()))
        w.write(1.7e9 + 8, _raw_imu(3.5).pack(v2()))
    c = read_log(p)
    assert "temp" not in c.recordings[0].data.columns
    assert any("clock jumps back" in m for m in c.messages)
    msgs = ref.pymavlink_messages(p, ref.TLOG_READ)
    assert ref.compare(c, ref.tlog_expected(msgs)) > 0


@pytest.mark.parametrize("version", ["v1", "v2"])
def test_only_the_autopilots_parameters_are_read(tmp_path, version):
    """A gimbal (component 154, autopilot INVALID) sends its own parameter list, with a name the
    autopilot also has: the vehicle's parameters are the autopilot's alone (component 1)."""
    from apmcal_sim.logwriter import TlogWriter

    dialect = mav1 if version == "v1" else mav2
    autopilot = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    gimbal = dialect.MAVLink(None, srcSystem=1, srcComponent=154)
    p = tmp_path / "components.tlog"
    with TlogWriter(p) as w:
        w.write(1.7e9, dialect.MAVLink_heartbeat_message(26, 8, 0, 0, 4, 3).pack(gimbal))
        w.write(1.7e9, dialect.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(autopilot))
        for mav, value in ((autopilot, 0.25), (gimbal, 7.0)):
            w.write(1.7e9, dialect.MAVLink_param_value_message(b"INS_ACCOFFS_X", value, 9, 1,
                                                               0).pack(mav))
        w.write(1.7e9 + 1, mav2.MAVLink_raw_imu_message(10**6, 0, 0, -1000, 0, 0, 0, 1, 2, 3, 0, 0)
                .pack(v2()))
    c = read_log(p)
    assert c.params == {"INS_ACCOFFS_X": 0.25}
    assert "note: 1 PARAM_VALUE from components other than the autopilot (1/1) ignored" in \
        c.messages
