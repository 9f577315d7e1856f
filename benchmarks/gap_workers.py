"""What the forked workers of ``apmcal gap`` buy and cost: the same diagnosis in one process.

    python benchmarks/gap_workers.py [--repeat 2]

Diagnoses gap_speed.py's session (``benchmarks/_data/gap_400hz_script.bin``, 636 s at 400
Hz; simulated first when missing) with the forked workers of
:mod:`apmcal.diagnosis.compute.workers` and without them (every model in this process), each
``--repeat`` times, alternating, each in a fresh process. Printed per way, best of the repeats
by wall time: wall seconds, CPU seconds (the process and its workers, user + system), of
them system seconds, minor page faults, and the number of worker pools forked (a pair kept
per fold counts once); then the
speed-up the workers give (one-process wall / workers' wall) and the CPU they add. The log is
read and cut before the clock starts; the imports the diagnosis needs are made before it too.
Another revision's tree on ``PYTHONPATH`` (e.g. a ``git worktree``) is measured the same way.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SESSION = HERE / "_data" / "gap_400hz_script.bin"


def measure(parallel: bool) -> dict:
    """One diagnosis in this process: wall, CPU and system seconds, page faults, pools."""
    from apmcal.calibration.log import Options
    from apmcal.diagnosis.compute import workers
    from apmcal.diagnosis.run import diagnose, preload_imports
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    if not parallel:
        workers.parallel = lambda: False
    pools = []
    pool, per_fold = workers._pool, getattr(workers, "per_fold", None)    # (an older tree
                                                                          # on PYTHONPATH)

    def counted(target, n):
        pools.append(n)
        return pool(target, n)

    def counted_per_fold(target, folds):
        if workers.parallel():      # else it forks none
            pools.append(len(folds))
        return per_fold(target, folds)

    workers._pool = counted
    if per_fold is not None:
        workers.per_fold = counted_per_fold
    preload_imports()
    session = session_from_log(read_log(SESSION), Options(lat_deg=47.4, lon_deg=8.5))
    before, start = _usage(), time.perf_counter()
    selected = diagnose(session).result.selected
    wall = time.perf_counter() - start
    after = _usage()
    return {"wall": wall, "cpu": after["cpu"] - before["cpu"],
            "system": after["system"] - before["system"],
            "faults": after["faults"] - before["faults"], "pools": len(pools),
            "selected": selected}


def _usage() -> dict:
    own, children = (resource.getrusage(who) for who in
                     (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return {"cpu": sum(u.ru_utime + u.ru_stime for u in (own, children)),
            "system": own.ru_stime + children.ru_stime,
            "faults": own.ru_minflt + children.ru_minflt}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=2, help="runs of each way (default 2)")
    ap.add_argument("--one", choices=("workers", "one process"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure(args.one == "workers")))
        return
    if not SESSION.exists():
        from gap_speed import make_session

        print(f"simulating {SESSION.name} ...", flush=True)
        make_session(SESSION, 400.0, None)
    runs: dict = {"workers": [], "one process": []}
    for _ in range(args.repeat):
        for way in runs:
            out = subprocess.run([sys.executable, __file__, "--one", way], check=True,
                                 capture_output=True, text=True, cwd=HERE)
            runs[way].append(json.loads(out.stdout.strip().splitlines()[-1]))
    best = {way: min(r, key=lambda m: m["wall"]) for way, r in runs.items()}
    for way, m in best.items():
        print(f"{way:12s} wall {m['wall']:6.2f} s  CPU {m['cpu']:6.2f} s  (system "
              f"{m['system']:.2f} s)  page faults {m['faults']:>8d}  pools {m['pools']:>3d}  "
              f"selected {', '.join(m['selected']) or 'nothing'}")
    w, o = best["workers"], best["one process"]
    print(f"the workers: {o['wall'] / w['wall']:.2f}× the speed of one process, "
          f"{w['cpu'] / o['cpu']:.2f}× its CPU")


if __name__ == "__main__":
    main()
