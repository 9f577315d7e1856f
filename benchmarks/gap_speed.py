"""How long ``apmcal gap`` takes on a ten-minute 400 Hz session, stage by stage.

    python benchmarks/gap_speed.py [--rate 400] [--seconds S] [--runs 3] [--before REV]

The session is simulated once with sitl (the ``diagnosis`` script, 635 s, or padded to
``--seconds`` with a still hold; the nominal errors plus temperature drift, a board warming
up) and kept in ``benchmarks/_data/``. Printed: the time to read it, to cut it into holds and
moves, to score the nominal model, to rank every candidate, to select a combination, to fit
the parameters on all the data, and in all; and, as the peer measured in the same run,
pymavlink's DFReader reading the same file's IMU records; then the whole command as a user runs
it, in a fresh process (imports included), ``--runs`` times, alternating with the same command of
revision ``--before`` (its apmcal and sitl exported with ``git archive``; default e130e47, main
before the speed work that began after it on 2026-11-24), so that both see the same machine
load. Issue 8's target: under 10 s on this 2-core machine.
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from end_to_end import export_tree  # the sibling benchmark (this script's folder is on the path)

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "_data"
BEFORE = "e130e47"      # main before the memo and the log read beside the imports


def make_session(path: Path, rate: float, seconds: float) -> None:
    from apmcal_sim.gap_benchmark import START_UNIX, truth_for
    from apmcal_sim.makelog import write_bin
    from apmcal_sim.vehicle import SimVehicle

    v = SimVehicle(truth_for(("temperature_drift",), 11), "diagnosis", "3.3", None, fs=rate,
                   seed=11, duration=seconds, start_unix=START_UNIX)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    v.reset_zero_compass_diagonals()
    write_bin(v, path, rate, v.motion.duration + 1.0)


def pymavlink_read(path: Path) -> float:
    from pymavlink import DFReader

    start = time.perf_counter()
    log = DFReader.DFReader_binary(str(path))
    while log.recv_match(type="IMU") is not None:
        pass
    return time.perf_counter() - start


def whole_command(path: Path, tree: Path = ROOT) -> tuple[float, float]:
    """Wall time of ``apmcal gap FILE`` as a user runs it — a fresh Python, the imports
    (scipy, pandas, sitl), the diagnosis and the printed summary — and the CPU time it took,
    user and system, its workers included [s]; ``tree``'s apmcal and sitl (run from
    benchmarks/_data: ``python -m`` would put the current directory first)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "apmcal", "gap", str(path), "--lat", "47.4",
                    "--lon", "8.5"], check=True, stdout=subprocess.DEVNULL, cwd=DATA, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=400.0)
    ap.add_argument("--seconds", type=float, default=None,
                    help="session length [s] (default: the diagnosis script's own, 635 s)")
    ap.add_argument("--runs", type=int, default=3, help="runs of the whole command (default 3)")
    ap.add_argument("--before", default=BEFORE,
                    help=f"revision to compare the whole command with (default {BEFORE}; "
                         "'none': no comparison)")
    args = ap.parse_args(argv)
    DATA.mkdir(exist_ok=True)
    path = DATA / f"gap_{int(args.rate)}hz_{int(args.seconds or 0) or 'script'}.bin"
    if not path.exists():
        print(f"simulating {path.name} ...", flush=True)
        make_session(path, args.rate, args.seconds)

    from apmcal.calibration.log import Options
    from apmcal.diagnosis.run import diagnose
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    times = {}
    start = t0 = time.perf_counter()
    contents = read_log(path)
    times["read"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    session = session_from_log(contents, Options(lat_deg=47.4, lon_deg=8.5))
    times["cut into holds and moves"] = time.perf_counter() - t0
    stage = {"name": None, "t0": time.perf_counter()}

    def progress(name: str) -> None:     # diagnose() announces each stage as it starts
        now = time.perf_counter()
        if stage["name"]:
            times[stage["name"]] = now - stage["t0"]
        stage.update(name=name, t0=now)

    diagnosis = diagnose(session, progress=progress)
    progress("")
    total = time.perf_counter() - start
    peer = pymavlink_read(path)
    before = None if args.before == "none" else export_tree(args.before)
    commands, commands_before = [], []
    for _ in range(args.runs):      # alternating: both see the same load
        commands.append(whole_command(path))
        if before is not None:
            commands_before.append(whole_command(path, before))
    command = statistics.median(w for w, _ in commands)
    cpu = statistics.median(c for _, c in commands)
    result = diagnosis.result
    print(f"{path.name}: {len(session.t)} IMU samples, {session.duration:.0f} s at "
          f"{session.fs:.0f} Hz; {sum(not e.get('not_tested') for e in result.effects)} "
          f"candidates tested; selected {', '.join(result.selected) or 'nothing'}")
    for name, seconds in times.items():
        print(f"  {name:28s} {seconds:7.2f} s")
    print(f"  {'total':28s} {total:7.2f} s   (target < 10 s)")
    walls = [w for w, _ in commands]
    print(f"  {'the whole command':28s} {command:7.2f} s   (`apmcal gap FILE` in a fresh "
          f"process, median of {args.runs}, min {min(walls):.2f}, max {max(walls):.2f}; "
          f"{command - total:.2f} s more than the diagnosis in this process; {cpu:.1f} "
          f"CPU-seconds)")
    if commands_before:
        was = [w for w, _ in commands_before]
        print(f"  {'the same command at ' + args.before:28s} {statistics.median(was):7.2f} s   "
              f"(min {min(was):.2f}, max {max(was):.2f}; "
              f"{statistics.median(c for _, c in commands_before):.1f} CPU-seconds): now "
              f"{statistics.median(was) / command:.2f}× as fast")
    print(f"  pymavlink DFReader reading the IMU records: {peer:.2f} s; apmcal gap in all "
          f"{total / peer:.1f}× that")


if __name__ == "__main__":
    main()
