"""How long ``apmcal log`` takes on a ten-minute 400 Hz session, stage by stage, now and before.

    python benchmarks/end_to_end.py [--runs 5] [--before REF | --no-before] [--session FILE]

The session is simulated once with sitl (the ``diagnosis`` script: 632 s at 400 Hz with
accelerometer, gyro and compass — six faces, corner holds, turns about each axis, motors; a
dataflash .bin of 20 MB) and kept in ``benchmarks/_data/``. Measured in this one run, each in a
fresh process (so imports and the page cache are as for a user):

* ``import``: ``python -c "import apmcal.cli, apmcal.calibration.log, apmcal.sources"``;
* the stages of ``apmcal log SESSION --lat 47.4 --lon 8.5`` run in-process: read, prepare
  (parameter changes, time base, the firmware's correction undone, units check), static holds,
  each solver (ferraris / ellipsoid / one-position, magnetometer), parameters, report; times are
  exclusive (a stage called inside another is not counted twice), the rest is "other";
* ``whole process``: the wall time of ``python -m apmcal log ...`` (warm: after one run);
* ``apmcal --help``;
* the same for the code "before" (``--before``, default the commit this benchmark was written
  against), exported with ``git archive`` into the cache directory and run the same way;
* the peer: pymavlink's DFReader reading the same file's IMU and MAG records.

Times are the minimum over ``--runs`` runs (one for the slow "before" pipeline, ``--before-runs``)
— the machine is shared, the minimum is the least disturbed. Issue 10's targets: calibration
≤ 1 s beyond reading, whole process ≤ 2 s warm, ``apmcal --help`` ≤ 0.3 s.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "benchmarks" / "_data"
BEFORE = "545fc532e7c157f73b10a9933037596bef4fc6f9"     # main before issue 10's speed work
SITE = ["--lat", "47.4", "--lon", "8.5"]
TARGETS = {"beyond_read": 1.0, "whole_process": 2.0, "help": 0.3}

# (module, function, stage): wrapped with a timer in the measured process
STAGES = [
    ("apmcal.sources", "read_log", "read"),
    ("apmcal.sources.units", "require_plausible_units", "prepare"),
    ("apmcal.calibration.log", "pick_recording", "prepare"),
    ("apmcal.preprocessing.param_changes", "split_at_param_changes", "prepare"),
    ("apmcal.calibration.log", "prepare", "prepare"),
    ("apmcal.preprocessing.static", "find_static_segments", "static holds"),
    ("apmcal.preprocessing.ferraris_regions", "ferraris_regions", "static holds"),
    ("apmcal.solvers.ferraris", "ferraris_calibration", "solver: ferraris"),
    ("apmcal.solvers.holds", "ellipsoid_on_holds", "solver: ellipsoid"),
    ("apmcal.solvers.holds", "one_position_on_holds", "solver: one-position"),
    ("apmcal.solvers.magnetometer", "calibrate_magnetometer", "solver: magnetometer"),
    ("apmcal.ardupilot.params", "to_ardupilot_params", "parameters"),
    ("apmcal.report.text", "summarize", "report"),
    ("apmcal.report.text", "print_summary", "report"),
    ("apmcal.report.text", "print_calibration", "report"),
]


# ---------------------------------------------------------------- measured process (--child)

def _now() -> tuple[float, float]:
    """(wall clock, this process's CPU time) [s]."""
    return time.perf_counter(), time.process_time()


def _instrument(times: dict, cpu: dict, stack: list) -> None:
    """Wrap each STAGES function with an exclusive timer (children's time subtracted), wall
    clock into ``times`` and CPU time into ``cpu``."""
    import importlib

    def wrap(fn, stage):
        def timed(*args, **kwargs):
            stack.append([0.0, 0.0])
            w0, c0 = _now()
            try:
                return fn(*args, **kwargs)
            finally:
                w1, c1 = _now()
                inner = stack.pop()
                times[stage] = times.get(stage, 0.0) + (w1 - w0) - inner[0]
                cpu[stage] = cpu.get(stage, 0.0) + (c1 - c0) - inner[1]
                if stack:
                    stack[-1][0] += w1 - w0
                    stack[-1][1] += c1 - c0
        return timed

    for module, name, stage in STAGES:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError:     # a stage the code measured (e.g. the "before" tree) lacks
            continue
        setattr(mod, name, wrap(getattr(mod, name), stage))


def child(session: str) -> None:
    """Run ``apmcal log`` in this process and print its stage times (wall and CPU) as JSON
    (stdout's last line); the command's own output goes to /dev/null."""
    w0, c0 = _now()
    try:        # as `apmcal log` does before numpy loads (the code before this change did not)
        from apmcal.core.blas_threads import one_blas_thread_from_start
        one_blas_thread_from_start()
    except ImportError:
        pass
    import apmcal.calibration.log
    import apmcal.cli
    import apmcal.sources
    w1, c1 = _now()
    times, cpu = {"import": w1 - w0}, {"import": c1 - c0}
    _instrument(times, cpu, [])
    out = sys.stdout
    with open(os.devnull, "w") as null:
        sys.stdout = null
        try:
            status = apmcal.cli.main(["log", session, *SITE])
        finally:
            sys.stdout = out
    w2, c2 = _now()
    for clock, total in ((times, w2 - w0), (cpu, c2 - c0)):
        clock["total"] = total
        clock["other"] = total - sum(v for k, v in clock.items() if k != "total")
    print(json.dumps({"status": status, "times": times, "cpu": cpu}))


# ---------------------------------------------------------------- driver

def make_session(path: Path) -> None:
    """The diagnosis script at 400 Hz (accelerometer, gyro, compass), firmware 3.3, seed 11."""
    subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", "diagnosis", "--rate",
                    "400", "--fs", "400", "--firmware", "3.3", "--seed", "11", "--out",
                    str(path)], cwd=ROOT, check=True)


PACKAGES = ("apmcal", "apmcal_sim", "sitl")     # the package and its simulator, old name too


def export_tree(ref: str, folders: tuple | None = None) -> Path:
    """``ref``'s ``folders`` (git archive; default: those of :data:`PACKAGES` it has) in the
    cache directory, once per commit."""
    commit = subprocess.run(["git", "rev-parse", ref], cwd=ROOT, check=True, capture_output=True,
                            text=True).stdout.strip()
    if folders is None:
        listed = subprocess.run(["git", "ls-tree", "--name-only", commit], cwd=ROOT, check=True,
                                capture_output=True, text=True).stdout.split()
        folders = tuple(f for f in PACKAGES if f in listed)
    tree = DATA / f"tree-{commit[:12]}"
    if not all((tree / folder).is_dir() for folder in folders):
        tree.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "archive", commit, *folders], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def _run(tree: Path, argv: list[str]) -> tuple[float, str, float]:
    """(wall time [s], stdout, CPU time [s], user + system) of ``python argv`` with ``tree``
    first on the path."""
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, *argv], env=env, cwd=DATA, capture_output=True,
                          text=True, check=False)     # exit status 1 (a value withheld) is fine
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):
        raise RuntimeError(f"{argv} failed ({done.returncode}): {done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, done.stdout, cpu


def measure(tree: Path, session: Path, runs: int, whole: bool = True) -> dict:
    """Minimum over ``runs`` of: import, each stage, whole process, --help (after a warm-up
    read: .pyc files and the file's pages in place). ``whole=False`` (the slow
    "before" code) takes the in-process total of the staged run as the whole process."""
    _run(tree, ["-c", f"from apmcal.sources import read_log; read_log({str(session)!r})"])
    best: dict = {}

    def keep(name, value):
        best[name] = min(best.get(name, float("inf")), value)

    for _ in range(runs):
        wall, _, cpu = _run(tree, ["-c", "import apmcal.cli, apmcal.calibration.log, apmcal.sources"])
        keep("import", wall)
        keep("cpu import process", cpu)
        out = json.loads(_run(tree, [__file__, "--child", str(session)])[1].splitlines()[-1])
        for name, value in out["times"].items():
            keep("stage " + name, value)
        for name, value in out["cpu"].items():
            keep("cpu " + name, value)
        wall, _, cpu = (_run(tree, ["-m", "apmcal", "log", str(session), *SITE]) if whole
                        else (out["times"]["total"], "", out["cpu"]["total"]))
        keep("whole process", wall)
        keep("cpu whole process", cpu)
        wall, _, cpu = _run(tree, ["-m", "apmcal", "--help"])
        keep("help", wall)
        keep("cpu help", cpu)
    return best


def pymavlink_read(path: Path, runs: int) -> float:
    """Best time of pymavlink's DFReader reading the IMU and MAG records [s]."""
    from pymavlink import DFReader

    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        log = DFReader.DFReader_binary(str(path))
        while log.recv_match(type=["IMU", "MAG"]) is not None:
            pass
        best = min(best, time.perf_counter() - t0)
    return best


def report(now: dict, before: dict | None, peer: float) -> None:
    """The table (wall clock and CPU time; before/now of the wall clock), ratios, targets."""
    names = [k[6:] for k in now if k.startswith("stage ")]
    print(f"{'':26s} {'now [s]':>9s} {'CPU [s]':>9s} {'before [s]':>11s} {'before/now':>11s}")
    for name in ["import", *[f"stage {n}" for n in names], "whole process", "help"]:
        b = before.get(name) if before else None
        cpu = now.get("cpu " + (name[6:] if name.startswith("stage ") else
                                {"import": "import process"}.get(name, name)))
        ratio = f"{b / now[name]:10.1f}×" if b and now[name] > 0 else ""
        print(f"  {name:24s} {now[name]:9.3f} {'' if cpu is None else f'{cpu:9.3f}':>9s} "
              f"{'' if b is None else f'{b:11.3f}':>11s} {ratio}")
    read, total = now["stage read"], now["stage total"]
    print(f"  total / read: {total / read:.1f} (now)"
          + (f", {before['stage total'] / before['stage read']:.1f} (before)" if before else ""))
    print(f"  peer: pymavlink DFReader reading the IMU and MAG records {peer:.2f} s; "
          f"apmcal's read {peer / read:.0f}× faster, the whole `apmcal log` process "
          f"{now['whole process'] / peer:.2f}× the peer's read")
    beyond = total - now["stage import"] - read
    beyond_cpu = now["cpu total"] - now["cpu import"] - now["cpu read"]
    checks = [("calibration beyond reading (total − import − read)", beyond, beyond_cpu,
               "beyond_read"),
              ("whole process, warm", now["whole process"], now["cpu whole process"],
               "whole_process"),
              ("apmcal --help", now["help"], now["cpu help"], "help")]
    for label, value, cpu, key in checks:
        verdict = "met" if value <= TARGETS[key] else "NOT met"
        print(f"  target {label}: {value:.2f} s ≤ {TARGETS[key]} s: {verdict} "
              f"(CPU time {cpu:.2f} s: {'met' if cpu <= TARGETS[key] else 'NOT met'})")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--before", default=BEFORE, help="git ref of the code to compare with")
    ap.add_argument("--before-runs", type=int, default=1)
    ap.add_argument("--no-before", action="store_true")
    ap.add_argument("--session", type=Path, help="a log to use instead of the sitl session")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child)
        return
    DATA.mkdir(parents=True, exist_ok=True)
    session = args.session or DATA / "end_to_end_diagnosis_400hz.bin"
    if not session.exists():
        print(f"simulating {session.name} ...", flush=True)
        make_session(session)
    session = session.resolve()
    print(f"{session.name}: {session.stat().st_size / 1e6:.1f} MB; best of {args.runs} runs "
          f"(before: {args.before_runs}); load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores", flush=True)
    now = measure(ROOT, session, args.runs)
    before = None if args.no_before else measure(export_tree(args.before), session,
                                                 args.before_runs, whole=False)
    report(now, before, pymavlink_read(session, min(args.runs, 2)))
    print(f"  load average at the end {os.getloadavg()[0]:.1f} (other work on the machine "
          f"slows every stage alike)")


if __name__ == "__main__":
    main()
