"""The README's live demo, run as the README writes it: the bundled simulated vehicle turned
through ArduPilot's six poses by its simulated person, and `apmcal live --guide ardupilot6 --auto
--upload` recording, calibrating and uploading, in a fresh folder.

Two changes only, both to keep the suite short and parallel-safe: the simulator runs at 8×
real time (``--speedup 8``; the guide measures the holds in vehicle time, so what it accepts
is the same) and the UDP port is a free one instead of 14550.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from sim_operator import free_udp_port

ROOT = Path(__file__).resolve().parents[1]


def readme_demo() -> str:
    """The README's shell block that starts the simulated vehicle, as written."""
    blocks = re.findall(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    demo = [b for b in blocks if "python -m apmcal_sim" in b and "--guide ardupilot6" in b]
    assert len(demo) == 1, "the README has one live demo block"
    return demo[0]


def test_the_readme_live_demo_runs_as_written(tmp_path):
    demo = readme_demo()
    port = free_udp_port()
    script = (demo.replace("python -m apmcal_sim",
                           f"python -m apmcal_sim udpout:127.0.0.1:{port} --speedup 8")
              .replace("udp:127.0.0.1:14550", f"udp:127.0.0.1:{port}"))
    assert script.count(str(port)) == 2
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    proc = subprocess.Popen(["bash", "-c", script], cwd=tmp_path, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=240)
    finally:            # never a simulator left behind, whatever happened
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
    assert proc.returncode == 0, out[-3000:]
    assert "all six poses recorded" in out, out[-3000:]
    assert "rejected" not in out, out      # no pose rejected: not even the one just recorded
    verdict = next(line for line in out.splitlines() if line.startswith("verdict: "))
    assert verdict.startswith(("verdict: GOOD", "verdict: USABLE")), verdict
    assert "wrote and verified" in out and "apmcal restore" in out, out[-3000:]
    # the simulated vehicle's own store holds the uploaded calibration (it starts at 0)
    stored = json.loads((tmp_path / "sitl-params.json").read_text())
    assert all(stored[f"INS_ACCOFFS_{a}"] != 0 for a in "XYZ"), stored


def test_the_demo_vehicle_is_booted_before_a_ground_station_can_ask(tmp_path):
    """`apmcal live` started at once after the demo's vehicle (a loaded machine, a short
    sleep) must not fetch its parameters before the boot gyro calibration stores INS_GYROFFS:
    the recording would be refused. The first answer already holds the calibrated offsets."""
    from apmcal.sources.live import VehicleLink

    port = free_udp_port()
    sim = subprocess.Popen([sys.executable, "-m", "apmcal_sim", f"udpout:127.0.0.1:{port}",
                            "--script", "ardupilot6", "--firmware", "3.3"], cwd=tmp_path,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           start_new_session=True)
    try:
        with VehicleLink(f"udp:127.0.0.1:{port}", timeout_s=60.0) as link:
            first = link.fetch_params()
        assert first["INS_GYR_CAL"] == 1
        assert all(first[f"INS_GYROFFS_{a}"] != 0 for a in "XYZ"), first
    finally:
        os.killpg(sim.pid, signal.SIGKILL)
        sim.wait()
