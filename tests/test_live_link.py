"""Issue 9, the link to a vehicle: serial ports (--baud, pyserial) tried over a pseudo-terminal,
tcp refusals in one line, the faulty-HIGHRES_IMU firmware live, Ctrl-C, --version."""
import json
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_live_sitl import free_udp_port, wait_for_boot

from apmcal import cli
from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
SITL_QUIET = "motion_contamination,temperature_drift"


def start_sitl(tmp_path, connection, *extra, speedup: float = 4.0):
    """The simulated vehicle; a low ``speedup`` keeps it answering on a loaded machine (it
    advances its sensors to the wall clock before it reads what the ground station sent)."""
    return subprocess.Popen(
        [sys.executable, "-m", "apmcal_sim", connection, "--firmware", "3.3", "--speedup", str(speedup),
         "--param-file", str(tmp_path / "sitl-params.json"), "--disable", SITL_QUIET,
         "--write-truth", str(tmp_path / "truth.json"), *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stop(proc) -> None:
    proc.kill()
    proc.wait(timeout=10)


def first_line(proc, timeout_s: float = 60.0) -> str:
    """The first stdout line of ``proc`` (the sim prints its serial port there)."""
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    assert ready, f"no output from the simulator: {proc.stderr.read() if proc.poll() else ''}"
    return proc.stdout.readline().strip()


def test_serial_link_over_a_pseudo_terminal(tmp_path):
    """A USB / telemetry-radio APM: the sim on one end of a pty, apmcal on /dev/pts/N."""
    proc = start_sitl(tmp_path, "pty", "--script", "onepos", "--seed", "21")
    try:
        line = first_line(proc)
        assert line.startswith("serial port: /dev/"), line
        device = line.split(": ", 1)[1]
        wait_for_boot(tmp_path / "sitl-params.json")
        out = tmp_path / "serial.json"
        status = main(["live", device, "--baud", "57600", "--duration", "6", "--rate", "20",
                       "--quiet", "--save-log", str(tmp_path / "serial.tlog"),
                       "--json", str(out)])
    finally:
        stop(proc)
    assert status == 0
    result = json.loads(out.read_text())
    assert result["summary"]["param_count"] > 20          # the parameter list came through
    assert result["summary"]["recordings"][0]["samples"] > 20      # and the IMU stream
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert np.allclose([result["params"][f"INS_GYROFFS_{a}"] for a in "XYZ"],
                       truth["gyr"]["offset"], atol=5e-3)


@pytest.mark.parametrize("command", [["live", "/dev/ttyACM0"],
                                     ["upload", "/dev/ttyACM0", "x.param"],
                                     ["restore", "/dev/ttyACM0", "x.param"]])
def test_baud_reaches_pymavlink(monkeypatch, tmp_path, capsys, command):
    from pymavlink import mavutil

    seen = {}

    def fake_connection(device, **kwargs):
        seen.update(kwargs, device=device)
        raise OSError("no such port (test)")

    monkeypatch.setattr(mavutil, "mavlink_connection", fake_connection)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.param").write_text("INS_GYROFFS_X 0.01\n")
    assert main([*command, "--baud", "57600"]) == 2
    assert seen == {**seen, "device": "/dev/ttyACM0", "baud": 57600}
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "/dev/ttyACM0" in err[0] and "no such port" in err[0]


def test_baud_defaults_to_115200_and_refuses_nonsense(capsys):
    assert cli.build_parser().parse_args(["live", "/dev/ttyUSB0"]).baud == 115200
    with pytest.raises(SystemExit) as exc:
        main(["live", "/dev/ttyUSB0", "--baud", "fast"])
    assert exc.value.code == 2
    assert "baud" in capsys.readouterr().err


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_tcp_refusal_is_one_line_on_stderr_and_nothing_on_stdout(tmp_path):
    connection = f"tcp:127.0.0.1:{free_tcp_port()}"      # nobody listens there
    proc = subprocess.run([sys.executable, "-m", "apmcal", "live", connection, "--duration",
                           "1", "--save-log", str(tmp_path / "x.tlog")],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2
    assert proc.stdout == ""                    # pymavlink's "... sleeping" lines swallowed
    err = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and connection in err[0] and "refused" in err[0], proc.stderr


def test_live_faulty_highres_compass_firmware(tmp_path):
    """Firmware sending HIGHRES_IMU's field in mGauss×1000: the compass is calibrated from
    RAW_IMU and uploaded; the user is told about HIGHRES_IMU."""
    port = free_udp_port()
    proc = start_sitl(tmp_path, f"udpout:127.0.0.1:{port}", "--script", "tumble",
                      "--duration", "600", "--seed", "21", "--highres-mag-bug", speedup=2.0)
    out = tmp_path / "live.json"
    try:
        wait_for_boot(tmp_path / "sitl-params.json")
        status = main(["live", f"udp:127.0.0.1:{port}", "--duration", "12", "--rate", "20",
                       "--quiet",
                       "--save-log", str(tmp_path / "live.tlog"), "--json", str(out),
                       "--upload", "--backup", str(tmp_path / "backup.param")])
    finally:
        stop(proc)
    assert status == 0
    result = json.loads(out.read_text())
    sent = {r["message"]: r["sensors"] for r in result["summary"]["recordings"]}
    assert sent["HIGHRES_IMU"] == ["acc", "gyr"] and "mag" in sent["RAW_IMU"]
    assert any("HIGHRES_IMU[0] mag" in n and "e+08 mGauss" in n
               for n in result["summary"]["notes"])
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert np.allclose(result["mag"]["offset"], truth["mag"]["offset"], atol=5.0)
    uploaded = json.loads((tmp_path / "sitl-params.json").read_text())
    assert np.isclose(uploaded["COMPASS_OFS_X"], result["params"]["COMPASS_OFS_X"], atol=1e-3)


CTRL_C_DURING_IMPORTS = """
import builtins, runpy, sys
real_import = builtins.__import__

def ctrl_c_at(name, *args, **kwargs):      # Ctrl-C pressed while {module} is being imported
    if name.split(".")[0] == "{module}":
        raise KeyboardInterrupt
    return real_import(name, *args, **kwargs)

builtins.__import__ = ctrl_c_at
sys.argv = ["apmcal", "log", {log!r}]
runpy.run_module("apmcal", run_name="__main__", alter_sys=True)
"""


@pytest.mark.parametrize("module", ["pandas", "numpy", "pymavlink"])
def test_ctrl_c_during_start_up_exits_130_in_one_line(module):
    code = CTRL_C_DURING_IMPORTS.format(module=module, log=str(ROOT / "logs" / "onepos.tlog"))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip() == "apmcal: interrupted (Ctrl-C)"


def test_ctrl_c_while_recording_exits_130_and_keeps_the_recording(tmp_path):
    port = free_udp_port()
    sim = start_sitl(tmp_path, f"udpout:127.0.0.1:{port}", "--script", "onepos")
    log = tmp_path / "live.tlog"
    try:
        wait_for_boot(tmp_path / "sitl-params.json")
        proc = subprocess.Popen([sys.executable, "-m", "apmcal", "live", f"udp:127.0.0.1:{port}",
                                 "--duration", "600", "--quiet", "--save-log", str(log)],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        deadline = time.monotonic() + 60
        while not (log.exists() and log.stat().st_size > 20_000) and time.monotonic() < deadline:
            time.sleep(0.1)             # recording has begun once IMU samples fill the log
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        stop(sim)
    assert proc.returncode == 130, err
    assert err.strip() == "apmcal: interrupted (Ctrl-C)"
    assert log.stat().st_size > 20_000


def test_version_comes_from_the_package_metadata(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"apmcal {version('apmcal')}"


def test_only_the_rejected_sensor_is_withheld_from_an_upload(capsys):
    """A compass out of the firmware's limits does not stop the gyro's upload."""
    from types import SimpleNamespace

    from apmcal.ardupilot.limits import Writable
    from apmcal.ardupilot.params import ParamProposal

    def report(proposal):
        return SimpleNamespace(proposal=proposal, writable=Writable.sort(
            proposal.values, {}, proposal.rejected))

    proposal = ParamProposal(values={"INS_GYROFFS_X": 0.01, "INS_GYROFFS_Y": -0.02},
                             rejected={"COMPASS_OFS_X": "offset vector length 2500 > 1800"})
    console = cli.common.console_for(type("Args", (), {"quiet": False})())
    assert cli.live.values_to_upload(report(proposal), "udp:x", console) == proposal.values
    assert "COMPASS_OFS_X" in capsys.readouterr().out
    # nothing within the limits: nothing uploaded, said (the exit status is 1)
    assert cli.live.values_to_upload(report(ParamProposal(rejected=proposal.rejected)),
                                     "udp:x", console) == {}
    out = capsys.readouterr().out
    assert "COMPASS_OFS_X" in out and "nothing uploaded" in out


def test_a_missing_pyserial_is_named_in_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "serial", None)       # as if pyserial were not installed
    device = str(tmp_path / "ttyACM0")
    backup = tmp_path / "x.param"
    backup.write_text("INS_ACCOFFS_X 0.1\n")      # restore reads its file before connecting
    assert main(["restore", device, str(backup), "--baud", "57600"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and device in err[0] and "pip install pyserial" in err[0]


@pytest.mark.parametrize("command", ["live", "restore"])
def test_a_log_file_given_as_connection_is_refused_in_one_line(capsys, command, tmp_path):
    """pymavlink would read it as a log, and hang at its end (restore) or fail inside."""
    log = str(ROOT / "logs" / "onepos.tlog")
    backup = tmp_path / "x.param"
    backup.write_text("INS_ACCOFFS_X 0.1\n")      # restore reads its file before connecting
    args = [command, log, str(backup)] if command == "restore" else [command, log]
    assert main(args) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and log in err[0] and "apmcal log" in err[0]
