"""Does ``apmcal gap`` still give the same result, byte for byte, as at an earlier commit?

    python benchmarks/gap_identical.py [--before REV] [--no-real]

A speed change to the diagnosis must not change a single number it reports. This runs
``apmcal gap FILE --json OUT`` with this tree and with revision ``--before`` (its apmcal and its
simulator, apmcal_sim or the older sitl, exported with ``git archive``; default: main before the
speed work that began at 05:44 UTC on 2026-11-24) on:

* the 400 Hz session of ``gap_speed.py`` (made by it, kept in ``benchmarks/_data/``);
* six 100 Hz sitl sessions, each with other effects withheld from the twin (made here once);
* the real recordings of the README's table, when ``../shared/data`` is there.

and compares the two JSON files of each. Prints one line per session and exits 1 when any differs.
"""
from __future__ import annotations

import argparse
import filecmp
import os
import subprocess
import sys
from pathlib import Path

from end_to_end import export_tree  # the sibling benchmarks (this script's folder is on the path)
from gap_speed import make_session

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "_data"
SHARED = ROOT.parent / "shared" / "data"
BEFORE = "521fba9"      # main before the speed work that began at 05:44 UTC on 2026-11-24
SITE = ["--lat", "47.4", "--lon", "8.5"]
# (effects withheld from the twin, seed): a pair, a fine effect, the hold motion, an effect of
# the moves, none, a noise effect
SITL_CASES = [(("gyro_scale", "mag_interference"), 3), (("lowpass_filter",), 4),
              (("motion_contamination",), 5), (("cross_axis",), 6), ((), 7),
              (("bias_random_walk",), 8)]
REAL = [("ardupilot/pxf_copter_static_51.BIN", []),
        ("mpu6050/example_data_tinit_calc.csv", []),
        ("mpu6050/imu_static_test.csv", []),
        ("mpu6050/example_data_calibration.csv", ["--min-still", "1"]),
        ("imucal/example_ferraris_session.csv", [])]


def sessions(with_real: bool) -> list[tuple[Path, list[str]]]:
    """(log, its extra arguments) of every session compared, made when missing."""
    from apmcal_sim.gap_benchmark import simulate_log

    DATA.mkdir(exist_ok=True)
    out = []
    fast = DATA / "gap_400hz_script.bin"          # gap_speed.py's, the same file
    if not fast.exists():
        print(f"simulating {fast.name} ...", flush=True)
        make_session(fast, 400.0, None)
    out.append((fast, SITE))
    for withheld, seed in SITL_CASES:
        path = DATA / f"gap_identical_{'+'.join(withheld) or 'none'}_{seed}.bin"
        if not path.exists():
            print(f"simulating {path.name} ...", flush=True)
            simulate_log(withheld, seed, path, 100.0, 100.0)
        out.append((path, SITE))
    if with_real and SHARED.is_dir():
        out += [(SHARED / name, extra) for name, extra in REAL if (SHARED / name).exists()]
    elif with_real:
        print(f"({SHARED} is not there: the real recordings are left out)")
    return out


def gap_json(tree: Path, log: Path, extra: list[str], out: Path) -> None:
    """``apmcal gap LOG --json OUT`` with ``tree``'s apmcal (run from the data folder:
    ``python -m`` would put the current directory first)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    subprocess.run([sys.executable, "-m", "apmcal", "gap", str(log), *extra, "--json", str(out)],
                   check=True, stdout=subprocess.DEVNULL, cwd=DATA, env=env)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", default=BEFORE, help=f"revision to compare with (default {BEFORE})")
    ap.add_argument("--no-real", action="store_true", help="leave out the real recordings")
    args = ap.parse_args(argv)
    before = export_tree(args.before)
    differ = 0
    for log, extra in sessions(not args.no_real):
        now, was = DATA / "gap_identical_now.json", DATA / "gap_identical_before.json"
        gap_json(ROOT, log, extra, now)
        gap_json(before, log, extra, was)
        same = filecmp.cmp(now, was, shallow=False)
        differ += not same
        print(f"{'same' if same else 'DIFFERENT':9s} {log.name}", flush=True)
    print(f"{differ} of the sessions differ from {args.before}" if differ else
          f"every session gives the same JSON as at {args.before}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
