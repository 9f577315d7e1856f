"""Out-of-sample validation of the joint calibration ([Chow] §5) against the other methods.

    python benchmarks/joint_validation.py [--quick | --real-only]

Every method is fitted on one set of still poses and checked on poses it never saw: the gyro's
orientation change between two consecutive still poses against the one the accelerometer (and
compass, when there is one) gives at those poses (:mod:`apmcal.calibration.orientation_check`; the
gyro bias is re-measured on the checked session, as ArduPilot does at boot). Printed: RMS
error over the pose pairs [deg] for raw samples, Ferraris, ellipsoid + static and joint.

First the real recordings with turns between still poses
(:data:`apmcal.calibration.validation.REAL_RECORDINGS`: imucal's hand-held Ferraris session,
imu_tk's Xsens sequence, the MPU-6050 run and its separate 90° turn; none logs a compass, so
the tilt is checked), each fitted on its first still poses and checked on the turns after them
(Ferraris needs those turns: in-sample there, marked *), with the check's own noise (what the
sensors' white noise alone gives) and the turns not checked because the gyro was at its range
limit. Then sitl (APM 2.8-like errors of one seed, gyro scale and misalignment included;
effects no method here models switched off), fitted on a Ferraris session and on a hand-held
one, checked on another hand-held session of the same board, and the same with ``handheld_real``
sessions (a hand's tremor, turns that move the board, a laptop's slowly changing field); for
sitl, the joint's gyro matrix against the injected one in reported σ.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator

from apmcal.calibration.log import Options
from apmcal.calibration.validation import check, fit, session
from apmcal.core.errors import ApmcalError
from apmcal.solvers.result import Calibration

DATA = ROOT.parent / "shared" / "data"
SITE = {"lat_deg": 5.6037, "lon_deg": -0.187,      # sitl's default home (Accra) and the
        "date": __import__("datetime").date(2026, 5, 28)}   # date apmcal_sim.makelog's logs carry
UNMODELLED = ("temperature_drift,motion_contamination,scale_nonlinearity,gyro_bias_random_walk,"
              "earth_rate,gyro_bias_drift,lowpass_filter,time_offset,quantization")
METHODS = ("raw", "ferraris", "ellipsoid", "joint")
LABELS = {"raw": "raw", "ferraris": "Ferraris", "ellipsoid": "ellipsoid + static",
          "joint": "joint"}


def sitl_log(tmp: Path, script: str, seed: int, truth: Path | None, duration: float | None,
             rate: float) -> Path:
    from apmcal_sim.makelog import main as makelog
    out = tmp / f"{script}_{seed}.bin"
    # handheld_real's tremor is its own (the motion_contamination switch turns it on)
    off = UNMODELLED.replace("motion_contamination,", "") if script == "handheld_real" else UNMODELLED
    args = ["--script", script, "--out", str(out), "--seed", str(seed), "--rate", str(rate),
            "--fs", str(rate), "--disable", off]
    args += ["--truth", str(truth)] if truth else ["--truth-out", str(tmp / "truth.json")]
    args += ["--duration", str(duration)] if duration else []
    if makelog(args) != 0:
        raise SystemExit(f"apmcal_sim.makelog failed for {script}")
    return out


def gyro_truth_z(cal: Calibration, truth_file: Path) -> float:
    """Largest |joint − injected| / σ over the gyro matrix (in the accelerometer frame)."""
    import json
    t = json.loads(truth_file.read_text())
    m_acc = np.array(t["acc"]["matrix"])
    flip = np.fliplr(np.eye(3))
    low = flip @ np.linalg.cholesky(flip @ m_acc.T @ m_acc @ flip).T @ flip
    q = m_acc @ np.linalg.inv(low)                       # board = Q · accelerometer frame
    g = cal.sensors["gyr"]
    return float(np.max(np.abs(g.matrix - q.T @ np.array(t["gyr"]["matrix"])) / g.sigma["matrix"]))


def row(name: str, results: dict, extra: str = "") -> None:
    cells = [results.get(m, "n/a") for m in METHODS]
    print(f"| {name} | " + " | ".join(cells) + f" | {extra} |")


def run_sitl(tmp: Path, quick: bool, script: str = "handheld") -> None:
    rate = 50.0 if script == "handheld" else 100.0
    opts = Options("joint", **SITE)
    seconds = 40.0 if quick else 60.0 if script == "handheld" else 120.0
    hand = sitl_log(tmp, script, 31, None, seconds, rate)
    truth = tmp / "truth.json"
    val = session(sitl_log(tmp, script, 32, truth, seconds, rate))
    fits = [(f"sitl {script} {seconds:g} s at {rate:g} Hz", hand)]
    if not quick and script == "handheld":
        fits.insert(0, ("sitl Ferraris session", sitl_log(tmp, "ferraris", 33, truth, None, rate)))
    for name, log in fits:
        s = session(log)
        res, z, kind, n = {}, "", "", 0
        for m in METHODS:
            try:
                cal = fit(m, *s, opts)
            except ApmcalError as err:
                res[m] = f"n/a ({err.why.split(';')[0][:40]})"
                continue
            rms, n, kind = check(cal, val[2], val[3], val[4])
            tilt = check(cal, val[2], None, val[4])[0]
            res[m] = f"{rms:.3f} ({tilt:.3f})"
            if m == "joint":
                z = f"joint gyro matrix vs injected: max {gyro_truth_z(cal, truth):.1f} σ"
        row(f"{name} → another {script} session, {n} pairs, {kind} (tilt)", res, z)


def run_real() -> None:
    from apmcal.calibration.validation import REAL_RECORDINGS, out_of_sample

    if not DATA.exists():
        print("| real recordings | skipped: ../shared/data absent | | | | | | |")
        return
    print("| real recording (fitted → checked) | pairs | check noise | " + " | ".join(
        LABELS[m] for m in METHODS) + " |")
    print("|---|---|---|" + "---|" * len(METHODS))
    for rec in REAL_RECORDINGS:
        res = out_of_sample(rec, DATA, METHODS)
        any_ = next(iter(res.values()))
        pairs = f"{any_.pairs}" + (f" ({any_.clipped} at the gyro's range limit, not checked)"
                                   if any_.clipped else "")
        cells = []
        for m in METHODS:
            sc = res[m]
            if sc.rms_deg is None:
                cells.append(f"n/a ({sc.note[:40]})")
            else:
                mark = {"in-sample": "*", "fallback": " (fallback to its start)"}.get(sc.note, "")
                cells.append(f"{sc.rms_deg:.3f}{mark}")
        print(f"| {rec.name} | {pairs} | {any_.noise_deg:.3f} | " + " | ".join(cells) + " |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="hand-held sitl sessions only, 40 s")
    ap.add_argument("--real-only", action="store_true", help="the real recordings alone")
    args = ap.parse_args(argv)
    print("RMS tilt error out of sample [deg] on real recordings: the calibrated gyro carries "
          "gravity from one still pose to the next, compared with the gravity measured there\n")
    run_real()
    if args.real_only:
        return 0
    print("\nRMS orientation error out of sample [deg] on sitl sessions (gyro integrated between "
          "two still poses against accelerometer + compass at those poses; in brackets the tilt "
          "part alone)\n")
    print("| session | " + " | ".join(LABELS[m] for m in METHODS) + " | note |")
    print("|---|" + "---|" * (len(METHODS) + 1))
    with tempfile.TemporaryDirectory() as tmp:
        run_sitl(Path(tmp), args.quick)
    with tempfile.TemporaryDirectory() as tmp:
        run_sitl(Path(tmp), args.quick, "handheld_real")
    return 0


if __name__ == "__main__":
    sys.exit(main())
