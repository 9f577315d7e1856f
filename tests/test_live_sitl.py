"""`apmcal live` against the simulated vehicle over loopback UDP: record, calibrate, upload
(backed up, verified), then `apmcal restore`."""
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from apmcal.ardupilot.paramfile import read_param_file
from apmcal.cli import main
from apmcal.sources.live import VehicleLink

ROOT = Path(__file__).resolve().parents[1]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_boot(param_file: Path, timeout_s: float = 60.0) -> None:
    """Wait until the vehicle's boot gyro calibration (INS_GYR_CAL=1) has stored INS_GYROFFS.

    A fixed sleep is not enough on a loaded machine: starting the simulator's Python alone can
    take seconds, and a recording begun before the boot calibration ends is (rightly) refused.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if json.loads(param_file.read_text()).get("INS_GYROFFS_X", 0.0) != 0.0:
                return
        except (OSError, ValueError):       # not written yet, or caught mid-write
            pass
        time.sleep(0.1)
    raise TimeoutError(f"simulated vehicle did not finish its boot calibration ({param_file})")


@pytest.fixture
def vehicle(tmp_path):
    port = free_udp_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "apmcal_sim", f"udpout:127.0.0.1:{port}", "--script", "onepos",
         "--firmware", "3.3", "--speedup", "4", "--seed", "21",
         "--param-file", str(tmp_path / "sitl-params.json"),
         "--disable", "motion_contamination,temperature_drift",
         "--write-truth", str(tmp_path / "truth.json")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    wait_for_boot(tmp_path / "sitl-params.json")
    yield f"udp:127.0.0.1:{port}", tmp_path
    proc.kill()
    proc.wait(timeout=10)


def test_live_record_calibrate_upload_restore(vehicle):
    connection, tmp = vehicle
    out, backup = tmp / "live.json", tmp / "backup.param"
    status = main(["live", connection, "--duration", "12", "--rate", "50", "--quiet",
                   "--save-log", str(tmp / "live.tlog"), "--json", str(out),
                   "--upload", "--backup", str(backup), "--lat", "5.6037", "--lon", "-0.187"])
    assert status == 0
    result = json.loads(out.read_text())
    proposed = result["params"]
    assert set(proposed) == {"INS_GYROFFS_X", "INS_GYROFFS_Y", "INS_GYROFFS_Z"}   # one pose

    # the recording is a tlog of its own, with the parameters in force
    assert (tmp / "live.tlog").stat().st_size > 10_000
    before = read_param_file(backup)
    assert "INS_GYROFFS_X" in before and len(before) > 20

    with VehicleLink(connection) as link:
        for name, value in proposed.items():
            assert np.float32(link.read_param(name)) == np.float32(value)

    # the uploaded gyro offsets are the truth's bias plus what one pose cannot separate from it
    # (g-sensitivity x g, Earth rate: a few mrad/s, see test_end_to_end)
    truth = json.loads((tmp / "truth.json").read_text())
    assert np.allclose([proposed[f"INS_GYROFFS_{a}"] for a in "XYZ"], truth["gyr"]["offset"],
                       atol=5e-3)

    assert main(["restore", connection, str(backup)]) == 0
    with VehicleLink(connection) as link:
        for name in proposed:
            assert np.float32(link.read_param(name)) == np.float32(before[name])


def test_live_without_vehicle_fails_in_one_line(capsys, tmp_path):
    port = free_udp_port()
    log = tmp_path / "never.tlog"
    status = main(["live", f"udp:127.0.0.1:{port}", "--duration", "1", "--save-log", str(log)])
    assert status == 2
    assert not log.exists()                  # nothing recorded, nothing left behind
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "HEARTBEAT" in err[0]


def test_live_refuses_a_recording_whose_parameters_changed(tmp_path, capsys):
    """Connecting during the boot gyro calibration: RAW_IMU's correction changes mid-recording."""
    port = free_udp_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "apmcal_sim", f"udpout:127.0.0.1:{port}", "--script", "onepos",
         "--firmware", "3.3", "--speedup", "0.25", "--param-file", str(tmp_path / "p.json")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        # boot calibration ends 1 s simulated = 4 s wall after start: inside the recording
        status = main(["live", f"udp:127.0.0.1:{port}", "--duration", "6", "--quiet",
                       "--save-log", str(tmp_path / "live.tlog")])
    finally:
        proc.kill()
        proc.wait(timeout=10)
    assert status == 2
    assert "INS_GYROFFS_X" in capsys.readouterr().err


# the guided six-pose session (--guide ardupilot6): tests/test_guided.py
