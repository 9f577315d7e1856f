"""``apmcal tcal`` on the bundled warm-up log against its peer, timed in the same run.

    python benchmarks/tcal_speed.py [FILE] [--runs 3] [--peer PATH/TO/tempcal_IMU.py]

The peer is ArduPilot's ``Tools/scripts/tempcal_IMU.py`` (the script that fits INS_TCAL from a
log on a computer). It is not on PyPI, so it is run only where it is installed: ``--peer`` or
``tempcal_IMU.py`` on the PATH (it is run as ``python tempcal_IMU.py --no-graph FILE``, its
own defaults otherwise). Without it, the peer row is pymavlink's DFReader reading the same
file's IMU records — the part of the peer's work that any pymavlink-based tool pays before
fitting anything — and the script says which peer it ran.

Each command runs as a user runs it, in a fresh process (imports included), ``--runs`` times
alternating with the peer so that both see the same machine load; printed: the median wall
time and the CPU time (user + system of the child: on a shared machine the CPU time does not
count other processes' turns), and the ratios peer / apmcal of both.
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WARMUP = ROOT / "logs" / "warmup.bin"
DFREADER_IMU = ("import sys; from pymavlink import DFReader; "
                "log = DFReader.DFReader_binary(sys.argv[1]); "
                "n = 0\nwhile log.recv_match(type='IMU') is not None: n += 1\nprint(n)")


def timed(command: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system) of one child process running ``command``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, cwd=ROOT,
                   env=dict(os.environ, MPLBACKEND="Agg"))
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def peer_command(path: Path, given: str | None) -> tuple[str, list[str]]:
    """The peer's name and command: tempcal_IMU.py where installed, else DFReader's read."""
    script = given or shutil.which("tempcal_IMU.py")
    if script:
        return "ArduPilot tempcal_IMU.py", [sys.executable, script, "--no-graph", str(path)]
    return ("pymavlink DFReader reading the IMU records (tempcal_IMU.py not installed: it is "
            "not on PyPI; give its path with --peer)",
            [sys.executable, "-c", DFREADER_IMU, str(path)])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("file", nargs="?", default=str(WARMUP), help="a warm-up log "
                    "(default: logs/warmup.bin)")
    ap.add_argument("--runs", type=int, default=3, help="runs of each command (default 3)")
    ap.add_argument("--peer", default=None, help="path of ArduPilot's tempcal_IMU.py")
    args = ap.parse_args(argv)
    path = Path(args.file).resolve()
    peer_name, peer = peer_command(path, args.peer)
    ours = [sys.executable, "-m", "apmcal", "tcal", str(path), "--quiet"]
    mine, theirs = [], []
    for _ in range(args.runs):              # alternating: both see the same load
        mine.append(timed(ours))
        theirs.append(timed(peer))
    wall, cpu = (statistics.median(x[i] for x in mine) for i in (0, 1))
    peer_wall, peer_cpu = (statistics.median(x[i] for x in theirs) for i in (0, 1))
    print(f"{path.name} ({path.stat().st_size / 1e6:.2f} MB), median of {args.runs} fresh "
          f"processes each, load average {os.getloadavg()[0]:.1f}")
    print(f"  apmcal tcal: {wall:.2f} s wall, {cpu:.2f} s CPU")
    print(f"  peer, {peer_name}: {peer_wall:.2f} s wall, {peer_cpu:.2f} s CPU")
    print(f"ratio_vs_peer wall={peer_wall / wall:.2f} cpu={peer_cpu / cpu:.2f}")


if __name__ == "__main__":
    main()
