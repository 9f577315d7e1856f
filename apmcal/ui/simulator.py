"""A simulated vehicle to try the live calibration with, started from the page: the bundled
simulator (``python -m apmcal_sim``, installed beside apmcal) run as a program of its own in
operator mode, the person at the page being the person at the vehicle.

The library never imports the simulator: it runs it as another process, when it is installed,
and turns it by typing on its operator console (a pose's name, or ``tumble`` for the compass
turn), as a person at a terminal would.
"""
from __future__ import annotations

import importlib.util
import socket
import subprocess
import sys
from pathlib import Path

from apmcal.core.errors import ApmcalError

#: what the page's buttons type on the simulator's console, and their words on the page
MOVES = {"level": "level", "left": "on its left side", "right": "on its right side",
         "nose down": "nose down", "nose up": "nose up", "back": "on its back",
         "tumble": "through every direction (40 s)"}


def available() -> bool:
    """True when the simulator is installed (``pip install .`` installs it)."""
    return importlib.util.find_spec("apmcal_sim") is not None


def free_udp_port() -> int:
    """A UDP port of 127.0.0.1 free now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Simulator:
    """One simulated vehicle process, sending to ``connection`` until :meth:`stop`.

    Parameters
    ----------
    folder : Path
        Its parameter store and console output.
    """

    def __init__(self, folder: Path):
        if not available():
            raise ApmcalError("the simulator (apmcal_sim) is not installed: pip install apmcal "
                              "from its source folder installs it")
        folder.mkdir(parents=True, exist_ok=True)
        port = free_udp_port()
        self.connection = f"udp:127.0.0.1:{port}"
        self.console = open(folder / "simulator-console.txt", "ab")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "apmcal_sim", f"udpout:127.0.0.1:{port}", "--script",
             "operator", "--param-file", str(folder / "simulated-vehicle-params.json")],
            stdin=subprocess.PIPE, stdout=self.console, stderr=subprocess.STDOUT,
            cwd=folder)

    def running(self) -> bool:
        """True while the process runs."""
        return self.process.poll() is None

    def move(self, move: str) -> None:
        """Turn the vehicle: one of :data:`MOVES`."""
        if move not in MOVES:
            raise ApmcalError(f"unknown move {move!r}: one of {', '.join(MOVES)}")
        if not self.running():
            raise ApmcalError("the simulated vehicle has stopped: start it again")
        try:
            self.process.stdin.write(f"{move}\n".encode())
            self.process.stdin.flush()
        except OSError:
            raise ApmcalError("the simulated vehicle has stopped: start it again") from None

    def stop(self) -> None:
        """End the process (terminate, then kill after 5 s)."""
        if self.running():
            self.process.terminate()
            try:
                self.process.wait(5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        for stream in (self.process.stdin, self.console):
            try:
                stream.close()
            except OSError:
                pass

