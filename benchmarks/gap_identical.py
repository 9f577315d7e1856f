"""Does ``apmcal gap`` still give the same result, byte for byte, as at an earlier commit?

    python benchmarks/gap_identical.py [--before REV] [--no-real] [--no-firmware] [--numbers]
                                       [--only NAME ...]

A speed change to the diagnosis must not change a single number it reports. This runs
``apmcal gap FILE --json OUT`` with this tree and with revision ``--before`` (its apmcal and its
simulator, apmcal_sim or the older sitl, exported with ``git archive``; default: main before the
speed work that began at 05:44 UTC on 2026-11-24) on:

* the 400 Hz session of ``gap_speed.py`` (made by it, kept in ``benchmarks/_data/``);
* six 100 Hz sitl sessions, each with other effects withheld from the twin (made here once);
* the 636 s 400 Hz session with every effect on of ``gap_cost.py``;
* the real recordings of the README's table, when ``../shared/data`` is there;
* logs of ArduPilot's own firmware (SITL, ``../shared/ardupilot-sitl``), recorded once: its
  default drift held still (.tlog and dataflash) and a warm-up (.tlog), when it is there.

and compares the two JSON files of each. Prints one line per session and exits 1 when any differs.

``--numbers``: for a change that legitimately moves numbers by rounding (e.g. an analytic
Jacobian instead of finite differences), a session whose JSON differs is still "same" when
every non-number (effect names, selections, verdicts, flags, list lengths) is equal; the line
then gives how many numbers moved, how many by more than 1e-6 relative, the largest relative
change |a − b| / max(|a|, |b|), and the largest change of a fitted parameter in units of its
σ. Exits 1 only on a non-number difference.
"""
from __future__ import annotations

import argparse
import filecmp
import json
import math
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
# ArduPilot SITL sessions (name, simulated seconds from boot, SIM_* at boot)
FIRMWARE = [("drift", 420, {}),
            ("warmup", 240, {"SIM_DRIFT_SPEED": 0, "SIM_IMUT1_ENABLE": 1, "SIM_IMUT1_TMIN": -10,
                             "SIM_IMUT1_TMAX": 80, "SIM_IMUT_TCONST": 100,
                             "SIM_IMUT1_GYR1_X": 300, "SIM_IMUT1_GYR1_Y": -200,
                             "SIM_IMUT1_GYR1_Z": 150})]
REAL = [("ardupilot/pxf_copter_static_51.BIN", []),
        ("mpu6050/example_data_tinit_calc.csv", []),
        ("mpu6050/imu_static_test.csv", []),
        ("mpu6050/example_data_calibration.csv", ["--min-still", "1"]),
        ("imucal/example_ferraris_session.csv", [])]


def sessions(with_real: bool, with_firmware: bool = True) -> list[tuple[Path, list[str]]]:
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
    alleffects = DATA / "gap_alleffects_400hz.bin"     # gap_cost.py's, the same file
    if not alleffects.exists():
        print(f"simulating {alleffects.name} ...", flush=True)
        subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", "diagnosis",
                        "--rate", "400", "--fs", "400", "--out", str(alleffects)],
                       check=True, cwd=ROOT)
    out.append((alleffects, []))
    if with_real and SHARED.is_dir():
        out += [(SHARED / name, extra) for name, extra in REAL if (SHARED / name).exists()]
    elif with_real:
        print(f"({SHARED} is not there: the real recordings are left out)")
    if with_firmware:
        out += firmware_logs()
    return out


def firmware_logs() -> list[tuple[Path, list[str]]]:
    """Logs of ArduPilot's own firmware (SITL, ``../shared/ardupilot-sitl``), recorded once
    into ``benchmarks/_data/gap_firmware_*``: SITL's default drift held still (.tlog and
    dataflash) and a warm-up with SIM_IMUT1 coefficients (.tlog); none without the firmware."""
    sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "sitl")]
    from ardupilot_sitl import unavailable_reason

    if unavailable_reason():
        print(f"({unavailable_reason()}: the firmware's logs are left out)")
        return []
    from gap_sitl_sessions import record

    out = []
    for name, until, boot in FIRMWARE:
        folder = DATA / f"gap_firmware_{name}"
        if not (folder / "done").exists():
            print(f"recording {folder.name} on ArduPilot SITL ...", flush=True)
            import shutil

            shutil.rmtree(folder, ignore_errors=True)
            rec = record(folder, [("until", until)], boot)
            shutil.copy(rec.bin, folder / "dataflash.bin")
            (folder / "done").write_text("")
        out.append((folder / "sitl.tlog", []))
        if name == "drift":
            out.append((folder / "dataflash.bin", []))
    return out


def gap_json(tree: Path, log: Path, extra: list[str], out: Path) -> None:
    """``apmcal gap LOG --json OUT`` with ``tree``'s apmcal (run from the data folder:
    ``python -m`` would put the current directory first)."""
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    subprocess.run([sys.executable, "-m", "apmcal", "gap", str(log), *extra, "--json", str(out)],
                   check=True, stdout=subprocess.DEVNULL, cwd=DATA, env=env)


def number_differences(was, now) -> tuple[list, list, float]:
    """(non-number differences, [(relative change, path, was, now)] of the numbers that moved,
    the largest change of a parameter value in units of its σ) of two JSON documents."""
    other, moved, in_sigma = [], [], [0.0]

    def walk(a, b, path):
        if isinstance(a, dict) and isinstance(b, dict):
            if set(a) != set(b):
                other.append((path, "keys"))
            for k in a.keys() & b.keys():
                walk(a[k], b[k], f"{path}.{k}")
            if "value" in a and "sigma" in a and "value" in b:
                _sigma_change(a["value"], b["value"], a["sigma"])
        elif isinstance(a, list) and isinstance(b, list):
            if len(a) != len(b):
                other.append((path, "length"))
                return
            for i, (x, y) in enumerate(zip(a, b)):
                walk(x, y, f"{path}[{i}]")
        elif _number(a) and _number(b):
            if a != b and not (math.isnan(a) and math.isnan(b)):
                moved.append((abs(a - b) / max(abs(a), abs(b)), path, a, b))
        elif a != b:
            other.append((path, a, b))

    def _sigma_change(value, new, sigma):
        for v, w, s in zip(*(x if isinstance(x, list) else [x] for x in (value, new, sigma))):
            if _number(v) and _number(w) and _number(s) and s > 0:
                in_sigma[0] = max(in_sigma[0], abs(v - w) / s)

    walk(was, now, "")
    return other, sorted(moved, reverse=True), in_sigma[0]


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", default=BEFORE, help=f"revision to compare with (default {BEFORE})")
    ap.add_argument("--no-real", action="store_true", help="leave out the real recordings")
    ap.add_argument("--no-firmware", action="store_true",
                    help="leave out the logs of ArduPilot's own firmware (SITL)")
    ap.add_argument("--only", nargs="+", default=None, metavar="NAME",
                    help="only the sessions whose file name contains one of these")
    ap.add_argument("--numbers", action="store_true",
                    help="accept numbers moved by rounding when every non-number is equal")
    args = ap.parse_args(argv)
    before = export_tree(args.before)
    differ = 0
    for log, extra in sessions(not args.no_real, not args.no_firmware):
        if args.only and not any(part in str(log) for part in args.only):
            continue
        now, was = DATA / "gap_identical_now.json", DATA / "gap_identical_before.json"
        gap_json(ROOT, log, extra, now)
        gap_json(before, log, extra, was)
        same = filecmp.cmp(now, was, shallow=False)
        note = "(byte for byte)" if same and args.numbers else ""
        if not same and args.numbers:
            other, moved, in_sigma = number_differences(json.loads(was.read_text()),
                                                        json.loads(now.read_text()))
            same = not other
            beyond = sum(m[0] > 1e-6 for m in moved)
            note = (f"(every non-number equal; {len(moved)} numbers moved, {beyond} by more "
                    f"than 1e-6 relative, at most {moved[0][0]:.1e} ({moved[0][1]}: "
                    f"{moved[0][2]!r} → {moved[0][3]!r}); parameters at most {in_sigma:.1e} σ)"
                    if same and moved else "(every number and non-number equal)" if same
                    else f"{other[:3]}")
        differ += not same
        print(f"{'same' if same else 'DIFFERENT':9s} {log.name} {note}", flush=True)
    print(f"{differ} of the sessions differ from {args.before}" if differ else
          f"every session gives the same JSON as at {args.before}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
