"""What ``apmcal tcal`` prints: first what it proposes, in words (the HTML page's first lines
too), then per IMU and sensor ArduPilot's coefficients with their σ."""
from __future__ import annotations

import numpy as np

from apmcal.ardupilot.tcal_params import TEMP_REFERENCE_C, polynomial
from apmcal.report.text import say

UNITS = {"acc": ("m/s²", "accelerometer"), "gyr": ("rad/s", "gyro")}


def action(results) -> list[str]:
    """What ``apmcal tcal`` proposes, in words, one line per IMU instance: the console's and the
    HTML page's first lines."""
    out = []
    for r in results:
        n = r.instance + 1
        if r.withheld:
            why = r.withheld.removeprefix(f"INS_TCAL{n}_* not proposed: ")
            out.append(f"IMU {r.instance}: nothing proposed (INS_TCAL{n}_*) — {why}")
            continue
        d = np.array([r.tmin_c, r.tmax_c]) - TEMP_REFERENCE_C
        drift = {s: float(np.max(np.abs(np.diff(polynomial(f.coeffs, d), axis=0))))
                 for s, f in r.fits.items()}
        said = []
        if "acc" in drift:
            said.append(f"{drift['acc']:.2g} m/s² of the accelerometer")
        if "gyr" in drift:
            said.append(f"{np.degrees(drift['gyr']):.2g} °/s of the gyro")
        out.append(f"IMU {r.instance}: proposed — enable its temperature calibration "
                   f"(INS_TCAL{n}_ENABLE 1 and its coefficients, for {r.tmin_c:.1f} to "
                   f"{r.tmax_c:.1f} °C): it takes out a drift of up to "
                   + " and ".join(said) + " over that range; it takes effect at the next "
                   "reboot")
    return out


def print_tcal(results, console) -> None:
    """What is proposed, in words (:func:`action`); then one block per IMU instance: data
    used, c1, c2, c3 ± σ per axis (parameter units, 1e-6 unit/K^k) and the drift the
    polynomial describes over the data's range."""
    for line in action(results):
        say(console, line)
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
