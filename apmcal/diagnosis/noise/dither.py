"""White noise below the readings' step, measured by how often the readings change.

A sensor read through an integer format (ArduPilot's RAW_IMU: int16 mrad/s, truncated toward
zero) whose noise is a fraction of a step reads one value for long runs: the wavelet variances
see the rounding (Δ²/12) and not the noise, and the white level anchored there
(:func:`apmcal.diagnosis.noise.fit.fit_channels`) comes out as zero. The noise still shows — as
the flicker between two neighbouring values while the signal passes a rounding threshold —
and a twin without it reads a clean staircase that never flickers: every level-1 coefficient
of the real flicker is then a gap no effect can close, and the null sessions drawn from such a
model are all the same staircase (no spread, so chance seems to give nothing).

With the model's prediction μ at a sample, the thresholds around it at distances d (the
nearer) and g − d (g the width of the count μ is in: one step, or two for the count of 0 of a
truncating format) and noise of distribution F and standard deviation σ, the reading is beyond
the nearer threshold with probability q₁ = 1 − F(d/σ), beyond the other with q₂ = 1 − F((g −
d)/σ), and between them otherwise. Successive samples are independent draws around nearly the
same μ (μ moves far less than σ from one sample to the next in a hold), so they differ with
probability 1 − q₁² − q₂² − (1 − q₁ − q₂)², and the expected number of changes is

    E(σ) = Σ_i 1 − q₁ᵢ² − q₂ᵢ² − (1 − q₁ᵢ − q₂ᵢ)²,

which grows with σ. The σ where E(σ) equals the changes counted in the readings (a
method-of-moments estimate on that one statistic) is what makes the twin flicker as often as
the board — Gaussian noise, or uniform noise when that is modelled (SITL's, ±√3 σ). Up to one
step (a third threshold is then more than a step away), above which the rounding error is
white and the wavelet estimate holds. The sum is taken over histograms of d on a log scale
(bins 2 % wide), one per width g, so that each trial σ costs a few hundred operations, not one
per sample.
"""
from __future__ import annotations

import numpy as np
from scipy.special import ndtr

ITERATIONS = 15         # bisection steps on log σ over 1e-4 … 1 step: to 0.03 % of σ
LOWEST, HIGHEST = 1e-4, 1.0     # σ tried [steps]
BINS = np.geomspace(1e-7, 2.0, 860)     # d [steps]: 2 % wide, everything below in the first
CENTRES = np.concatenate([[0.0], np.sqrt(BINS[:-1] * BINS[1:]), [BINS[-1]]])


def dither_sigma(readings: np.ndarray, predicted: np.ndarray, i0: np.ndarray, i1: np.ndarray,
                 step: np.ndarray, truncated: bool, uniform: bool = False) -> np.ndarray:
    """Per-axis σ [unit] of the white noise that makes readings of ``predicted`` change as
    often as ``readings`` do between successive samples of the pieces ``[i0, i1)``.

    Parameters
    ----------
    readings : (n, c) array
        The readings, on the format's lattice (truncated ones moved half a step out, as
        :func:`apmcal.diagnosis.twin.simulate.truncated_reading` leaves them).
    predicted : (n, c) array
        The model's value at each sample [unit].
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces (pairs across pieces are not counted).
    step : (c,) array
        The format's step [unit].
    truncated : bool
        Counts truncated toward zero (thresholds at the non-zero multiples of the step), else
        rounded to nearest (thresholds half a step between them).
    uniform : bool
        Uniform noise of standard deviation σ (half-width √3 σ) instead of Gaussian.

    Returns
    -------
    (c,) array
        σ [unit], between 1e-4 and 1 step; NaN for an axis without a pair of samples.
    """
    pairs = _pairs(i0, i1)
    out = np.full(readings.shape[1], np.nan)
    if not len(pairs):
        return out
    for k in range(readings.shape[1]):
        y = readings[pairs, k] / step[k]
        changed = int(np.sum(np.abs(readings[pairs + 1, k] / step[k] - y) > 1e-6))
        near, width = _thresholds(predicted[pairs, k] / step[k], truncated)
        groups = []
        for g in np.unique(width):
            counts = np.bincount(np.searchsorted(BINS, near[width == g]),
                                 minlength=len(BINS) + 1)
            used = np.flatnonzero(counts)
            groups.append((counts[used], CENTRES[used], float(g)))
        out[k] = step[k] * _matching_sigma(changed, groups, uniform)
    return out


def _pairs(i0: np.ndarray, i1: np.ndarray) -> np.ndarray:
    """First samples of the successive pairs inside the pieces."""
    parts = [np.arange(a, b - 1) for a, b in zip(i0, i1) if b - a > 1]
    return np.concatenate(parts) if parts else np.zeros(0, int)


def _thresholds(mu: np.ndarray, truncated: bool) -> tuple[np.ndarray, np.ndarray]:
    """For each value μ [steps]: the distance to its nearer rounding threshold, and the width
    of the count it is in (both thresholds' distances add up to it) [steps]."""
    if truncated:       # counts k ≥ 1 on [k, k + 1), 0 on (−1, 1), k ≤ −1 on (k − 1, k]
        lower = np.where(mu >= 1, np.floor(mu), np.where(mu > -1, -1.0, np.floor(mu)))
        upper = np.where(mu <= -1, np.ceil(mu), np.where(mu < 1, 1.0, np.ceil(mu)))
        upper = np.where(upper == lower, upper + 1, upper)     # μ on a whole step
    else:               # counts k on [k − ½, k + ½)
        lower = np.floor(mu - 0.5) + 0.5
        upper = lower + 1.0
    return np.minimum(mu - lower, upper - mu), upper - lower


def _cdf(x: np.ndarray, sigma: float, uniform: bool) -> np.ndarray:
    if uniform:
        return np.clip(0.5 + x / (2.0 * np.sqrt(3.0) * sigma), 0.0, 1.0)
    return ndtr(x / sigma)


def _expected_changes(sigma: float, groups: list, uniform: bool = False) -> float:
    total = 0.0
    for counts, near, width in groups:
        q1 = 1.0 - _cdf(near, sigma, uniform)             # beyond the nearer threshold
        q2 = 1.0 - _cdf(width - near, sigma, uniform)     # beyond the other one
        total += float(np.sum(counts * (1.0 - q1 ** 2 - q2 ** 2 - (1.0 - q1 - q2) ** 2)))
    return total


def _matching_sigma(changed: int, groups: list, uniform: bool = False) -> float:
    """σ [steps] with E(σ) = ``changed``, by bisection on log σ within [LOWEST, HIGHEST]."""
    lo, hi = np.log(LOWEST), np.log(HIGHEST)
    if changed >= _expected_changes(HIGHEST, groups, uniform):
        return HIGHEST
    if changed <= _expected_changes(LOWEST, groups, uniform):
        return LOWEST
    for _ in range(ITERATIONS):
        mid = 0.5 * (lo + hi)
        if _expected_changes(float(np.exp(mid)), groups, uniform) < changed:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))
