"""What ``apmcal tcal`` prints: per IMU and sensor, ArduPilot's coefficients with their σ."""
from __future__ import annotations

import numpy as np

from apmcal.ardupilot.tcal_params import TEMP_REFERENCE_C, polynomial
from apmcal.report.text import say

UNITS = {"acc": ("m/s²", "accelerometer"), "gyr": ("rad/s", "gyro")}


def print_tcal(results, console) -> None:
    """One block per IMU instance: data used, then c1, c2, c3 ± σ per axis (parameter units,
    1e-6 unit/K^k) and the drift the polynomial describes over the data's range."""
    for r in results:
        still = "" if r.still_s is None else f", {r.still_s:.0f} s still"
        console.print(f"IMU instance {r.instance} ({r.source}{still}): {r.tmin_c:.1f} to "
                      f"{r.tmax_c:.1f} °C")
        for note in r.notes:
            console.print(f"  note: {note}")
        for sensor, fit in r.fits.items():
            unit, name = UNITS[sensor]
            d = np.array([r.tmin_c, r.tmax_c]) - TEMP_REFERENCE_C
            drift = np.diff(polynomial(fit.coeffs, d), axis=0)[0]
            kind = "ACC" if sensor == "acc" else "GYR"
            console.print(f"  {name}: INS_TCAL{r.instance + 1}_{kind}1..3 [1e-6 {unit}/K^k], "
                          f"{fit.n_blocks} blocks, residual RMS "
                          + "/".join(f"{v:.2g}" for v in fit.residual_rms) + f" {unit}")
            for j, axis in enumerate("XYZ"):
                terms = " ".join(f"c{k + 1} {fit.coeffs[k, j]:+.4g} ± {fit.sigma[k, j]:.2g}"
                                 for k in range(3))
                console.print(f"    {axis}  {terms}  drift {drift[j]:+.3g} {unit}")
        if r.withheld:
            say(console, r.withheld, "  ")
