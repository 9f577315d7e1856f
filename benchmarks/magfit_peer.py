"""apmcal's flight compass fit beside pymavlink's magfit_WMM.py on flights with known truth:
errors of both against the exact calibration, and their times, in the same run.

    python benchmarks/magfit_peer.py [--seeds 1 2 3] [--sitl-seeds 1 2] [--reduce 1]

Simulated flights (``--seeds``): ``apmcal_sim.flight`` (about 2 minutes at 25 Hz, the logged
yaw biased 8° with a heading-dependent part) with ONE compass (magfit_WMM reads the MAG
messages without telling the instances of a 4.x log apart), a stale calibration in force and the
current logged in BAT. ArduPilot's own firmware (``--sitl-seeds``, where
../shared/ardupilot-sitl is present): a quad flown by tests/test_flight_compass_sitl.py's
``record_copter`` with one compass (SIM_MAG2-8_DEVID 0), hard and soft iron and motor
interference injected, a stale calibration in force, the gyro drifting (SIM_DRIFT_SPEED 0.05);
odd seeds the calibration-friendly flight, even seeds the ordinary square mission; the exact
answer is the SITL README's (COMPASS_OFS/DIA/ODI = SIM_MAG1_*, COMPASS_MOT = −SIM_MAG_MOT).
magfit_WMM runs as users run it with the right options: ``--elliptical --cmot --att-source ATT``
(the log has no XKF1), on the whole log; apmcal as ``calibrate_flight`` (the orientation search
included). Errors: the largest |COMPASS_OFS error| [mGauss], the largest |DIA/ODI error|, and
|ΔMOT|/|MOT| [%]; a parameter apmcal keeps in force (not identified) counts with the value in
force. magfit prints offsets as whole mGauss and DIA/ODI/MOT to 3 decimals, which bounds its
error from below by 0.5 mGauss and 0.0005.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl"), str(ROOT / "tests")]

from apmcal.calibration.flight import calibrate_flight  # noqa: E402
from apmcal_sim import flight as sim  # noqa: E402

AXES = "XYZ"


def errors(values: dict, ideal: dict) -> tuple[float, float, float]:
    """(max |OFS err| mGauss, max |DIA/ODI err|, |ΔMOT|/|MOT| %) of COMPASS_* ``values``
    (DIA/ODI times COMPASS_SCALE when the values carry one: the matrix the firmware applies)."""
    ofs = max(abs(values[f"COMPASS_OFS_{a}"] - ideal[f"OFS_{a}"]) for a in AXES)
    scale = values.get("COMPASS_SCALE", 0.0) or 1.0      # magfit fits SCALE apart from DIA
    mat = max(abs(scale * values[f"COMPASS_{k}_{a}"] - ideal[f"{k}_{a}"]) for k in ("DIA", "ODI")
              for a in AXES)
    mot = np.array([values.get(f"COMPASS_MOT_{a}", np.nan) for a in AXES])
    true = np.array([ideal[f"MOT_{a}"] for a in AXES])
    return ofs, mat, 100 * float(np.linalg.norm(mot - true) / np.linalg.norm(true))


def run_magfit(path: Path, reduce: int) -> tuple[dict, float, str]:
    """magfit_WMM's proposal (COMPASS_* name → value), its wall time [s] and its last line."""
    cmd = [sys.executable, "-m", "pymavlink.tools.magfit_WMM", "--elliptical", "--cmot",
           "--att-source", "ATT", "--reduce", str(reduce), str(path)]
    env = dict(os.environ, MPLBACKEND="Agg")
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=path.parent,
                         timeout=1800)
    dt = time.perf_counter() - t0
    values = {m.group(1): float(m.group(2)) for m in
              re.finditer(r"^(COMPASS_\w+) (-?[\d.]+)$", out.stdout, re.M)}
    last = (out.stdout.strip().splitlines() or [out.stderr.strip()[-200:]])[-1]
    return values, dt, last


def sitl_flight(seed: int, workdir: Path) -> tuple[Path, dict, str, dict]:
    """(log, ideal OFS_X.. values, description, calibration in force) of one SITL flight."""
    from test_flight_compass_sitl import record_copter

    kind = "friendly" if seed % 2 else "mission"
    rec = record_copter(workdir, seed, kind, drift=True, single=True)
    ideal = {k[len("COMPASS_"):]: v for k, v in rec.injected.exact(0).items()}
    return rec.log, ideal, f"SITL {kind} ({seed})", dict(rec.injected.in_force)


def compare(path: Path, ideal: dict, label: str, in_force: dict, reduce: int) -> tuple:
    """One row: label, apmcal's errors and time, magfit's errors and time, magfit's last line
    when it failed."""
    t0 = time.perf_counter()
    res = calibrate_flight(path)
    t_apm = time.perf_counter() - t0
    values = dict(in_force, **res.params())     # kept in force: the value in force
    e_apm = errors(values, ideal)
    mf, t_mf, last = run_magfit(path, reduce)
    e_mf = errors(mf, ideal) if "COMPASS_OFS_X" in mf else (np.nan,) * 3
    return label, e_apm, t_apm, e_mf, t_mf, last if not mf else ""


def main(argv=None) -> int:
    """Run the comparison and print the table; exit status 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3],
                    help="simulated flights (apmcal_sim.flight seeds)")
    ap.add_argument("--sitl-seeds", type=int, nargs="*", default=[1, 2],
                    help="ArduPilot SITL flights (odd: calibration-friendly, even: a mission)")
    ap.add_argument("--reduce", type=int, default=1, help="magfit_WMM --reduce (1: every sample)")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for seed in args.seeds:
            path = Path(d) / f"flight{seed}.bin"
            comp = sim.default_compasses(seed)[:1]
            truth = sim.write_flight(path, seed=seed, compasses=comp)
            in_force = {sim.param_name(k, 0): v for k, v in comp[0].params.items()}
            rows.append(compare(path, truth["compasses"][0]["ideal"], f"simulated ({seed})",
                                in_force, args.reduce))
        if args.sitl_seeds:
            from ardupilot_sitl import unavailable_reason
            if unavailable_reason():
                print(f"SITL flights skipped: {unavailable_reason()}")
            else:
                for seed in args.sitl_seeds:
                    rows.append(compare(*sitl_flight(seed, Path(d) / f"sitl{seed}"),
                                        args.reduce))
    print("| flight (seed) | apmcal OFS err [mGauss] | DIA/ODI err | MOT err [%] | time [s] "
          "| magfit_WMM OFS err [mGauss] | DIA/ODI err | MOT err [%] | time [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, ea, ta, em, tm, note in rows:
        mf = " | ".join(f"{v:.4g}" for v in em) if np.all(np.isfinite(em)) else f"failed: {note}"
        print(f"| {label} | {ea[0]:.2f} | {ea[1]:.4f} | {ea[2]:.1f} | {ta:.1f} | {mf} | "
              f"{tm:.1f} |")
    ratio = sum(r[4] for r in rows) / sum(r[2] for r in rows)
    print(f"\nmagfit_WMM time / apmcal time: {ratio:.1f}× (same run, same machine)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
