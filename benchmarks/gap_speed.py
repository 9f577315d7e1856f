"""How long ``apmcal gap`` takes on a ten-minute 400 Hz session, stage by stage, against a peer.

    python benchmarks/gap_speed.py [--rate 400] [--seconds S] [--runs 3] [--repeat 2]
                                   [--before REV | --before none] [--stages-before REV]
                                   [--floor]

The session is simulated once with sitl (the ``diagnosis`` script, 635 s, or padded to
``--seconds`` with a still hold; the nominal errors plus temperature drift, a board warming
up) and kept in ``benchmarks/_data/``. Printed:

* the diagnosis stage by stage — read, cut into holds and moves, nominal model, candidate
  effects, null sessions (from each "null sessions for NAME" of the progress text to the
  stage announced after them, all together), combination, selected model — each run
  ``--repeat`` times in a fresh process, best of them: wall seconds
  and CPU seconds (this process and its forked workers, user + system); with
  ``--stages-before REV`` the same for revision REV, alternating;
* the whole command as a user runs it (``apmcal gap FILE``, a fresh process, imports and
  printed summary included), ``--runs`` times, alternating with the peer and with the same
  command of revision ``--before`` (its apmcal and simulator exported with ``git archive``;
  default e130e47, main before the speed work that began after it on 2026-11-24), so that all
  see the same machine load; median wall and CPU seconds;
* the peer, measured in the same run: pymavlink's DFReader reading the same file's IMU and
  MAG records (``recv_match(type=["IMU", "MAG"])`` to the end), in a fresh process each time
  too (the read timed, not the import), median wall and CPU seconds;
* with ``--floor``, the smallest diagnoses the command makes, in the same alternation: with
  one candidate only, ``--effects lowpass_filter`` (the nominal model at both rates, one
  effect scored at the recorded rate, the selected model and the reports) and ``--effects
  temperature_drift`` (the same with one effect scored on the block means instead, its null
  sessions drawn): what every diagnosis of this session costs before the other candidates;
* on the last line, the ratio of the whole command to the peer, CPU and wall. The issue's
  target: the whole command no slower than the peer (ratio ≤ 1), the null sessions included.
"""
from __future__ import annotations

import argparse
import json
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
# --floor: the smallest diagnoses, one candidate each: one scored at the recorded rate, one on
# the block means (with its null sessions)
FLOOR = ("lowpass_filter", "temperature_drift")


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


PEER = """
import resource, sys, time
from pymavlink import DFReader
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
start, c0 = time.perf_counter(), cpu()
log = DFReader.DFReader_binary(sys.argv[1])
n = 0
while log.recv_match(type=["IMU", "MAG"]) is not None:
    n += 1
print(time.perf_counter() - start, cpu() - c0, n)
"""


def pymavlink_read(path: Path) -> tuple[float, float, int]:
    """The peer: pymavlink's DFReader reading ``path``'s IMU and MAG records to the end, in a
    fresh process (the import not timed): (wall [s], CPU [s], records read)."""
    out = subprocess.run([sys.executable, "-c", PEER, str(path)], check=True,
                         capture_output=True, text=True).stdout.split()
    return float(out[0]), float(out[1]), int(out[2])


def _cpu() -> float:
    """CPU seconds of this process and its waited-for children (forked workers), user + system."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def stage_of(announced: str) -> str | None:
    """The benchmark's stage for a stage ``diagnose`` announces: its null sessions of both
    rates are one stage, "null sessions", and its candidates scored on the block means count in
    "candidate effects"; None for the progress of one null session (no new stage)."""
    if announced.startswith("null sessions"):
        return "null sessions"
    if announced.startswith("null session"):
        return None
    if announced.startswith("slow candidate effects"):
        return "candidate effects"
    return announced


def stage_times(path: Path) -> dict:
    """{stage: (wall [s], CPU [s])} of the diagnosis of ``path`` in this process; the stages
    as ``diagnose`` announces them, merged by :func:`stage_of`."""
    from apmcal.calibration.log import Options
    from apmcal.diagnosis.run import diagnose
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    times: dict = {}

    def add(name: str, wall: float, cpu: float) -> None:
        was = times.get(name, (0.0, 0.0))
        times[name] = (was[0] + wall, was[1] + cpu)

    start, cpu0 = time.perf_counter(), _cpu()
    t0, c0 = start, cpu0
    contents = read_log(path)
    add("read", time.perf_counter() - t0, _cpu() - c0)
    t0, c0 = time.perf_counter(), _cpu()
    session = session_from_log(contents, Options(lat_deg=47.4, lon_deg=8.5))
    add("cut into holds and moves", time.perf_counter() - t0, _cpu() - c0)
    stage = {"name": None, "t0": time.perf_counter(), "c0": _cpu()}

    def progress(announced: str) -> None:     # diagnose() announces each stage as it starts
        name = stage_of(announced)
        if name is None:
            return
        now, cpu = time.perf_counter(), _cpu()
        if stage["name"]:
            add(stage["name"], now - stage["t0"], cpu - stage["c0"])
        stage.update(name=name, t0=now, c0=cpu)

    diagnosis = diagnose(session, progress=progress)
    progress("")
    times["total"] = (time.perf_counter() - start, _cpu() - cpu0)
    result = diagnosis.result
    times["_about"] = (f"{path.name}: {len(session.t)} IMU samples, {session.duration:.0f} s "
                       f"at {session.fs:.0f} Hz; "
                       f"{sum(not e.get('not_tested') for e in result.effects)} candidates "
                       f"tested; selected {', '.join(result.selected) or 'nothing'}")
    return times


def stage_times_fresh(path: Path, tree: Path = ROOT) -> dict:
    """:func:`stage_times` in a fresh process (nothing cached from an earlier run), with
    ``tree``'s apmcal."""
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    out = subprocess.run([sys.executable, __file__, "--stages-of", str(path)], check=True,
                         capture_output=True, text=True, env=env).stdout
    return json.loads(out.strip().splitlines()[-1])


def print_stages(title: str, repeats: list) -> None:
    """The best of ``repeats`` (:func:`stage_times` results), stage by stage."""
    print(f"  {title}, best of {len(repeats)} (each in a fresh process):")
    print(f"  {'stage':28s} {'wall':>8s} {'CPU':>8s}")
    for name in repeats[0]:
        if not name.startswith("_"):
            wall = min(r[name][0] for r in repeats if name in r)
            cpu = min(r[name][1] for r in repeats if name in r)
            print(f"  {name:28s} {wall:7.2f}s {cpu:7.2f}s")


def whole_command(path: Path, tree: Path = ROOT, effects: str | None = None
                  ) -> tuple[float, float]:
    """Wall time of ``apmcal gap FILE`` as a user runs it — a fresh Python, the imports
    (scipy, pandas, sitl), the diagnosis and the printed summary — and the CPU time it took,
    user and system, its workers included [s]; ``tree``'s apmcal and sitl (run from
    benchmarks/_data: ``python -m`` would put the current directory first); ``effects``:
    its ``--effects`` (default: every candidate)."""
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    only = ["--effects", effects] if effects else []
    subprocess.run([sys.executable, "-m", "apmcal", "gap", str(path), "--lat", "47.4",
                    "--lon", "8.5", *only], check=True, stdout=subprocess.DEVNULL, cwd=DATA,
                   env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=400.0)
    ap.add_argument("--seconds", type=float, default=None,
                    help="session length [s] (default: the diagnosis script's own, 635 s)")
    ap.add_argument("--runs", type=int, default=3, help="runs of the whole command (default 3)")
    ap.add_argument("--repeat", type=int, default=2,
                    help="runs of the stage-by-stage diagnosis, each in a fresh process; the "
                         "best of them is printed (default 2)")
    ap.add_argument("--before", default=BEFORE,
                    help=f"revision to compare the whole command with (default {BEFORE}; "
                         "'none': no comparison)")
    ap.add_argument("--stages-before", default=None, metavar="REV",
                    help="also time the stages of revision REV, alternating (its apmcal must "
                         "have diagnosis.scoring.null)")
    ap.add_argument("--floor", action="store_true",
                    help="also time the command with one candidate only (--effects "
                         f"{' / '.join(FLOOR)}), alternating with the rest")
    ap.add_argument("--stages-of", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.stages_of is not None:      # one fresh run of stage_times_fresh
        print(json.dumps(stage_times(args.stages_of)))
        return
    DATA.mkdir(exist_ok=True)
    path = DATA / f"gap_{int(args.rate)}hz_{int(args.seconds or 0) or 'script'}.bin"
    if not path.exists():
        print(f"simulating {path.name} ...", flush=True)
        make_session(path, args.rate, args.seconds)

    before = None if args.before == "none" else export_tree(args.before)
    stages_before = None if args.stages_before is None else export_tree(args.stages_before)
    repeats, repeats_before = [], []
    for _ in range(max(args.repeat, 1)):        # alternating, as below
        repeats.append(stage_times_fresh(path))
        if stages_before is not None:
            repeats_before.append(stage_times_fresh(path, stages_before))
    commands, commands_before, peers = [], [], []
    floors: dict = {name: [] for name in (FLOOR if args.floor else ())}
    for _ in range(args.runs):      # alternating: all see the same load
        commands.append(whole_command(path))
        peers.append(pymavlink_read(path))
        if before is not None:
            commands_before.append(whole_command(path, before))
        for name, runs in floors.items():
            runs.append(whole_command(path, effects=name))
    print(repeats[0]["_about"])
    print_stages("the diagnosis stage by stage, with its forked workers", repeats)
    if repeats_before:
        print_stages(f"the same at {args.stages_before}", repeats_before)
    walls = [w for w, _ in commands]
    command = statistics.median(walls)
    cpu = statistics.median(c for _, c in commands)
    print(f"  {'the whole command':28s} {command:7.2f}s {cpu:7.2f}s   (`apmcal gap FILE` in a "
          f"fresh process, median of {args.runs}, wall min {min(walls):.2f}, "
          f"max {max(walls):.2f})")
    if commands_before:
        was = [w for w, _ in commands_before]
        was_cpu = statistics.median(c for _, c in commands_before)
        print(f"  {'the same command at ' + args.before:28s} {statistics.median(was):7.2f}s "
              f"{was_cpu:7.2f}s   (min {min(was):.2f}, max {max(was):.2f}): now "
              f"{statistics.median(was) / command:.2f}× as fast (wall), "
              f"{was_cpu / cpu:.2f}× (CPU)")
    peer_wall = statistics.median(w for w, _, _ in peers)
    peer_cpu = statistics.median(c for _, c, _ in peers)
    print(f"  {'pymavlink DFReader IMU+MAG':28s} {peer_wall:7.2f}s {peer_cpu:7.2f}s   "
          f"({peers[0][2]} records, median of {len(peers)})")
    for name, runs in floors.items():
        wall = statistics.median(w for w, _ in runs)
        print(f"  {'--effects ' + name:28s} {wall:7.2f}s "
              f"{statistics.median(c for _, c in runs):7.2f}s   (one candidate only: "
              f"{wall / peer_wall:.2f}× the peer's wall time)")
    print(f"apmcal gap / DFReader (IMU and MAG records): CPU {cpu / peer_cpu:.2f}×, "
          f"wall {command / peer_wall:.2f}×   (target ≤ 1)")


if __name__ == "__main__":
    main()
