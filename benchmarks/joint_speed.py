"""The joint method's time against the ellipsoid method's on the same hand-held session, and its
results against the joint solver of an earlier revision.

    python benchmarks/joint_speed.py [--before REV] [--runs 3] [--command-runs 3] [--log FILE]
                                     [--real-only]

The session: a 250 s hand-held sitl session at 100 Hz with accelerometer, gyro and compass
(``python -m apmcal_sim.makelog --script handheld --seed 11 --rate 100 --fs 100 --duration 250``,
made once into ``benchmarks/_data/``), or ``--log FILE`` (another session, to check the
results on data the changes were not tuned on; the site stays sitl's). Both methods run in
this process on the log read once, through ``apmcal.calibration.log.calibrate_log`` (what
``apmcal log FILE --method ellipsoid`` and ``--method joint`` run after reading; BLAS
single-threaded, as ``apmcal log`` runs), best of ``--runs`` after a warm-up run of each
(imports left out: scipy.optimize's import, ~0.3 s of CPU, comes with the joint method's first
fit in a process), wall and CPU seconds (the machine may be shared: the CPU time does not count
other processes' turns). Then the joint fit of revision ``--before`` (default: main; its apmcal
and simulator exported with ``git archive``) runs on the same file in a fresh process (best of
``--runs``: the first pays the imports), and every parameter both fits estimate is compared:
the largest change in units of the earlier fit's σ is printed, with the range of the σ
ratios, and the check fails (exit status 1) when a parameter moved by more than
``MAX_CHANGE_SIGMA`` σ, a σ changed by more than ``MAX_SIGMA_CHANGE`` (relative), or the two
fits estimate or drop different parameters.

Then the same identity check on every real recording the out-of-sample checks use
(``apmcal.calibration.validation.REAL_RECORDINGS``: imucal's session, imu_tk's Xsens sequence,
the MPU-6050 run; absent without ../shared/data): each brought to SI units and to the joint
fit's 50 Hz as the command line does, saved once, and fitted by the joint solver of this tree
and of ``--before``, each in a fresh process (:func:`real_identity`): the same parameters
estimated and dropped, none moved by more than ``MAX_CHANGE_SIGMA`` σ, no σ changed by more
than ``MAX_SIGMA_CHANGE``. A speed change must pass it on the real recordings as on the
simulated session (``--real-only`` runs it alone).

Last, the whole commands, as a user runs them: ``apmcal log FILE --method joint`` and
``--method ellipsoid`` (``--lat/--lon`` of the site, ``--quiet``), each in a fresh process
(reading the log, imports and the report included), best of ``--command-runs`` by CPU time
(user + system of the child), for this tree and for the joint method of ``--before``.
The 4× target is the calibration stage's (``ratio_joint_vs_ellipsoid_cpu``); the whole
commands' ratio (``ratio_command_joint_vs_ellipsoid_cpu``) is printed beside it.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "benchmarks" / "_data"
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator
sys.path.insert(0, str(ROOT / "benchmarks"))

SESSION = DATA / "joint_speed_handheld.bin"
SITE = {"lat_deg": 5.6037, "lon_deg": -0.187,          # sitl's default home and the date
        "date": datetime.date(2026, 5, 28)}            # apmcal_sim.makelog's logs carry
TARGET_RATIO = 4.0
MAX_CHANGE_SIGMA = 0.1      # "results unchanged": no parameter moved by more than this many σ
MAX_SIGMA_CHANGE = 0.01     # ... and no σ changed by more than 1 %

# run in a fresh process with an exported tree first on the path: time and parameters as JSON
_CHILD = r"""
import datetime, json, sys, time
import numpy, scipy.linalg  # the BLAS libraries loaded, so that the limit below reaches them
from threadpoolctl import threadpool_limits
threadpool_limits(1, user_api="blas")
from apmcal.calibration.log import Options, calibrate_log
from apmcal.sources import read_log
site = json.loads(sys.argv[2]); site["date"] = datetime.date.fromisoformat(site["date"])
contents = read_log(sys.argv[1])
best = None
for _ in range(int(sys.argv[3])):
    w0, c0 = time.perf_counter(), time.process_time()
    cal, _ = calibrate_log(contents, Options("joint", **site))
    took = (time.perf_counter() - w0, time.process_time() - c0)
    best = took if best is None or took[1] < best[1] else best
print(json.dumps({"wall": best[0], "cpu": best[1], "parameters": cal.report.joint.parameters,
                  "dropped": cal.report.joint.dropped_t_test}))
"""


# the joint solver of whichever tree is first on the path, on a session saved by
# real_sessions(): parameters, σ and the dropped set as JSON
_CHILD_REAL = r"""
import json, sys
import numpy as np
from threadpoolctl import threadpool_limits
threadpool_limits(1, user_api="blas")
from apmcal.preprocessing.static import find_static_segments
from apmcal.solvers.joint.solve import joint_calibration
z = np.load(sys.argv[1])
mag = z["mag"] if z["mag"].size else None
holds = find_static_segments(z["t"], z["acc"], z["gyr"], min_duration=1.0)
cal = joint_calibration(z["t"], z["acc"], z["gyr"], mag, holds, gravity=float(z["gravity"]))
print(json.dumps({"parameters": cal.report.joint.parameters,
                  "dropped": cal.report.joint.dropped_t_test}))
"""


def real_sessions() -> list[tuple[str, Path]]:
    """(name, .npz) of each real recording of the out-of-sample checks, whole, in SI units at
    the joint fit's rate (apmcal.calibration.joint.at_joint_rate), saved once into
    benchmarks/_data/; [] without ../shared/data."""
    import numpy as np

    from apmcal.calibration.joint import at_joint_rate
    from apmcal.calibration.validation import REAL_RECORDINGS, session
    from apmcal.core.constants import STANDARD_GRAVITY

    shared = ROOT.parent / "shared" / "data"
    out = []
    for rec in {r.file: r for r in REAL_RECORDINGS}.values():
        if not (shared / rec.file).exists():
            continue
        path = DATA / f"joint_real_{Path(rec.file).stem}.npz"
        if not path.exists():
            DATA.mkdir(parents=True, exist_ok=True)
            _, _, raw, mag, _ = session(shared / rec.file, rec.layout, rec.counts)
            t, acc, gyr, mag, _ = at_joint_rate(raw.t, raw.xyz("acc"), raw.xyz("gyr"), mag)
            np.savez(path, t=t, acc=acc, gyr=gyr, mag=np.zeros(0) if mag is None else mag,
                     gravity=STANDARD_GRAVITY)
        out.append((rec.file, path))
    return out


def real_identity(before_tree: Path, before: str) -> bool:
    """The joint solver of this tree against ``before_tree``'s on every real recording
    (:func:`real_sessions`), fresh processes; True when every result is unchanged."""
    same = True
    for name, path in real_sessions():
        fits = []
        for tree in (ROOT, before_tree):
            env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
            done = subprocess.run([sys.executable, "-c", _CHILD_REAL, str(path)], env=env,
                                  cwd=DATA, capture_output=True, text=True, check=True)
            fits.append(json.loads(done.stdout.strip().splitlines()[-1]))
        print(f"real recording {name}:")
        same &= compare(fits[0]["parameters"], fits[1]["parameters"], fits[0]["dropped"],
                        fits[1]["dropped"], before)
    return same


def make_session() -> Path:
    if not SESSION.exists():
        from apmcal_sim.makelog import main as makelog
        DATA.mkdir(parents=True, exist_ok=True)
        print(f"simulating {SESSION.name} ...", flush=True)
        if makelog(["--script", "handheld", "--out", str(SESSION), "--seed", "11", "--rate",
                    "100", "--fs", "100", "--duration", "250"]) != 0:
            raise SystemExit("apmcal_sim.makelog failed")
    return SESSION


def timed(contents, method: str, runs: int):
    """(best wall [s], best CPU [s], the last Calibration) of calibrate_log with ``method``."""
    from threadpoolctl import threadpool_limits

    from apmcal.calibration.log import Options, calibrate_log
    threadpool_limits(1, user_api="blas")      # as ``apmcal log`` runs (core/blas_threads.py)
    best = None
    for _ in range(runs):
        w0, c0 = time.perf_counter(), time.process_time()
        cal, _ = calibrate_log(contents, Options(method, **SITE))
        took = (time.perf_counter() - w0, time.process_time() - c0)
        best = took if best is None or took[1] < best[1] else best
    return best[0], best[1], cal


def joint_in(tree: Path, session: Path, runs: int) -> dict:
    site = dict(SITE, date=SITE["date"].isoformat())      # (its first run includes the imports)
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    done = subprocess.run([sys.executable, "-c", _CHILD, str(session), json.dumps(site),
                           str(runs)], env=env, cwd=DATA, capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def command(tree: Path, session: Path, method: str, runs: int) -> tuple[float, float]:
    """(best wall [s], its CPU [s]) of ``apmcal log SESSION --method METHOD`` in fresh processes
    with ``tree`` first on the path, best of ``runs`` by CPU time (user + system)."""
    argv = [sys.executable, "-m", "apmcal", "log", str(session), "--method", method,
            "--lat", str(SITE["lat_deg"]), "--lon", str(SITE["lon_deg"]), "--quiet"]
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    best = None
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        done = subprocess.run(argv, env=env, cwd=DATA, capture_output=True, text=True)
        wall = time.perf_counter() - w0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if done.returncode not in (0, 1):      # 1: a value withheld, still a full run
            raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}): {done.stderr[-500:]}")
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        best = (wall, cpu) if best is None or cpu < best[1] else best
    return best


def compare(now: dict, old: dict, dropped_now: list, dropped_old: list, before: str) -> bool:
    """Print the largest parameter change [σ of ``old``] and the σ ratios; True when the
    results are unchanged (module docstring)."""
    common = sorted(set(now) & set(old))
    changes = {n: abs(now[n][0] - old[n][0]) / old[n][1] for n in common if old[n][1] > 0}
    worst = max(changes, key=changes.get)
    ratios = [now[n][1] / old[n][1] for n in common if old[n][1] > 0]
    only = sorted(set(now) ^ set(old))
    print(f"parameters compared: {len(common)}; estimated in one fit only: {only or 'none'}; "
          f"dropped by the t-test: {'the same' if dropped_now == dropped_old else 'DIFFERENT'} "
          f"({len(dropped_now)})")
    print(f"largest change against {before}: {changes[worst]:.3f} σ ({changes[worst]:.1e}; {worst}); "
          f"σ ratio new/old {min(ratios):.3f}-{max(ratios):.3f}")
    same = (not only and dropped_now == dropped_old and changes[worst] <= MAX_CHANGE_SIGMA
            and max(abs(r - 1) for r in ratios) <= MAX_SIGMA_CHANGE)
    print(f"max_change_sigma={changes[worst]:.3f} (results unchanged: "
          f"{'yes' if same else 'NO'}; limits {MAX_CHANGE_SIGMA:g} σ, σ within "
          f"{MAX_SIGMA_CHANGE:.0%}, the same parameters estimated and dropped)")
    return same


def main(argv=None) -> int:
    from end_to_end import export_tree

    from apmcal.sources import read_log

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default="main", help="revision to compare with (default main)")
    ap.add_argument("--runs", type=int, default=3, help="runs per method, best taken (default 3)")
    ap.add_argument("--log", type=Path, help="another session instead of the simulated one")
    ap.add_argument("--command-runs", type=int, default=3,
                    help="fresh-process runs of each whole command, best taken (default 3)")
    ap.add_argument("--real-only", action="store_true",
                    help="only the identity check on the real recordings")
    args = ap.parse_args(argv)
    if args.real_only:
        return 0 if real_identity(export_tree(args.before), args.before) else 1
    session = args.log.resolve() if args.log else make_session()
    contents = read_log(session)
    timed(contents, "ellipsoid", 1)                       # warm-up: imports
    timed(contents, "joint", 1)
    e_wall, e_cpu, _ = timed(contents, "ellipsoid", args.runs)
    j_wall, j_cpu, cal = timed(contents, "joint", args.runs)
    now = cal.report.joint.parameters
    print(f"session {session.name}: {len(contents.recordings[0])} IMU samples")
    print(f"ellipsoid      {e_wall:7.2f} s wall  {e_cpu:7.2f} s CPU")
    print(f"joint          {j_wall:7.2f} s wall  {j_cpu:7.2f} s CPU")
    tree = export_tree(args.before)
    before = joint_in(tree, session, args.runs)
    print(f"joint {args.before:8s} {before['wall']:7.2f} s wall  {before['cpu']:7.2f} s CPU "
          f"(now {before['cpu'] / j_cpu:.1f}x as fast, CPU)")
    same = compare(now, before["parameters"], cal.report.joint.dropped_t_test,
                   before.get("dropped", cal.report.joint.dropped_t_test), args.before)
    same &= real_identity(tree, args.before)
    ratio = j_cpu / e_cpu
    print(f"ratio_joint_vs_ellipsoid_cpu={ratio:.2f} (wall {j_wall / e_wall:.2f}; target ≤ "
          f"{TARGET_RATIO:g}: {'met' if ratio <= TARGET_RATIO else 'NOT met'}; "
          f"calibration stage, CPU {j_cpu:.3f} s vs {e_cpu:.3f} s)")
    print("whole commands (apmcal log FILE --method M, fresh process, best of "
          f"{args.command_runs} by CPU):")
    ce = command(ROOT, session, "ellipsoid", args.command_runs)
    cj = command(ROOT, session, "joint", args.command_runs)
    cb = command(tree, session, "joint", args.command_runs)
    print(f"ellipsoid      {ce[0]:7.2f} s wall  {ce[1]:7.2f} s CPU")
    print(f"joint          {cj[0]:7.2f} s wall  {cj[1]:7.2f} s CPU")
    print(f"joint {args.before:8s} {cb[0]:7.2f} s wall  {cb[1]:7.2f} s CPU "
          f"(now {cb[1] / cj[1]:.1f}x as fast, CPU)")
    print(f"ratio_command_joint_vs_ellipsoid_cpu={cj[1] / ce[1]:.2f} "
          f"(wall {cj[0] / ce[0]:.2f})")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
