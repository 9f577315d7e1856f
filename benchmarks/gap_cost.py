"""What ``apmcal gap`` costs — wall time, CPU time and peak memory — on a board with many faults,
and on an hour of it, against pymavlink's DFReader reading the same file, in the same run.

    python benchmarks/gap_cost.py [--runs 2] [--before REV] [--hour] [--stages]

Sessions (simulated once, kept in ``benchmarks/_data/``):

* ``alleffects``: ``python -m apmcal_sim.makelog --script diagnosis --rate 400 --fs 400`` — the
  diagnosis script's 636 s at 400 Hz with the simulator's default board, every effect on (as
  real boards have several);
* ``hour`` (with ``--hour``): the same board and script padded to 3600 s with a still hold
  (``--duration 3600``): 1.44 million IMU samples, 112 MB.

For each, alternating ``--runs`` times so that all see the same machine load: the whole
command as a user runs it (``apmcal gap FILE``, a fresh process, its forked workers included);
with ``--before REV`` the same command of revision REV (``git archive``'d; not on the hour,
which needed an estimated 10 GB before); and the peer,
pymavlink's ``DFReader_binary`` reading the file's IMU and MAG records to the end in a fresh
process. Each is measured from outside: wall time, CPU time (user + system of the process and
everything it forked), the largest resident set of any one process, and the peak of the sum
of the proportional set sizes (PSS: shared pages split between the processes sharing them) of
the process and all its descendants, sampled every 50 ms — the memory the command needs of
the machine. Printed as a Markdown table with the ratios to the peer.

With ``--stages``, where the memory goes instead: each session diagnosed once in a fresh
process as ``apmcal gap`` does it (read, cut, diagnose, its workers forked as the command forks
them), the same PSS sampler on that process tree, and for each stage the diagnosis announces
the peak PSS of the tree and of its largest process while the stage ran, and the seconds from
its first to its last sample (the diagnosis comes back to a stage after others announced in it:
those later stages then lie within its span).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

from end_to_end import export_tree  # the sibling benchmark (this script's folder is on the path)

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "_data"
SESSIONS = {"alleffects": ("gap_alleffects_400hz.bin", []),
            "hour": ("gap_alleffects_400hz_3600s.bin", ["--duration", "3600"])}
PEER = """
import sys
from pymavlink import DFReader
log = DFReader.DFReader_binary(sys.argv[1])
n = 0
while log.recv_match(type=["IMU", "MAG"]) is not None:
    n += 1
print(n)
"""


def session(name: str) -> Path:
    """The session's file, simulated when missing."""
    file, extra = SESSIONS[name]
    path = DATA / file
    if not path.exists():
        DATA.mkdir(exist_ok=True)
        print(f"simulating {file} ...", flush=True)
        subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", "diagnosis",
                        "--rate", "400", "--fs", "400", *extra, "--out", str(path)],
                       check=True, cwd=ROOT)
    return path


def _descendants(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            kids = [int(x) for x in f.read().split()]
    except OSError:
        return []
    return kids + [d for k in kids for d in _descendants(k)]


def _pss(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Pss:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def measured(cmd: list[str], env=None, cwd=None) -> dict:
    """Run ``cmd``; its wall [s], CPU [s] (its descendants included), largest resident set
    of one process [bytes] and peak PSS of the process tree [bytes]."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, env=env, cwd=cwd)
    peak = [0]

    def sample():
        while proc.poll() is None:
            total = sum(_pss(p) for p in [proc.pid] + _descendants(proc.pid))
            peak[0] = max(peak[0], total)
            time.sleep(0.05)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    sampler.join(1.0)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited with {proc.returncode}")
    return {"wall": wall, "cpu": usage.ru_utime + usage.ru_stime,
            "rss": usage.ru_maxrss * 1024, "pss": peak[0]}


STAGES = """
import json, os, sys, threading, time
sys.path.insert(0, sys.argv[2])
from gap_cost import _descendants, _pss
from apmcal.calibration.log import Options
from apmcal.diagnosis.run import diagnose
from apmcal.diagnosis.session.log import session_from_log
from apmcal.sources import read_log

me, stage, peaks, t0 = os.getpid(), ["read and cut"], {}, time.perf_counter()
done = threading.Event()

def sample():
    while not done.is_set():
        pss = {p: _pss(p) for p in [me] + _descendants(me)}
        name = stage[0]
        tree, top, first, last = peaks.get(name, (0, 0, time.perf_counter() - t0, 0))
        peaks[name] = (max(tree, sum(pss.values())), max(top, max(pss.values())), first,
                       time.perf_counter() - t0)
        time.sleep(0.05)

threading.Thread(target=sample, daemon=True).start()
session = session_from_log(read_log(sys.argv[1]), Options(lat_deg=47.4, lon_deg=8.5))
stage[0] = "(session read, before the diagnosis)"
time.sleep(0.2)

def progress(announced):
    if not announced.startswith("null session ") or announced.startswith("null sessions"):
        stage[0] = announced
diagnose(session, progress=progress)
done.set()
time.sleep(0.1)
print(json.dumps(peaks))
"""


def stage_memory(path: Path) -> list[tuple[str, float, float, float]]:
    """(stage, wall [s], peak PSS of the process tree [bytes], of its largest process
    [bytes]) per stage of one diagnosis of ``path`` in a fresh process."""
    import json

    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{ROOT}/sitl")
    out = subprocess.run([sys.executable, "-c", STAGES, str(path), str(Path(__file__).parent)],
                         env=env, cwd=DATA, check=True, capture_output=True, text=True).stdout
    peaks = json.loads(out.strip().splitlines()[-1])
    return [(name, last - first, tree, top) for name, (tree, top, first, last) in peaks.items()]


def gap_command(path: Path, tree: Path = ROOT) -> dict:
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    return measured([sys.executable, "-m", "apmcal", "gap", str(path)], env=env, cwd=DATA)


def peer(path: Path) -> dict:
    return measured([sys.executable, "-c", PEER, str(path)])


def median(runs: list[dict]) -> dict:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def row(what: str, m: dict, ref: dict | None) -> str:
    ratio = f"{m['wall'] / ref['wall']:.2f}× / {m['cpu'] / ref['cpu']:.2f}×" if ref else "1"
    return (f"| {what} | {m['wall']:.2f} | {m['cpu']:.2f} | {m['rss'] / 2**20:.0f} | "
            f"{m['pss'] / 2**20:.0f} | {ratio} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=2, help="runs of each command (median)")
    ap.add_argument("--before", default="none",
                    help="also the command of revision REV ('none': not)")
    ap.add_argument("--hour", action="store_true", help="also the one-hour session")
    ap.add_argument("--stages", action="store_true",
                    help="the peak memory of each stage of the diagnosis instead")
    args = ap.parse_args(argv)
    names = ["alleffects"] + (["hour"] if args.hour else [])
    if args.stages:
        for name in names:
            print(f"\n{name}: | stage | span [s] | peak PSS of all processes [MB] | "
                  "largest process [MB] |\n|---|---|---|---|")
            for stage, wall, tree, top in stage_memory(session(name)):
                print(f"| {stage} | {wall:.1f} | {tree / 2**20:.0f} | {top / 2**20:.0f} |",
                      flush=True)
        return 0
    before = None if args.before == "none" else export_tree(args.before)
    lines = ["| command | wall [s] | CPU [s] | largest process [MB] | peak PSS of all "
             "processes [MB] | / the peer (wall / CPU) |", "|---|---|---|---|---|---|"]
    for name in names:
        path = session(name)
        runs: dict = {"gap": [], "peer": [], "before": []}
        for _ in range(args.runs):
            runs["gap"].append(gap_command(path))
            runs["peer"].append(peer(path))
            if before is not None and name != "hour":   # the hour: ~10 GB before (issue)
                runs["before"].append(gap_command(path, before))
        ref = median(runs["peer"])
        size = path.stat().st_size / 1e6
        lines.append(row(f"{name} ({size:.0f} MB): `apmcal gap`", median(runs["gap"]), ref))
        if runs["before"]:
            lines.append(row(f"{name}: `apmcal gap` at {args.before}", median(runs["before"]),
                             ref))
        lines.append(row(f"{name}: pymavlink DFReader, IMU and MAG records", ref, None))
        print("\n".join(lines[-2 - bool(runs['before']):]), flush=True)
    load = os.getloadavg()
    print(f"\n(median of {args.runs}; load average {load[0]:.1f} at the end)")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
