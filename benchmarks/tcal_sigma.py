"""Is the σ `apmcal tcal` reports honest? (fit − injected)/σ over many simulated warm-ups.

    python benchmarks/tcal_sigma.py [--seeds 12] [--extra quantization gyro_bias_random_walk]

Each seed: sitl's error model (``ImuErrorModel``) drives a still, level board for 300 s at
50 Hz while it warms from 22 °C by 26 K (τ 120 s), with temperature drift, white noise, biases
and the 20 Hz low-pass, plus the ``--extra`` effects; the still blocks are fitted as
``apmcal tcal`` does. Printed per sensor: the RMS of (fit − truth)/σ for c1, c2, c3 over
seeds × axes (1 for an honest σ) and the largest |z|. The truth is linear (c2 = c3 = 0).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator
sys.path.insert(0, str(ROOT / "tests"))

from sitl_helpers import only, still  # noqa: E402

from apmcal.preprocessing.static import find_static_segments  # noqa: E402
from apmcal.preprocessing.tcal_blocks import still_blocks  # noqa: E402
from apmcal.solvers.tcal import fit_tcal  # noqa: E402

BASE = ["temperature_drift", "acc_noise", "gyro_noise", "acc_bias", "gyro_bias",
        "lowpass_filter"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--extra", nargs="*", default=[], help="further sitl effects")
    args = ap.parse_args()
    z = {"acc": [], "gyr": []}
    for seed in range(args.seeds):
        truth = only(*BASE, *args.extra, seed=seed)
        truth.temperature.update({"ambient_c": 22.0, "rise_k": 26.0, "tau_s": 120.0})
        s = still(truth, 300.0, fs=50.0, seed=seed + 100)
        temp = s["model"].temperature(s["t"])
        blocks = still_blocks(s["t"], temp, s["acc"], s["gyr"],
                              find_static_segments(s["t"], s["acc"], s["gyr"]))
        for sensor, values, key in (("acc", blocks.acc, "acc_coef"),
                                    ("gyr", blocks.gyr, "gyro_coef")):
            fit = fit_tcal(blocks.temp_c, values, blocks.n, blocks.group, blocks.t_s)
            expect = np.array([np.asarray(truth.temperature[key]) * 1e6, np.zeros(3),
                               np.zeros(3)])
            z[sensor].append((fit.coeffs - expect) / fit.sigma)
    print(f"{args.seeds} seeds, effects {', '.join(BASE + args.extra)}")
    for sensor, values in z.items():
        v = np.array(values)
        rms = np.sqrt((v ** 2).mean(axis=(0, 2)))
        print(f"{sensor}: RMS z of c1, c2, c3 = {', '.join(f'{x:.2f}' for x in rms)}; "
              f"largest |z| {np.abs(v).max():.2f}")


if __name__ == "__main__":
    main()
