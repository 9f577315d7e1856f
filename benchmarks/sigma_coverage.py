"""Is the σ `apmcal log` reports for a Ferraris session honest? |error| < 3σ over sitl seeds.

    python benchmarks/sigma_coverage.py [--seeds 10] [--nominal]

Each seed: a sitl Ferraris session (the bundled sample's script: six faces, three 360° turns,
469 s) with every effect on (``--nominal``: only the errors ArduPilot's parameters hold, noise,
local gravity and the Earth rate), made in one pass of sitl's error model at 50 Hz (tests/sitl_helpers.py
``session_recording``) and calibrated as ``apmcal log --method ferraris --lat 5.6037`` does.
Printed per parameter group (accelerometer and gyro offsets and matrices): the share with
|estimate − truth| < 3σ, the median |z| (about 0.67 for an honest Gaussian σ) and the largest,
and the σ against the noise-only σ (how much the misfit widened it).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator
sys.path.insert(0, str(ROOT / "tests"))

from sitl_helpers import session_recording, sigma_z  # noqa: E402

from apmcal.calibration.log import Options, calibrate  # noqa: E402

LAT = 5.6037                # sitl's default home (Accra)
# a clean session: the errors ArduPilot's parameters hold, noise, and the physics apmcal
# expects (local gravity: without it sitl's g is 9.80665, apmcal's 9.7808 at this latitude)
CLEAN = ["nominal", "local_gravity", "earth_rate"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--nominal", action="store_true", help="only the nominal effects")
    args = ap.parse_args()
    switch = (["all"], CLEAN) if args.nominal else ((), ())
    groups: dict[str, list] = {}
    widening = []
    for seed in range(1, args.seeds + 1):
        truth, rec, vehicle = session_recording(seed, *switch)
        cal = calibrate(rec, Options(method="ferraris", lat_deg=LAT))
        for k, z in sigma_z(truth, cal, vehicle).items():
            groups.setdefault(k, []).extend(np.abs(z))
        noise_only = cal.report.six_face.sigma_noise_only["offset"]
        widening.append(cal.sensors["acc"].sigma["offset"] / noise_only)
    every = np.concatenate([np.asarray(v) for v in groups.values()])
    print(f"{args.seeds} seeds, {'nominal effects' if args.nominal else 'every effect'} on")
    for k, v in groups.items():
        v = np.asarray(v)
        print(f"  {k:11s} {np.mean(v < 3):5.0%} within 3σ, median |z| {np.median(v):.2f}, "
              f"largest {v.max():.1f} (n = {v.size})")
    print(f"  all         {np.mean(every < 3):5.1%} within 3σ (n = {every.size})")
    print(f"  acc offset σ / noise-only σ: median {np.median(widening):.2f}, "
          f"largest {np.max(widening):.1f}")


if __name__ == "__main__":
    main()
