"""Where ``apmcal gap`` spends its CPU time: cProfile of the diagnosis of gap_speed.py's session.

    python benchmarks/gap_profile.py [--top 30] [--stage "null sessions"] [--out FILE.prof]

The diagnosis runs in this one process (no forked workers, so that cProfile sees every model;
the numbers are the same, the CPU time a little lower than with workers, which fork and ship
their results back). Printed: the CPU seconds of each stage (as ``gap_speed.py`` counts them,
under the profiler), then the functions with the most CPU time of their own and with their
callees, within ``--stage`` only when given. The session is the one
``gap_speed.py`` makes (``benchmarks/_data/gap_400hz_script.bin``).
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path

DATA = Path(__file__).resolve().parent / "_data"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--top", type=int, default=30, help="functions listed (default 30)")
    ap.add_argument("--stage", default=None,
                    help="profile only this stage (e.g. 'null sessions', 'nominal model')")
    ap.add_argument("--out", type=Path, default=None, help="also write the profile here")
    args = ap.parse_args(argv)
    path = DATA / "gap_400hz_script.bin"
    if not path.exists():
        from gap_speed import make_session

        print(f"simulating {path.name} ...", flush=True)
        make_session(path, 400.0, None)

    from gap_speed import stage_of

    from apmcal.calibration.log import Options
    from apmcal.diagnosis.compute import workers
    from apmcal.diagnosis.run import diagnose
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    workers.parallel = lambda: False        # every model in this process, seen by cProfile
    session = session_from_log(read_log(path), Options(lat_deg=47.4, lon_deg=8.5))
    profile = cProfile.Profile(time.process_time)     # CPU time, not the busy machine's wall
    cpu: dict = {}
    stage = {"name": None, "t0": time.process_time()}

    def switch(name: str) -> None:
        now = time.process_time()
        if stage["name"]:
            cpu[stage["name"]] = cpu.get(stage["name"], 0.0) + now - stage["t0"]
            if args.stage == stage["name"]:
                profile.disable()
        if args.stage in (None, name):
            profile.enable()
        stage.update(name=name, t0=now)

    def progress(announced: str) -> None:     # diagnose() announces each stage as it starts
        if stage_of(announced) is not None:
            switch(stage_of(announced))

    diagnose(session, progress=progress)
    switch("")
    profile.disable()
    print("CPU seconds per stage (under the profiler, no workers):")
    for name, seconds in cpu.items():
        print(f"  {name:28s} {seconds:7.2f}")
    stats = pstats.Stats(profile)
    if args.out:
        stats.dump_stats(args.out)
    stats.sort_stats("tottime").print_stats(args.top)
    stats.sort_stats("cumulative").print_stats("apmcal", args.top)


if __name__ == "__main__":
    main()
