"""Physical limits of the candidate effects' parameters.

An effect fitted far outside what a MEMS IMU of the APM 2.x class (and its successors) can
have is not that effect: its parameters are standing in for something the candidate list does
not hold — most often a move that is not a pure turn about the sensor (the board swung on an
arm, a lever arm between the IMU and the centre of rotation), whose centripetal acceleration a
cross-axis term, a quadratic scale or a delay can partly mimic. Such an effect keeps its
evidence in the report but is marked implausible and never selected.

Limits are generous multiples of the InvenSense MPU-6000 / MPU-6050 datasheet values (PS-MPU-
6000A rev. 3.4), so that a real but poor sensor still passes:

====================  ======================================  ================================
parameter             limit                                   datasheet
====================  ======================================  ================================
alpha (cross-axis)    0.05 rad                                cross-axis sensitivity ±2 %
k2 (quadratic scale)  1e-3 1/(m/s²) (1 % of the reading at g)  nonlinearity 0.5 %
gyro scale − 1        0.1                                     sensitivity tolerance ±3 %
gyro misalignment     0.05 rad                                cross-axis sensitivity ±2 %
delay                 0.05 s                                  acc and gyro sampled together
g-sensitivity         2e-3 rad/s per m/s² (≈ 1.1 °/s/g)        linear acceleration sens. 0.1 °/s/g
gyro temperature      5e-3 rad/s per K                        ZRO variation ±20 °/s over 125 K
acc temperature       0.05 m/s² per K                         zero-G ±35 mg (x, y), ±60 (z) in 0-70 °C
bias drift            1e-4 rad/s per s                        -
Earth rate            up to twice Ω in each part              -
====================  ======================================  ================================
"""
from __future__ import annotations

import numpy as np

LIMITS = {                      # (effect, parameter): largest plausible |value| (of value − 1)
    ("cross_axis", "alpha"): 0.05,
    ("scale_nonlinearity", "k2"): 1e-3,
    ("gyro_scale", "scale"): 0.1,
    ("gyro_scale", "misalignment"): 0.05,
    ("time_offset", "delay"): 0.05,
    ("g_sensitivity", "matrix"): 2e-3,
    ("temperature_drift", "gyro_coef"): 5e-3,
    ("temperature_drift", "acc_coef"): 0.05,
    ("bias_drift", "gyro_drift"): 1e-4,
}
OFFSET_FROM_ONE = {("gyro_scale", "scale")}
EARTH_RATE_FACTOR = 2.0


def implausible(name: str, params: dict) -> str | None:
    """Why the fitted ``params`` of effect ``name`` cannot be that effect, or None. A parameter
    without a value (NaN: a half of the data could not fit it, e.g. too few orientations in
    it) leaves the effect undetermined, which counts the same."""
    for (effect, key), limit in LIMITS.items():
        if effect != name or key not in params:
            continue
        value = np.asarray(params[key]["value"], dtype=float)
        if not np.all(np.isfinite(value)):
            return f"{key} not determined by both halves of the data"
        if (effect, key) in OFFSET_FROM_ONE:
            value = value - 1.0
        worst = float(np.nanmax(np.abs(value))) if value.size else 0.0
        if worst > limit:
            return f"{key} {worst:.3g} beyond the physical limit {limit:g}"
    if name == "earth_rate":
        return _earth_rate(params)
    return None


def _earth_rate(params: dict) -> str | None:
    from apmcal.core.constants import EARTH_RATE

    for key in ("vertical", "horizontal"):
        if key in params:
            value = abs(float(np.asarray(params[key]["value"], dtype=float)))
            if value > EARTH_RATE_FACTOR * EARTH_RATE:
                return (f"{key} part {value:.3g} rad/s, more than {EARTH_RATE_FACTOR:g}× the "
                        f"Earth's rate {EARTH_RATE:.3g} rad/s")
    return None
