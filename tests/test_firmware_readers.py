"""apmcal's readers on the logs ArduPilot's own firmware (SITL) writes: a telemetry log with
HIGHRES_IMU, RAW_IMU, SCALED_IMU2/3 and the full parameter list, and dataflash logs with
instance-numbered IMU and MAG records, BAT, XKF* and PARM with about 1,350 values, from the
calibration model and from a flying quad — every value as pymavlink reads it.
"""
from __future__ import annotations

import pymavlink_ref as ref
import pytest

from apmcal.sources import read_log

pytestmark = pytest.mark.ardupilot_sitl

STREAMS = {27: 50.0, 116: 50.0, 129: 50.0, 105: 50.0, 1: 2.0, 29: 10.0}   # RAW_IMU, SCALED_IMU2/3,
# HIGHRES_IMU, SYS_STATUS, SCALED_PRESSURE: what apmcal's tlog reader turns into recordings


@pytest.fixture(scope="module")
def firmware_logs(tmp_path_factory):
    """(tlog, dataflash log) of the calibration model turning, and the dataflash log of a short
    quad flight (take-off, a yaw turn, landing)."""
    from ardupilot_sitl import ArduPilotSitl, unavailable_reason

    if unavailable_reason():
        pytest.skip(unavailable_reason())
    base = tmp_path_factory.mktemp("firmware-logs")
    with ArduPilotSitl(base / "calibration", speedup=100, boot_params={"LOG_DISARMED": 1}) as sitl:
        for message_id, rate in STREAMS.items():
            sitl.request_message(message_id, rate)
        sitl.all_params()                               # the whole table into the tlog
        sitl.pose(90, 0, 0)
        sitl.spin(1.0, (1, 1, 0))
        sitl.run_for(10)
    calibration_bin = sitl.dataflash_logs()[-1]
    with ArduPilotSitl(base / "quad", model="quad", speedup=100) as sitl:
        sitl.takeoff(10)
        sitl.fly_to(0, 0, 10, seconds=8, yaw_rate_deg_s=45)
        sitl.land()
    return sitl.tlog.parent.parent / "calibration" / "sitl.tlog", calibration_bin, \
        sitl.dataflash_logs()[-1]


def test_the_firmwares_tlog_reads_as_pymavlink_reads_it(firmware_logs):
    path = firmware_logs[0]
    contents = read_log(path)
    msgs = ref.pymavlink_messages(path, ref.TLOG_READ + ["PARAM_VALUE"])
    n = ref.compare(contents, ref.tlog_expected(msgs))
    assert n > 1000
    assert contents.params == ref.expected_params(msgs) and len(contents.params) > 1300
    assert {r.message for r in contents.recordings} >= {"RAW_IMU", "HIGHRES_IMU", "SCALED_IMU2"}


@pytest.mark.parametrize("which", [1, 2], ids=["calibration-model", "quad-flight"])
def test_the_firmwares_dataflash_logs_read_as_dfreader_reads_them(firmware_logs, which):
    path = firmware_logs[which]
    contents = read_log(path)
    msgs = ref.pymavlink_messages(path, None)
    n = ref.compare(contents, ref.df_expected(msgs))
    assert n > 1000
    assert contents.params == ref.expected_params(msgs) and len(contents.params) > 1300
    types = {m.get_type() for m in msgs}
    assert {"IMU", "MAG", "BAT", "PARM"} <= types
    if which == 2:
        assert {"XKF1", "XKF4"} <= types
    keys = {(r.message, r.instance) for r in contents.recordings}
    assert ("IMU", 0) in keys and ("IMU", 1) in keys and ("MAG", 0) in keys
