"""Why ``--method auto`` picks the joint method for hand-held sessions with a compass, and at
which rate it fits them.

    python benchmarks/joint_auto.py [--seeds 3] [--rate 200] [--seconds 60]

For sitl hand-held sessions (every simulated effect on, a different board per seed) the
parameters ArduPilot can hold — accelerometer offsets and diagonal scales, gyro offsets,
compass offsets and diagonal — from the ellipsoid fit (what ``auto`` chose before) and from the
joint fit (what it chooses now) are compared with the injected truth. Offsets are in the raw
sensor axes for both methods; the joint's matrices are in the accelerometer's frame, which
differs from the board's by the triad's small misalignment (second order on the diagonal).
``auto`` keeps the joint's accelerometer and gyro and fits the compass on its own. Then the joint
fit on block means at lower rates, against the truth: the rate it averages down to
(:data:`JOINT_RATE_HZ`) is chosen from this table.
"""
from __future__ import annotations

import argparse
import datetime
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator

from apmcal.calibration import joint as joint_pipeline
from apmcal.calibration.log import Options, calibrate_log
from apmcal.sources import read_log

SITE = {"lat_deg": 5.6037, "lon_deg": -0.187,          # sitl's default home (Accra) and the
        "date": datetime.date(2026, 5, 28)}            # date apmcal_sim.makelog's logs carry
HELD = (("acc", "offset"), ("acc", "diag"), ("gyr", "offset"), ("mag", "offset"),
        ("mag", "diag"))
UNITS = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}


def sitl_session(tmp: Path, seed: int, rate: float, seconds: float) -> tuple[Path, dict]:
    from apmcal_sim.makelog import main as makelog
    log, truth = tmp / f"hand_{seed}.bin", tmp / f"hand_{seed}.json"
    if makelog(["--script", "handheld", "--out", str(log), "--seed", str(seed), "--rate",
                str(rate), "--fs", str(rate), "--duration", str(seconds),
                "--truth-out", str(truth)]) != 0:
        raise SystemExit("apmcal_sim.makelog failed")
    return log, json.loads(truth.read_text())


def held_errors(cal, truth: dict) -> dict:
    """RMS error against the truth of what ArduPilot's parameters hold."""
    out = {}
    for sensor, part in HELD:
        est, true = cal.sensors[sensor], truth[sensor]
        if part == "offset":
            err = est.offset - np.asarray(true["offset"])
        else:
            err = np.diag(est.matrix) - np.diag(np.asarray(true["matrix"]))
        out[(sensor, part)] = float(np.sqrt(np.mean(err ** 2)))
    return out


def compare_methods(sessions) -> None:
    print("RMS error against the injected truth of what ArduPilot holds (per seed), and the "
          "fit's time\n")
    print("| seed | method | " + " | ".join(f"{s} {p}" for s, p in HELD) + " | time [s] |")
    print("|---|---|" + "---|" * (len(HELD) + 1))
    ratios = {k: [] for k in HELD}
    for seed, log, truth in sessions:
        errs = {}
        for method in ("ellipsoid", "joint", "auto"):
            start = time.perf_counter()
            cal, _ = calibrate_log(read_log(log), Options(method, **SITE))
            took = time.perf_counter() - start
            errs[method] = held_errors(cal, truth)
            cells = " | ".join(f"{errs[method][k]:.2g}" for k in HELD)
            print(f"| {seed} | {method} | {cells} | {took:.1f} |")
        for k in HELD:
            ratios[k].append(errs["joint"][k] / errs["ellipsoid"][k])
    print("\nmedian joint / ellipsoid error: "
          + ", ".join(f"{s} {p} {np.median(ratios[(s, p)]):.2f}" for s, p in HELD))


def compare_rates(sessions, rates) -> None:
    print("\nJoint fit on block means at lower rates: RMS error against the truth of what it "
          "gives ArduPilot under auto (accelerometer offset [m/s²] / diagonal, gyro offset "
          "[rad/s]), and the fit's time\n")
    print("| seed | " + " | ".join(f"{r:g} Hz" for r in rates) + " |")
    print("|---|" + "---|" * len(rates))
    saved = joint_pipeline.JOINT_RATE_HZ
    try:
        for seed, log, truth in sessions:
            cells = []
            for r in rates:
                joint_pipeline.JOINT_RATE_HZ = r
                start = time.perf_counter()
                cal, _ = calibrate_log(read_log(log), Options("joint", **SITE))
                took = time.perf_counter() - start
                e = held_errors(cal, truth)
                cells.append(f"{e[('acc', 'offset')]:.2g} / {e[('acc', 'diag')]:.2g} / "
                             f"{e[('gyr', 'offset')]:.2g}, {took:.1f} s")
            print(f"| {seed} | " + " | ".join(cells) + " |")
    finally:
        joint_pipeline.JOINT_RATE_HZ = saved


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="boards (sitl seeds 1..N)")
    ap.add_argument("--rate", type=float, default=200.0, help="recorded rate [Hz]")
    ap.add_argument("--seconds", type=float, default=60.0, help="session length [s]")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        sessions = [(seed, *sitl_session(Path(tmp), seed, args.rate, args.seconds))
                    for seed in range(1, args.seeds + 1)]
        compare_methods(sessions)
        rates = [args.rate] + [r for r in (100.0, 50.0, 20.0) if r < args.rate]
        compare_rates(sessions, rates)
    return 0


if __name__ == "__main__":
    sys.exit(main())
