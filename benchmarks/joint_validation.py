"""Out-of-sample validation of the joint calibration ([Chow] §5) against the other methods.

    python benchmarks/joint_validation.py [--quick]

Every method is fitted on one set of still poses and checked on poses it never saw: the gyro's
orientation change between two consecutive still poses against the one the accelerometer (and
compass, when there is one) gives at those poses (:mod:`apmcal.calibration.orientation_check`; the
gyro bias is re-measured on the checked session, as ArduPilot does at boot). Printed: RMS
error over the pose pairs [deg] for raw samples, Ferraris, ellipsoid and joint, and for the
simulated sessions the joint's gyro matrix against the injected one in reported σ.

Sessions: sitl (APM 2.8-like errors of one seed, gyro scale and misalignment included; effects
no method here models switched off), fitted on a Ferraris session and on a hand-held one,
checked on another hand-held session of the same board; imucal's hand-held Ferraris session
(no compass: tilt only; fitted on the six faces, checked on the turns after them — Ferraris
needs those turns, so it is in-sample there, marked *); the MPU-6050 six-orientation run
(no compass) checked on the separate 90° turn recording.
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


def sitl_log(tmp: Path, script: str, seed: int, truth: Path | None, duration: float | None,
             rate: float) -> Path:
    from apmcal_sim.makelog import main as makelog
    out = tmp / f"{script}_{seed}.bin"
    args = ["--script", script, "--out", str(out), "--seed", str(seed), "--rate", str(rate),
            "--fs", str(rate), "--disable", UNMODELLED]
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


def run_sitl(tmp: Path, quick: bool) -> None:
    rate = 50.0
    opts = Options("joint", **SITE)
    seconds = 40.0 if quick else 60.0
    hand = sitl_log(tmp, "handheld", 31, None, seconds, rate)
    truth = tmp / "truth.json"
    val = session(sitl_log(tmp, "handheld", 32, truth, seconds, rate))
    fits = [(f"sitl hand-held {seconds:g} s", hand)]
    if not quick:
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
        row(f"{name} → other hand-held session, {n} pairs, {kind} (tilt)", res, z)


def run_imucal() -> None:
    path = DATA / "imucal" / "example_ferraris_session.csv"
    if not path.exists():
        print("| imucal session | skipped: ../shared/data absent | | | | |")
        return
    s = session(path, "imucal")
    raw, holds = s[2], s[4]
    cut = holds[6].i1                    # the six faces (and a knock): holds 0-6
    part = np.arange(len(raw.t)) < cut
    pairs_val = [p for p in _pairs(raw, holds) if p.k0 >= cut]
    opts = Options("joint")
    res = {}
    for m in METHODS:
        try:
            cal = fit(m, *s, opts, part=None if m == "ferraris" else part)
        except ApmcalError as err:
            res[m] = f"n/a ({err.why[:40]})"
            continue
        rms, n, _ = check(cal, raw, None, holds, pairs_val)
        res[m] = f"{rms:.3f}" + ("*" if m == "ferraris" else "")
    row(f"imucal hand-held, faces → turns after them, {n} pairs, tilt (no compass)", res,
        "* Ferraris needs the turns: in-sample")


def _pairs(raw, holds):
    from apmcal.calibration.orientation_check import pose_pairs
    return pose_pairs(raw.t, holds)


def run_mpu6050() -> None:
    fit_path = DATA / "mpu6050" / "example_data_calibration.csv"
    val_path = DATA / "mpu6050" / "imu_90_x_rot.csv"
    if not fit_path.exists():
        print("| MPU-6050 | skipped: ../shared/data absent | | | | |")
        return
    s, v = session(fit_path, "mpu6050"), session(val_path, "mpu6050")
    res = {}
    for m in METHODS:
        try:
            cal = fit(m, *s, Options("joint"))
        except ApmcalError as err:
            res[m] = f"n/a ({err.why[:40]})"
            continue
        rms, n, _ = check(cal, v[2], None, v[4])
        res[m] = f"{rms:.3f}"
    row(f"MPU-6050 six orientations → separate 90° turn file, {n} pair, tilt (no compass)", res)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="hand-held sitl session only, 40 s")
    args = ap.parse_args(argv)
    print("RMS orientation error out of sample [deg] (gyro integrated between two still poses "
          "against accelerometer + compass at those poses; in brackets the tilt part alone)\n")
    print("| session | " + " | ".join(METHODS) + " | note |")
    print("|---|" + "---|" * (len(METHODS) + 1))
    with tempfile.TemporaryDirectory() as tmp:
        run_sitl(Path(tmp), args.quick)
    run_imucal()
    run_mpu6050()
    return 0


if __name__ == "__main__":
    sys.exit(main())
