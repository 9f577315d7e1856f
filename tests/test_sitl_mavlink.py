"""The simulated vehicle over MAVLink: a loopback UDP session with pymavlink as the ground
station, stream rates, message intervals, operator (accel-cal) mode and the command line."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_helpers import messages, only

from apmcal_sim.mavlink_vehicle import MavlinkVehicle
from apmcal_sim.vehicle import SimVehicle, parse_pose_text

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def loopback(tmp_path):
    """(gcs connection, vehicle) with the vehicle served from a background thread."""
    port = _free_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    v = SimVehicle(only("acc_noise"), "onepos", "3.2", param_file=tmp_path / "p.json",
                   duration=600.0)
    ep = MavlinkVehicle(v, f"udpout:127.0.0.1:{port}", speedup=1.0)
    stop = threading.Event()

    def serve():
        while not stop.is_set():
            ep.poll()
            time.sleep(0.002)

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    yield gcs, v
    stop.set()
    th.join(5)
    ep.close()
    gcs.close()


def _recv(gcs, kind, timeout=3.0, cond=lambda m: True):
    end = time.time() + timeout
    while time.time() < end:
        m = gcs.recv_match(type=kind, blocking=True, timeout=0.2)
        if m is not None and cond(m):
            return m
    return None


def test_udp_session_params_and_stream_rate(loopback):
    gcs, v = loopback
    hb = gcs.wait_heartbeat(timeout=5)
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    gcs.mav.param_set_send(1, 1, b"INS_ACCOFFS_Y", -0.75, mavlink.MAV_PARAM_TYPE_REAL32)
    pv = _recv(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "INS_ACCOFFS_Y")
    assert pv is not None and pv.param_value == np.float32(-0.75)
    gcs.mav.param_set_send(1, 1, b"INS_ACCOFFS_Y", float("nan"), mavlink.MAV_PARAM_TYPE_REAL32)
    assert _recv(gcs, "PARAM_VALUE", timeout=1.0) is None           # dropped silently
    gcs.mav.param_request_list_send(1, 1)
    got = {}
    while len(got) < len(v.params):
        m = _recv(gcs, "PARAM_VALUE")
        assert m is not None, f"only {len(got)} of {len(v.params)} PARAM_VALUE"
        got[m.param_id] = m.param_value
    assert got["INS_ACCOFFS_Y"] == np.float32(-0.75)

    gcs.mav.request_data_stream_send(1, 1, mavlink.MAV_DATA_STREAM_RAW_SENSORS, 20, 1)
    assert _recv(gcs, "RAW_IMU") is not None
    t0, stamps = time.time(), []
    while time.time() - t0 < 2.0:
        m = gcs.recv_match(type="RAW_IMU", blocking=True, timeout=0.2)
        if m is not None:
            stamps.append(m.time_usec)
    wall_rate = len(stamps) / 2.0
    stamp_rate = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) * 1e-6)
    assert abs(stamp_rate / 20 - 1) < 0.01
    assert abs(wall_rate / 20 - 1) < 0.10
    # RAW_IMU reflects the offset just set (3.2: acc = raw − OFFS; level, no bias → +0.75 m/s²)
    assert abs(m.yacc - 0.75 * 1000 / 9.80665) < 25                  # noise ~9 mG
    assert v.params["SR0_RAW_SENS"] == 20


def test_message_interval_up_to_400hz_and_ack():
    v = SimVehicle(only(), "onepos", "3.3")
    v.pop_messages()
    for hz, msg_id in ((400, 27), (100, 105), (0, 116)):
        us = 1e6 / hz if hz else -1
        v.handle(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                      0, msg_id, us, 0, 0, 0, 0, 0))
    acks = messages(v, "COMMAND_ACK")
    assert [a.result for a in acks] == [mavlink.MAV_RESULT_ACCEPTED] * 3
    v.run_for(2.0)
    out = v.pop_messages()
    for kind, hz in (("RAW_IMU", 400), ("HIGHRES_IMU", 100)):
        ts = np.array([m.time_usec for _, m in out if m.get_type() == kind]) * 1e-6
        assert len(ts) == pytest.approx(2 * hz, abs=1)
        assert np.diff(ts).mean() == pytest.approx(1 / hz, rel=0.01)
    assert not any(m.get_type() == "SCALED_IMU2" for _, m in out)
    # 3.2 has no SET_MESSAGE_INTERVAL; REQUEST_DATA_STREAM is capped at 50 Hz
    v2 = SimVehicle(only(), "onepos", "3.2")
    v2.handle(mavlink.MAVLink_command_long_message(1, 1, 511, 0, 27, 2500, 0, 0, 0, 0, 0))
    assert messages(v2, "COMMAND_ACK")[0].result == mavlink.MAV_RESULT_UNSUPPORTED
    v2.handle(mavlink.MAVLink_request_data_stream_message(1, 1, 1, 200, 1))
    v2.run_for(1.0)
    assert len(messages(v2, "RAW_IMU")) == 50


def test_operator_mode_turns_on_request_and_refuses_accelcal_commands():
    """MAV_CMD_ACCELCAL_VEHICLE_POS is answered as the firmware does without its own accel cal
    running (MAV_RESULT_FAILED) and moves nothing; the operator turns the vehicle."""
    v = SimVehicle(only(), "operator", "3.3", record=True)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    v.set_interval("RAW_IMU", 10)
    v.run_for(1.0)
    v.handle(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_ACCELCAL_VEHICLE_POS, 0,
                                                  4, 0, 0, 0, 0, 0, 0))
    assert messages(v, "COMMAND_ACK")[0].result == mavlink.MAV_RESULT_FAILED
    assert [m.command for _, m in v.commands] == [mavlink.MAV_CMD_ACCELCAL_VEHICLE_POS]
    v.run_for(4.0)
    m = messages(v, "RAW_IMU")[-1]
    assert (m.xacc, m.yacc, m.zacc) == (0, 0, -1000)                  # still level
    v.goto_pose("nosedown")
    assert not v.motion_done()
    v.run_for(4.0)
    assert v.motion_done()
    m = messages(v, "RAW_IMU")[-1]
    assert (m.xacc, m.yacc, m.zacc) == (-1000, 0, 0)                  # nose down
    v.goto_pose(parse_pose_text("on its LEFT side"))
    v.run_for(4.0)
    m = messages(v, "RAW_IMU")[-1]
    assert (m.xacc, m.yacc, m.zacc) == (0, 1000, 0)
    labels = [s[0] for s in v.motion.sections()]
    assert labels == ["level", "transition", "nosedown", "transition", "left"]


def test_command_line_serves_and_writes_truth(tmp_path):
    port = _free_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    truth = tmp_path / "truth.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "apmcal_sim", f"udpout:127.0.0.1:{port}", "--firmware", "3.3",
         "--duration", "6", "--speedup", "4", "--seed", "9", "--write-truth", str(truth),
         "--param-file", str(tmp_path / "p.json"), "--disable", "acc_noise,gyro_noise"],
        cwd=ROOT, stderr=subprocess.PIPE)
    try:
        txt = _recv(gcs, "STATUSTEXT", timeout=20)
        assert txt is not None and txt.text == "ArduCopter V3.3.3 (sitl)"
        assert gcs.wait_heartbeat(timeout=5) is not None
    finally:
        assert proc.wait(timeout=30) == 0, proc.stderr.read().decode()
        gcs.close()
    d = json.loads(truth.read_text())
    assert d["effects"]["seed"] == 9 and d["effects"]["enabled"]["acc_noise"] is False
    assert set(d) >= {"acc", "gyr", "mag"}


def test_a_stalled_endpoint_lags_instead_of_bursting():
    """After a stall the simulated clock advances at most MAX_CATCH_UP_S of wall time per poll
    (a burst would overflow the ground station's UDP buffer)."""
    v = SimVehicle(only(), "operator", "3.3")
    ep = MavlinkVehicle(v, f"udpout:127.0.0.1:{_free_port()}", speedup=4.0)
    try:
        ep.poll()
        time.sleep(0.6)                      # 2.4 s of simulated time owed
        ep.poll()
        assert v.t <= ep.MAX_CATCH_UP_S * 4.0 + 0.05
        ep.call_soon(lambda vehicle: vehicle.goto_pose("back"))
        ep.poll()
        assert v.motion.sections()[-1][0] == "back"
    finally:
        ep.close()


def test_operator_console_turns_the_vehicle_to_typed_poses():
    import io

    from apmcal_sim.__main__ import start_operator_console

    class Endpoint:
        calls = []

        def call_soon(self, fn):
            self.calls.append(fn)

    ep, out, v = Endpoint(), io.StringIO(), SimVehicle(only(), "operator", "3.3")
    start_operator_console(ep, io.StringIO("nose down\nsideways\nback\n"), out)
    deadline = time.monotonic() + 5
    while len(ep.calls) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    for fn in ep.calls:
        fn(v)
    assert [s[0] for s in v.motion.sections()][-3:] == ["nosedown", "transition", "back"]
    assert "no pose in 'sideways'" in out.getvalue()
