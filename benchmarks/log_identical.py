"""Does ``apmcal log`` still write the same JSON, byte for byte, as at an earlier commit?

    python benchmarks/log_identical.py [--before REV] [--no-real]

A change of layout (modules moved, results built elsewhere) must not change a single number the
calibration reports. This runs ``apmcal log FILE --json OUT`` with this tree and with revision
``--before`` (its package and simulator exported with ``git archive``; default: main before the
layout of one floor per folder) on the bundled sample logs (``logs/``) and, when
``../shared/data`` is there, on every real recording of ``ardupilot/`` and three CSV sessions,
and compares the two JSON files of each (exit status and all).

Some fits are not repeatable to the last bits from one run to the next (seen: the ellipsoid fit of
mpu6050/example_data_calibration.csv, whose numbers vary by ~2e-12 relative between two runs of
the same tree), so a file that differs is run once more with the old tree and both are told:
"same to the last digits" when every number agrees within TOLERANCE (relative) and the
structure and exit status are equal, with the largest difference and the old tree's own scatter
beside it. Prints one line per file and exits 1 when any differs beyond that.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from end_to_end import export_tree  # the sibling benchmark (this script's folder is on the path)

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "_data"
SHARED = ROOT.parent / "shared" / "data"
BEFORE = "3ff703f"      # main before the layout of one floor per folder
SAMPLES = [("ferraris.tlog", ["--lat", "5.6037", "--lon", "-0.187"]),
           ("ferraris_params32.tlog", ["--lat", "5.6037", "--lon", "-0.187"]),
           ("ferraris_params33.tlog", ["--lat", "5.6037", "--lon", "-0.187"]),
           ("onepos.tlog", ["--lat", "5.6037", "--lon", "-0.187"]),
           ("tumble.bin", ["--lat", "47.4", "--lon", "8.5"]),
           ("gap.bin", ["--lat", "47.4", "--lon", "8.5"]),
           ("gap.bin", ["--method", "joint", "--lat", "47.4", "--lon", "8.5"])]
TOLERANCE = 1e-9       # relative; a thousand times the run-to-run scatter seen
REAL_CSV = ["imucal/example_ferraris_session.csv", "mpu6050/example_data_calibration.csv",
            "mpu6050/imu_static_test.csv"]


def sessions(with_real: bool) -> list[tuple[Path, list[str]]]:
    """(file, its extra arguments) of every run compared."""
    out = [(ROOT / "logs" / name, extra) for name, extra in SAMPLES]
    if with_real and SHARED.is_dir():
        out += [(p, []) for p in sorted((SHARED / "ardupilot").iterdir())]
        out += [(SHARED / name, []) for name in REAL_CSV if (SHARED / name).exists()]
    elif with_real:
        print(f"({SHARED} is not there: the real recordings are left out)")
    return out


def log_json(tree: Path, log: Path, extra: list[str], out: Path) -> bytes:
    """``apmcal log LOG --json OUT`` with ``tree``'s package: the exit status and the JSON file
    (empty when none was written), as bytes."""
    out.unlink(missing_ok=True)
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    done = subprocess.run([sys.executable, "-m", "apmcal", "log", str(log), *extra, "--json",
                           str(out)], cwd=DATA, env=env, capture_output=True)
    return f"exit {done.returncode}\n".encode() + (out.read_bytes() if out.exists() else b"")


def numbers(blob: bytes) -> list[float]:
    """Every number of a JSON file, in order (none when it is not JSON)."""
    try:
        obj = json.loads(blob.split(b"\n", 1)[1] or b"null")
    except ValueError:
        return []
    found: list[float] = []

    def walk(x):
        if isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, list):
            for v in x:
                walk(v)
        elif isinstance(x, (int, float)) and not isinstance(x, bool):
            found.append(float(x))
    walk(obj)
    return found


def largest_difference(a: bytes, b: bytes) -> float:
    """Largest relative difference of corresponding numbers (inf when the structure differs)."""
    na, nb = numbers(a), numbers(b)
    if len(na) != len(nb) or a.split(b"\n", 1)[0] != b.split(b"\n", 1)[0]:
        return float("inf")
    return max((abs(x - y) / max(abs(x), abs(y), 1e-300) for x, y in zip(na, nb) if x != y),
               default=0.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", default=BEFORE, help=f"revision to compare with (default {BEFORE})")
    ap.add_argument("--no-real", action="store_true", help="leave out the real recordings")
    args = ap.parse_args(argv)
    DATA.mkdir(exist_ok=True)
    before = export_tree(args.before)
    differ = 0
    for log, extra in sessions(not args.no_real):
        now = log_json(ROOT, log, extra, DATA / "log_identical_now.json")
        was = log_json(before, log, extra, DATA / "log_identical_before.json")
        label = " ".join([log.name, *extra])
        if now == was:
            print(f"same       {label}", flush=True)
            continue
        again = log_json(before, log, extra, DATA / "log_identical_before.json")
        change, scatter = largest_difference(was, now), largest_difference(was, again)
        if change <= max(scatter, TOLERANCE):
            print(f"same to the last digits ({change:.1e}; the old tree's own scatter "
                  f"{scatter:.1e}) {label}", flush=True)
        else:
            differ += 1
            print(f"DIFFERENT  {label}: {change:.1e} (the old tree's own scatter {scatter:.1e})",
                  flush=True)
    print(f"{differ} of the files differ from {args.before}" if differ else
          f"every file gives the same JSON as at {args.before}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
