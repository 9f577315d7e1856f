"""The noise terms of a model, fitted to the residuals' Haar wavelet variances by maximum
likelihood — the same criterion the gap scores (:mod:`apmcal.diagnosis.gap`).

For one channel, level j (block m = 2**(j-1) samples at rate fs) has the model variance::

    M_j = σ²·L_j(f_c) + Δ²/12 + q²·Δt·(2m² + 1)/6 + a_t²·T_j + a_s²·S_j

σ the white noise per sample before the on-chip low-pass (gain L_j of a 2nd-order Butterworth
at f_c, 1 without it), Δ the quantization step (uniform rounding error), q the bias random walk
[unit/√s] (the Haar variance of a discrete random walk, derived in the test), and a_t, a_s the
hand tremor and sway amplitudes [deg] of sitl's motion contamination (gyro only; T_j, S_j their
band-averaged Haar gains). With n_j coefficients of mean square V_j, the parameters minimise
Σ_j n_j (V_j / M_j + ln M_j) — the Gaussian likelihood of the coefficients (wavelet Whittle,
in the spirit of GMWM, Guerrier et al. 2013, which fits the same wavelet variances by least
squares). The fit is linear in (σ², q², a_t², a_s²), so it is solved with bounds ≥ 0; the
cut-off f_c is found by a grid search around it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.optimize import minimize_scalar, nnls
from scipy.signal import butter, freqz


TREMOR_BAND_HZ = (4.0, 9.0)        # sitl's motion contamination bands (sitl.truth defaults)
SWAY_BAND_HZ = (0.1, 0.5)
N_FREQ = 4096                      # frequency grid of the Haar gains
CUTOFF_GRID = 24                   # candidate low-pass cut-offs between 2 % and 45 % of fs


@dataclass
class SensorNoise:
    """Noise terms of one sensor; per-axis arrays (3,) in the sensor's unit."""

    sigma: np.ndarray                      # white noise per sample (before the low-pass)
    rw_q: np.ndarray | None = None         # bias random walk [unit/√s]
    cutoff_hz: float | None = None         # low-pass cut-off
    step: np.ndarray | None = None         # quantization step
    uniform: bool = False                  # uniform instead of Gaussian white noise
    tremor_deg: float = 0.0                # motion contamination amplitudes (gyro fit)
    sway_deg: float = 0.0
    levels: dict = field(default_factory=dict)   # the fitted wavelet variances (for plots)


@dataclass
class NoiseModel:
    """The noise terms of every sensor."""

    sensors: dict                       # "acc", "gyr", "mag" -> SensorNoise

    def __getitem__(self, sensor: str) -> SensorNoise:
        return self.sensors[sensor]

    def __contains__(self, sensor: str) -> bool:
        return sensor in self.sensors


def fit_noise(coefficient_sets: list, train: np.ndarray, effects, fs_of: dict,
              steps: dict) -> NoiseModel:
    """Noise terms of each residual block (:class:`~apmcal.diagnosis.gap.BlockCoefficients`,
    named by its first channel's sensor) on the training pieces ``train``. ``fs_of`` gives each
    sensor's sample rate, ``steps`` the quantization step per axis of the sensors the model
    rounds (absent or None: no rounding)."""
    out = {}
    for coeffs in coefficient_sets:
        if not coeffs.block.shape:         # moves: scored, but the noise is the holds'
            continue
        sensor = coeffs.block.names[0].split("_")[0]
        v, n = level_stats(coeffs, train)
        gyro = sensor == "gyr"
        walk = gyro and "bias_random_walk" in effects
        out[sensor] = fit_sensor_noise(
            v, n, fs_of[sensor], lowpass="lowpass_filter" in effects and sensor != "mag",
            step=steps.get(sensor), random_walk=walk,
            tremor=gyro and "motion_contamination" in effects,
            uniform="uniform_noise" in effects,
            pairs=MeanPairs.of(coeffs.block, train) if walk else None)
    return NoiseModel(out)


def level_stats(coeffs, pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean square (levels, channels) and count (levels,) of a block's Haar details over the
    given pieces (levels without a coefficient there are left out at the coarse end)."""
    masks, _, _ = coeffs.masks(pieces)
    v, n = [], []
    for c, m in zip(coeffs.levels, masks):
        if not m.any():
            break
        v.append(np.mean(c.values[m] ** 2, axis=0))
        n.append(float(m.sum()))
    return np.array(v).reshape(len(v), -1), np.array(n)


def _omega() -> np.ndarray:
    return np.linspace(1e-6, np.pi, N_FREQ)


@lru_cache(maxsize=64)
def haar_gain(levels: int) -> np.ndarray:
    """|H_j(ω)|² = (2/m) sin⁴(mω/2) / sin²(ω/2) on the grid, (levels, N_FREQ) (cached: the
    grid is fixed; do not modify the returned array)."""
    w = _omega()
    m = (2.0 ** np.arange(levels))[:, None]
    return (2.0 / m) * np.sin(m * w / 2) ** 4 / np.sin(w / 2) ** 2


@lru_cache(maxsize=512)
def lowpass_gain(levels: int, fs: float, cutoff_hz: float | None) -> np.ndarray:
    """L_j: Haar variance of unit white noise after the Butterworth low-pass, per level."""
    h = haar_gain(levels)
    if cutoff_hz is None or cutoff_hz >= fs / 2:
        g = np.ones(N_FREQ)
    else:
        b, a = butter(2, cutoff_hz / (fs / 2))
        g = np.abs(freqz(b, a, worN=_omega())[1]) ** 2
    return np.trapezoid(h * g, _omega(), axis=1) / np.pi


def random_walk_gain(levels: int, fs: float) -> np.ndarray:
    """Haar variance per unit q² of a discrete random walk, Δt·(2m² + 1)/6."""
    m = 2.0 ** np.arange(levels)
    return (2 * m ** 2 + 1) / 6.0 / fs


def band_gain(levels: int, fs: float, band_hz: tuple[float, float]) -> np.ndarray:
    """Haar variance of the rate of sitl's tremor per deg² amplitude (frequencies uniform in the
    band; a sinusoid of rate amplitude 2πf·A has power (2πfA)²/2)."""
    w = _omega()
    f = w * fs / (2 * np.pi)
    inside = (f >= band_hz[0]) & (f <= band_hz[1])
    if not inside.any():
        return np.zeros(levels)
    power = (2 * np.pi * f[inside]) ** 2 * np.radians(1.0) ** 2 / 2
    return np.mean(haar_gain(levels)[:, inside] * power, axis=1)


def ml_variances(v: np.ndarray, n: np.ndarray, design: np.ndarray, fixed: np.ndarray,
                 iterations: int = 60) -> tuple[np.ndarray, float]:
    """Coefficients c ≥ 0 minimising Σ n (v / M + ln M), M = fixed + design·c (rows: levels of
    possibly several channels, or other variance statistics). Returns (c, objective).

    Fisher scoring: each step is the non-negative least-squares fit of v by M with weights
    n / M² from the previous step (the inverse variance of a mean square of n Gaussian
    terms), which converges to the maximum-likelihood point; bounded first-order optimisers
    stall here because the columns' scales differ by orders of magnitude.
    """
    scale = np.maximum(design.max(axis=0), 1e-300)
    d = design / scale
    floor = 1e-12 * max(float(np.max(v)), 1e-300)
    m = np.maximum(v, floor)
    c = np.zeros(d.shape[1])
    for _ in range(iterations):
        w = np.sqrt(n) / m
        c_new, _ = nnls(d * w[:, None], (v - fixed) * w)
        m = np.maximum(fixed + d @ c_new, floor)
        if np.allclose(c_new, c, rtol=1e-9, atol=1e-300):
            c = c_new
            break
        c = c_new
    return c / scale, float(np.sum(n * (v / m + np.log(m))))


def ml_white(v: np.ndarray, n: np.ndarray, gain: np.ndarray, fixed: float
             ) -> tuple[float, float]:
    """σ² ≥ 0 minimising Σ n (v / M + ln M) with M = σ²·gain + fixed, and the objective.

    Closed form without a fixed part (σ² = Σ n v/gain / Σ n); a 1-D search otherwise.
    """
    def objective(s2):
        m = np.maximum(s2 * gain + fixed, 1e-300)
        return float(np.sum(n * (v / m + np.log(m))))

    if fixed <= 0:
        s2 = float(np.sum(n * v / gain) / np.sum(n))
        return s2, objective(s2)
    hi = max(float(np.max(v / gain)), 1e-300)
    sol = minimize_scalar(lambda x: objective(x * hi), bounds=(0.0, 2.0), method="bounded")
    return float(sol.x * hi), float(sol.fun)


@dataclass
class MeanPairs:
    """Differences of consecutive piece means: what a random walk does between pieces.

    For a random walk of rate q [unit/√s] and white noise σ per sample, the difference of the
    means of two pieces (n_a, n_b samples lasting L_a, L_b [s], G [s] apart) has the variance
    σ²(1/n_a + 1/n_b) + q²(L_a/3 + L_b/3 + G) (the mean of a Wiener process over an interval
    sits a third of the interval from its end; the Allan variance's q²τ/3 is the case
    L_a = L_b = τ, G = 0).
    """

    squares: np.ndarray     # (P, 3) squared differences per axis
    white: np.ndarray       # (P,) 1/n_a + 1/n_b
    walk: np.ndarray        # (P,) L_a/3 + L_b/3 + G [s]

    @classmethod
    def of(cls, block, pieces: np.ndarray) -> "MeanPairs | None":
        keep = np.flatnonzero(np.isin(block.piece, pieces))
        keep = keep[np.argsort(block.t[block.i0[keep]])]
        if len(keep) < 3:
            return None
        i0, i1 = block.i0[keep], block.i1[keep]
        means = np.array([block.values[a:b].mean(axis=0) for a, b in zip(i0, i1)])
        start, end = block.t[i0], block.t[i1 - 1]
        n = (i1 - i0).astype(float)
        gap = np.maximum(start[1:] - end[:-1], 0.0)
        length = end - start
        return cls(np.diff(means, axis=0) ** 2, 1 / n[:-1] + 1 / n[1:],
                   length[:-1] / 3 + length[1:] / 3 + gap)


def fit_channels(v: np.ndarray, n: np.ndarray, fs: float, *, cutoff_hz: float | None,
                 step: np.ndarray | None, random_walk: bool, tremor: bool,
                 pairs: MeanPairs | None = None
                 ) -> tuple[np.ndarray, np.ndarray | None, float, float, float]:
    """One sensor's three channels with shared motion amplitudes; with a random walk the
    piece-mean ``pairs`` add its slow scales to the levels'.

    Returns per-axis σ, per-axis q (or None), tremor and sway [deg], and the objective.
    """
    levels, axes = v.shape
    lp = lowpass_gain(levels, fs, cutoff_hz)
    quant = np.zeros(axes) if step is None else np.asarray(step) ** 2 / 12.0
    if not (random_walk or tremor):             # white only: axis by axis, 1-D
        fits = [ml_white(v[:, a], n, lp, quant[a]) for a in range(axes)]
        return (np.sqrt([f[0] for f in fits]), None, 0.0, 0.0, float(sum(f[1] for f in fits)))
    rows_v, rows_n = [v], [n]
    white, walk = [lp], [random_walk_gain(levels, fs)]
    fixed = [np.ones(levels)]
    if random_walk and pairs is not None:
        rows_v.append(pairs.squares)
        rows_n.append(np.ones(len(pairs.white)))
        white.append(pairs.white)
        walk.append(pairs.walk)
        fixed.append(pairs.white)       # a pair's rounding noise: Δ²/12 per mean, like σ²
    v_all, n_all = np.vstack(rows_v), np.concatenate(rows_n)
    rows = len(n_all)
    white, walk, fixed = np.concatenate(white), np.concatenate(walk), np.concatenate(fixed)
    columns = [np.kron(np.eye(axes), white[:, None])]                   # σ² per axis
    if random_walk:
        columns.append(np.kron(np.eye(axes), walk[:, None]))
    if tremor:
        bands = np.zeros((rows, 2))
        bands[:levels] = np.column_stack([band_gain(levels, fs, TREMOR_BAND_HZ),
                                          band_gain(levels, fs, SWAY_BAND_HZ)])
        columns.append(np.tile(bands, (axes, 1)))
    coef, obj = ml_variances(v_all.T.ravel(), np.tile(n_all, axes), np.hstack(columns),
                             np.kron(quant, fixed))
    sigma = np.sqrt(coef[:axes])
    q = np.sqrt(coef[axes:2 * axes]) if random_walk else None
    amps = np.sqrt(coef[-2:]) if tremor else (0.0, 0.0)
    return sigma, q, float(amps[0]), float(amps[1]), obj


def fit_sensor_noise(v: np.ndarray, n: np.ndarray, fs: float, *, lowpass: bool = False,
                     step: np.ndarray | None = None, random_walk: bool = False,
                     tremor: bool = False, uniform: bool = False,
                     pairs: MeanPairs | None = None) -> SensorNoise:
    """Noise terms of one sensor from its level variances ``v`` (levels, 3) and counts ``n``."""
    cutoffs = [None]       # None: no filter (the cut-off at or above Nyquist)
    if lowpass:
        cutoffs += list(np.geomspace(0.02 * fs, 0.45 * fs, CUTOFF_GRID))
    best = None
    for fc in cutoffs:
        out = fit_channels(v, n, fs, cutoff_hz=fc, step=step, random_walk=random_walk,
                           tremor=tremor, pairs=pairs)
        if best is None or out[-1] < best[1][-1]:
            best = (fc, out)
    fc, (sigma, q, a_t, a_s, _) = best
    return SensorNoise(sigma=sigma, rw_q=q, cutoff_hz=fc, step=step, uniform=uniform,
                       tremor_deg=a_t, sway_deg=a_s,
                       levels={"v": v.tolist(), "n": n.tolist()})


def lattice_step(x: np.ndarray, min_fraction: float = 0.9) -> float | None:
    """The quantization step of samples on a lattice (their most common non-zero successive
    difference, when ``min_fraction`` of the differences are multiples of it), else None."""
    d = np.abs(np.diff(np.asarray(x, float)))
    d = d[d > 0]
    if len(d) < 100:
        return None
    step = float(np.min(d))
    rel = d / step
    on_lattice = np.abs(rel - np.round(rel)) < 1e-3 * np.maximum(rel, 1)
    if on_lattice.mean() < min_fraction or np.median(rel) > 50:
        return None
    return step
