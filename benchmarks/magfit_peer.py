"""apmcal's flight compass fit beside pymavlink's magfit_WMM.py on simulated flights with known
truth: errors of both against the injected parameters, and their times, in the same run.

    python benchmarks/magfit_peer.py [--seeds 1 2 3] [--reduce 1]

Each flight is ``apmcal_sim.flight`` (about 2 minutes at 25 Hz, the logged yaw biased 8° with a
heading-dependent part) with ONE compass (magfit_WMM reads the MAG messages without telling the
instances of a 4.x log apart), a stale calibration in force and the current logged in BAT.
magfit_WMM runs as users run it with the right options: ``--elliptical --cmot --att-source ATT``
(the log has no XKF1), on the whole log; apmcal as ``calibrate_flight`` (the orientation search
included). Errors: the largest |COMPASS_OFS error| [mGauss], the largest |DIA/ODI error|, and
|ΔMOT|/|MOT| [%]. magfit prints offsets as whole mGauss and DIA/ODI/MOT to 3 decimals, which
bounds its error from below by 0.5 mGauss and 0.0005.
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

from apmcal.calibration.flight import calibrate_flight
from apmcal_sim import flight as sim

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


def main(argv=None) -> int:
    """Run the comparison and print the table; exit status 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--reduce", type=int, default=1, help="magfit_WMM --reduce (1: every sample)")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for seed in args.seeds:
            path = Path(d) / f"flight{seed}.bin"
            comp = sim.default_compasses(seed)[:1]
            truth = sim.write_flight(path, seed=seed, compasses=comp)
            ideal = truth["compasses"][0]["ideal"]
            t0 = time.perf_counter()
            res = calibrate_flight(path)
            t_apm = time.perf_counter() - t0
            e_apm = errors(res.params(), ideal)
            mf, t_mf, last = run_magfit(path, args.reduce)
            e_mf = errors(mf, ideal) if "COMPASS_OFS_X" in mf else (np.nan,) * 3
            rows.append((seed, e_apm, t_apm, e_mf, t_mf, last if not mf else ""))
    print("| flight (seed) | apmcal OFS err [mGauss] | DIA/ODI err | MOT err [%] | time [s] "
          "| magfit_WMM OFS err [mGauss] | DIA/ODI err | MOT err [%] | time [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed, ea, ta, em, tm, note in rows:
        mf = " | ".join(f"{v:.4g}" for v in em) if np.all(np.isfinite(em)) else f"failed: {note}"
        print(f"| {seed} | {ea[0]:.2f} | {ea[1]:.4f} | {ea[2]:.1f} | {ta:.1f} | {mf} | {tm:.1f} |")
    ratio = sum(r[4] for r in rows) / sum(r[2] for r in rows)
    print(f"\nmagfit_WMM time / apmcal time: {ratio:.1f}× (same run, same machine)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
