"""How long ``apmcal --help`` takes, against the command before a change, in one run.

    python benchmarks/help_time.py [--before REV] [--runs 15]

The command line's start is what a user feels first; the target is ≤ 0.3 s. Runs ``python -m
apmcal --help`` with this tree and with revision ``--before`` (its package exported with ``git
archive``; default: main before the layout of one floor per folder), alternating, and prints the
median, min and max of each and their ratio. Also lists the heavy packages (numpy, pandas,
scipy, rich, pymavlink) that building the parser imports: none should.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from end_to_end import export_tree  # the sibling benchmark (this script's folder is on the path)

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "_data"
BEFORE = "3ff703f"
HEAVY = ("numpy", "pandas", "scipy", "rich", "pymavlink")


def once(tree: Path) -> float:
    """Wall time [s] of ``python -m apmcal --help`` with ``tree`` first on the path."""
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "apmcal", "--help"], env=env, cwd=DATA, check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def heavy_imports(tree: Path) -> list[str]:
    """The heavy packages that building the parser imports."""
    code = ("import sys; from apmcal.cli import build_parser; build_parser(); "
            f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))")
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    out = subprocess.run([sys.executable, "-c", code], env=env,
                         cwd=DATA, check=True, capture_output=True, text=True).stdout.strip()
    return [m for m in out.split(",") if m]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", default=BEFORE, help=f"revision to compare with (default {BEFORE})")
    ap.add_argument("--runs", type=int, default=15)
    args = ap.parse_args(argv)
    DATA.mkdir(exist_ok=True)
    before = export_tree(args.before)
    now, was = [], []
    for _ in range(args.runs):
        now.append(once(ROOT))
        was.append(once(before))
    for name, times in (("this tree", now), (args.before, was)):
        print(f"{name:12s} median {statistics.median(times):.3f} s  min {min(times):.3f}  "
              f"max {max(times):.3f}")
    print(f"ratio (this tree / {args.before}, medians): "
          f"{statistics.median(now) / statistics.median(was):.2f}")
    print(f"heavy packages the parser imports: {', '.join(heavy_imports(ROOT)) or 'none'}")
    return 0 if statistics.median(now) <= 0.3 else 1


if __name__ == "__main__":
    sys.exit(main())
