"""Do an effect's fitted parameters differ from the values that switch it off? (Wald test)

Held-out evidence says a model predicts better; on short sessions a model with many parameters
(gyro scale and misalignment: nine) can reach the evidence threshold by chance, when its fitted
values are all within their noise of "no effect". The Wald test asks the second question
directly: χ² = Σ ((θ − θ₀)/σ)² over the effect's parameters with a known σ (the fit's,
correlations between them ignored), against the χ² distribution with one degree of freedom per
parameter. An effect must pass both (``MAX_P_VALUE``). Effects whose parameters have no
least-squares σ (noise terms: random walk, low-pass, quantization, uniform noise, hold motion)
are judged by their evidence alone.
"""
from __future__ import annotations

import numpy as np
from scipy.special import chdtrc

MAX_P_VALUE = 1e-3
TESTED = {                      # effect: the parameters whose null value switches it off
    "temperature_drift": ("gyro_coef", "acc_coef"),
    "bias_drift": ("gyro_drift",),
    "triangle_drift": ("speed",),
    "g_sensitivity": ("matrix",),
    "earth_rate": ("vertical", "horizontal"),
    "cross_axis": ("alpha",),
    "scale_nonlinearity": ("k2",),
    "gyro_scale": ("scale", "misalignment"),
    "time_offset": ("delay",),
    "mag_interference": ("per_amp",),
}
NULL_VALUE = {("gyro_scale", "scale"): 1.0}     # every other parameter's is 0


def wald_p_value(name: str, params: dict) -> float | None:
    """p-value of "the effect is off" given its fitted ``params`` ({key: {value, sigma}}),
    or None when no parameter of it has a σ to test with."""
    z2 = []
    for key in TESTED.get(name, ()):
        if key not in params:
            continue
        value = np.ravel(np.asarray(params[key]["value"], float))
        sigma = np.ravel(np.asarray(params[key]["sigma"], float))
        if sigma.size != value.size:
            continue
        ok = np.isfinite(value) & np.isfinite(sigma) & (sigma > 0)
        z2.extend((((value - NULL_VALUE.get((name, key), 0.0)) / sigma)[ok] ** 2).tolist())
    if not z2:
        return None
    # the χ² survival function as scipy.stats.chi2.sf computes it (the same special function),
    # without importing scipy.stats (0.6 s) at the start of every `apmcal gap`
    return float(chdtrc(len(z2), sum(z2)))
