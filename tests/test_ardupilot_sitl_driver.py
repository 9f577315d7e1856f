"""The driver of ArduPilot's own firmware (sitl/ardupilot_sitl.py): it starts a fresh vehicle,
sets parameters by name and sees them echoed, poses the calibration model where it is told, and
never leaves a firmware process behind — after a failing test, a Ctrl-C, or its parent killed.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from ardupilot_sitl import ArduPilotSitl, SitlError, pwm_of_angle, pwm_of_rate

pytestmark = pytest.mark.ardupilot_sitl
ROOT = Path(__file__).resolve().parents[1]


def alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie awaiting its parent counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def wait_gone(pid: int, seconds: float = 10.0) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if not alive(pid):
            return True
        time.sleep(0.05)
    return False


def test_pwm_of_angle_and_rate_follow_the_calibration_model():
    # SIM_Calibration.cpp: angle = -π + 2π (PWM - 1000) / 1000; rate = 2π (PWM - 1300) / 700
    assert pwm_of_angle(0) == 1500 and pwm_of_angle(-180) == 1000 and pwm_of_angle(90) == 1750
    assert pwm_of_rate(2 * 3.141592653589793) == 2000 and pwm_of_rate(3.141592653589793) == 1650
    # an angle is taken into [-180, 180): 180° and a hair over it are -180° (a sweep's Euler
    # angles land there), not an error that would stop the model mid-session
    assert pwm_of_angle(180) == pwm_of_angle(180.0000001) == pwm_of_angle(-180) == 1000
    assert pwm_of_angle(270) == pwm_of_angle(-90) == 1250
    with pytest.raises(ValueError):
        pwm_of_angle(float("nan"))


def test_a_fresh_vehicle_takes_parameters_by_name_and_poses_where_told(ardupilot_sitl):
    sitl = ardupilot_sitl(speedup=100)
    assert sitl.get_param("SIM_ACC1_BIAS_X") == 0.0          # a factory-fresh store
    sitl.set_params({"SIM_ACC1_BIAS_X": 0.25, "COMPASS_OFS_X": 12.5})
    assert sitl.get_param("SIM_ACC1_BIAS_X") == pytest.approx(0.25)
    assert sitl.get_param("COMPASS_OFS_X") == pytest.approx(12.5)
    with pytest.raises(SitlError, match="NO_SUCH_PARAM"):
        sitl.set_params({"NO_SUCH_PARAM": 1.0}, attempts=1)
    for roll, pitch, yaw in [(180, 0, 0), (90, 0, 30), (0, -90, 0)]:
        sitl.pose(roll, pitch, yaw)
        truth = sitl.true_attitude()
        if abs(pitch) < 80:                         # roll and yaw are one angle at ±90° pitch
            assert abs((truth.roll - roll + 180) % 360 - 180) < 0.5
            assert abs((truth.yaw - yaw + 180) % 360 - 180) < 0.5
        assert abs(truth.pitch - pitch) < 0.5
    before = sitl.time_boot_s
    sitl.run_for(5.0)
    assert 5.0 <= sitl.time_boot_s - before < 6.0


def test_flushed_logs_cover_the_session_once_the_firmware_stops(ardupilot_sitl):
    """At 400× the dataflash writer runs behind the simulation and the firmware's stop loses
    what it has not written: after flush_logs the log reaches the session's end."""
    from pymavlink import DFReader

    sitl = ardupilot_sitl(speedup=400, boot_params={"LOG_DISARMED": 1})
    sitl.run_for(60.0)
    end_s = sitl.time_boot_s
    sitl.flush_logs()
    log = sitl.dataflash_logs()[-1]
    sitl.stop()
    reader, last_s = DFReader.DFReader_binary(str(log)), None
    while (msg := reader.recv_match(type="IMU")) is not None:
        last_s = msg.TimeUS * 1e-6
    assert last_s is not None and last_s >= end_s, (last_s, end_s)


def test_a_second_vehicle_gets_its_own_instance_and_ports(ardupilot_sitl):
    a, b = ardupilot_sitl(speedup=50), ardupilot_sitl(speedup=50)
    assert a.instance != b.instance and a.port != b.port and a.pid != b.pid
    a.set_params({"SIM_ACC1_BIAS_Y": 0.1})
    assert b.get_param("SIM_ACC1_BIAS_Y") == 0.0


def test_a_used_parameter_store_is_not_taken_for_a_fresh_one(tmp_path):
    (tmp_path / "eeprom.bin").write_bytes(b"\0" * 16)
    with pytest.raises(SitlError, match="eeprom.bin"):
        ArduPilotSitl(tmp_path)


def test_a_failing_test_leaves_no_firmware_running(tmp_path):
    pid = None
    with pytest.raises(ZeroDivisionError):
        with ArduPilotSitl(tmp_path / "v", speedup=50) as sitl:
            pid = sitl.pid
            assert alive(pid)
            raise ZeroDivisionError("a test failing while SITL runs")
    assert pid is not None and wait_gone(pid)


SCRIPT = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {sitl_dir!r})
    from ardupilot_sitl import ArduPilotSitl
    sitl = ArduPilotSitl({workdir!r}, speedup=50).start()
    # the link closed first: the firmware no longer dies of a write to a closed socket, so only
    # the driver's own safeguards can stop it
    sitl.master.close()
    print(sitl.pid, flush=True)
    {tail}
""")


def run_script(tmp_path, tail: str) -> tuple[subprocess.Popen, int]:
    code = SCRIPT.format(sitl_dir=str(ROOT / "sitl"), workdir=str(tmp_path / "v"), tail=tail)
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    pid = int(proc.stdout.readline())
    assert alive(pid)
    return proc, pid


@pytest.mark.parametrize("how", ["ctrl-c", "sigkill", "exit-without-stop"])
def test_no_firmware_outlives_the_process_that_started_it(tmp_path, how):
    # the exit waits for a line on stdin: the firmware is seen alive first
    tail = "sys.stdin.readline(); sys.exit(0)" if how == "exit-without-stop" else "time.sleep(60)"
    proc, pid = run_script(tmp_path, tail)
    if how == "exit-without-stop":
        proc.stdin.write("\n")
        proc.stdin.flush()
    elif how == "ctrl-c":
        proc.send_signal(signal.SIGINT)
    elif how == "sigkill":
        proc.kill()
    proc.wait(30)
    assert wait_gone(pid), f"SITL pid {pid} still running after the parent's {how}"
    if alive(pid):
        os.kill(pid, signal.SIGKILL)


FAILING_SESSION = textwrap.dedent("""
    import os, time
    from conftest import ardupilot_sitl   # noqa: F401  (the fixture under test)

    PID_FILE = {pid_file!r}

    def test_fails_while_the_firmware_runs(ardupilot_sitl):
        sitl = ardupilot_sitl(speedup=50)
        open(PID_FILE, "w").write(str(sitl.pid))
        assert False, "a test failing while SITL runs"

    def test_the_next_test_finds_it_stopped():
        pid = int(open(PID_FILE).read())
        deadline = time.monotonic() + 10
        while os.path.exists(f"/proc/{{pid}}") and time.monotonic() < deadline:
            stat = open(f"/proc/{{pid}}/stat").read().split(")")[-1].split()[0]
            if stat == "Z":
                break
            time.sleep(0.05)
        else:
            assert not os.path.exists(f"/proc/{{pid}}"), "SITL still running"
""")


def test_the_fixture_stops_the_firmware_of_a_failing_test_while_the_session_goes_on(tmp_path):
    """The pytest process lives on after the failure: only the fixture's finaliser can stop the
    firmware here (the firmware also exits by itself once the process that started it is gone,
    which the tests above see)."""
    (tmp_path / "test_session.py").write_text(
        FAILING_SESSION.format(pid_file=str(tmp_path / "pid")))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "tests"), str(ROOT / "sitl"),
                                                       str(ROOT)]))
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          "--rootdir", str(tmp_path), str(tmp_path / "test_session.py")],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert "1 failed, 1 passed" in out.stdout, out.stdout[-2000:]
