"""The noise terms of a model, fitted to the residuals' Haar wavelet variances by maximum
likelihood — the same criterion the gap scores (:mod:`apmcal.diagnosis.scoring.gap`).

For one channel, level j (block m = 2**(j-1) samples at rate fs) has the model variance::

    M_j = σ²·L_j(f_c) + Δ²/12 + q²·Δt·(2m² + 1)/6

σ the white noise per sample before the on-chip low-pass (gain L_j of a 2nd-order Butterworth
at f_c, 1 without it), Δ the quantization step (uniform rounding error) and q the bias random
walk [unit/√s] (the Haar variance of a discrete random walk, checked in the tests). With n_j
coefficients of mean square V_j, the parameters minimise Σ_j n_j (V_j / M_j + ln M_j) — the
Gaussian likelihood of the coefficients (wavelet Whittle, in the spirit of GMWM, Guerrier et
al. 2013, which fits the same wavelet variances by least squares). The fit is linear in
(σ², q²), so it is solved with bounds ≥ 0; the cut-off f_c is found by a grid search around
it. A random walk also shows between pieces (:class:`MeanPairs`). The motion inside the holds
is measured, not fitted here (:mod:`apmcal.diagnosis.session.hold_motion`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.optimize import nnls

from apmcal.diagnosis.compute import reuse

N_FREQ = 4096                      # frequency grid of the Haar gains
CUTOFF_GRID = 30                   # candidate low-pass cut-offs between fs/32 and 45 % of fs
# ArduPilot logs its IMU filtered by INS_GYRO_FILTER / INS_ACCEL_FILTER (20 Hz by default) at
# the loop rate (400 Hz on a copter): a twentieth of the logging rate (ardupilot-facts.md "What
# the telemetry really carries" and "Dataflash logs (.bin)"); an on-chip filter sits higher
# (MPU-6000 DLPF 20-256 Hz read at 50-1000 Hz). Below fs/32 a "filter" would only be a way to
# reshape any slow power with an absurd white level behind it
LOWEST_CUTOFF = 1.0 / 32


@dataclass
class SensorNoise:
    """Noise terms of one sensor; per-axis arrays (3,) in the sensor's unit.

    Attributes
    ----------
    sigma : (3,) array
        White noise per sample (before the low-pass) [unit].
    rw_q : (3,) array or None
        Bias random walk [unit/√s].
    cutoff_hz : float or None
        Low-pass cut-off [Hz].
    step : (3,) array or None
        Quantization step [unit].
    uniform : bool
        Uniform instead of Gaussian white noise.
    tremor_deg, sway_deg : float
        Motion contamination amplitudes [deg] (:mod:`apmcal.diagnosis.session.hold_motion`).
    motion_confirmed : tuple of float
        κ of the sway and tremor bands (same module).
    levels : dict
        The fitted wavelet variances, "v" (levels × axes) [unit²] and their counts "n"
        (for plots).
    """

    sigma: np.ndarray                      # white noise per sample (before the low-pass)
    rw_q: np.ndarray | None = None         # bias random walk [unit/√s]
    cutoff_hz: float | None = None         # low-pass cut-off
    step: np.ndarray | None = None         # quantization step
    uniform: bool = False                  # uniform instead of Gaussian white noise
    tremor_deg: float = 0.0                # motion contamination amplitudes [deg]
    sway_deg: float = 0.0                  # (apmcal.diagnosis.session.hold_motion)
    motion_confirmed: tuple = ()           # κ of the sway and tremor bands (same module)
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
              steps: dict, truncated: bool = False, origins: dict | None = None) -> NoiseModel:
    """Noise terms of each residual block (:class:`~apmcal.diagnosis.scoring.gap.BlockCoefficients`,
    named by its first channel's sensor) on the training pieces ``train``. ``fs_of`` gives each
    sensor's sample rate, ``steps`` the quantization step per axis of the sensors the model
    rounds (absent or None: no rounding). The low-pass, when modelled, is one cut-off for the
    accelerometer and the gyro, as the MPU-6000's DLPF (and sitl's ``lowpass_hz``) is.

    Parameters
    ----------
    coefficient_sets : list of BlockCoefficients
        The residual blocks' coefficients (moves are skipped).
    train : (k,) int array
        Session-wide ids of the training pieces.
    effects : collection of str
    fs_of : dict
        Sample rate of each sensor [Hz].
    steps : dict
        Quantization step (3,) of each sensor [its unit], or None.
    truncated : bool
        Whether the integer readings of the blocks that keep them (``readings``) are
        truncated toward zero (else rounded): below their step, the white noise is the one
        that makes them change as often as they do (:func:`apmcal.diagnosis.noise.dither.
        dither_sigma`), where the wavelet variances only see the rounding.
    origins : dict, optional
        The raw value of a count of 0 of each such sensor, (3,) [its unit] (0 by default:
        :attr:`apmcal.diagnosis.session.log.Session.lattice`).

    Returns
    -------
    NoiseModel
    """
    inputs, flicker = {}, {}
    for coeffs in coefficient_sets:
        if not coeffs.block.shape:         # moves: scored, but the noise is the holds'
            continue
        sensor = coeffs.block.names[0].split("_")[0]
        # a sensor the model leaves as another model had it: its statistics are that one's
        v, n = reuse.derived(coeffs, "levels", train, lambda c=coeffs: level_stats(c, train))
        floor = reuse.derived(coeffs, "floor", train, lambda c=coeffs: floor_stat(c.block, train))
        walk = sensor == "gyr" and "bias_random_walk" in effects
        inputs[sensor] = dict(v=v, n=n, fs=fs_of[sensor], step=steps.get(sensor),
                              random_walk=walk, floor=floor,
                              pairs=MeanPairs.of(coeffs.block, train) if walk else None)
        if coeffs.block.readings is not None and steps.get(sensor) is not None:
            flicker[sensor] = _flicker_sigma(coeffs.block, train, steps[sensor], truncated,
                                             "uniform_noise" in effects,
                                             (origins or {}).get(sensor, 0.0))
    filtered = [s for s in ("acc", "gyr") if s in inputs]
    cutoff = shared_cutoff([inputs[s] for s in filtered]) if "lowpass_filter" in effects \
        else None
    out = {}
    for sensor, kw in inputs.items():
        sigma, q, _ = fit_channels(**kw, cutoff_hz=cutoff if sensor in filtered else None)
        if sensor in flicker:   # the noise's own level where the rounding hides it
            gain = marginal_gain(kw["fs"], cutoff if sensor in filtered else None)
            sigma = np.fmax(sigma, flicker[sensor] / np.sqrt(gain))
        out[sensor] = SensorNoise(sigma=sigma, rw_q=q,
                                  cutoff_hz=cutoff if sensor in filtered else None,
                                  step=kw["step"], uniform="uniform_noise" in effects,
                                  levels={"v": kw["v"].tolist(), "n": kw["n"].tolist()})
    return NoiseModel(out)


def _flicker_sigma(block, train: np.ndarray, step: np.ndarray, truncated: bool,
                   uniform: bool, origin=0.0) -> np.ndarray:
    """:func:`~apmcal.diagnosis.noise.dither.dither_sigma` of a block that keeps its integer
    readings, on the training pieces (the model's value: the readings minus the residuals),
    counted from the count 0 at ``origin``."""
    from apmcal.diagnosis.noise.dither import dither_sigma

    keep = np.isin(block.piece, train)
    readings = block.readings - origin
    return dither_sigma(readings, readings - block.values, block.i0[keep], block.i1[keep],
                        np.asarray(step, float), truncated, uniform)


@lru_cache(maxsize=512)
def marginal_gain(fs: float, cutoff_hz: float | None) -> float:
    """Variance of unit white noise after the low-pass, per sample (1 without it).

    Parameters
    ----------
    fs : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Low-pass cut-off [Hz].

    Returns
    -------
    float
    """
    if cutoff_hz is None or cutoff_hz >= fs / 2:
        return 1.0
    return float(np.trapezoid(_filter_power_gain(cutoff_hz, fs), _omega()) / np.pi)


def shared_cutoff(sensors: list) -> float | None:
    """The low-pass cut-off [Hz] that fits all ``sensors`` (fit_channels keyword sets, one
    rate) best over all levels, or None when no filter fits better than none.

    Parameters
    ----------
    sensors : list of dict
        :func:`fit_channels` keyword arguments of each sensor (all of one ``fs``).

    Returns
    -------
    float or None
        Cut-off [Hz], one of ``CUTOFF_GRID`` values from fs/32 to 0.45·fs.
    """
    fs = sensors[0]["fs"]
    best, best_obj = None, np.inf
    for fc in [None] + list(np.geomspace(LOWEST_CUTOFF * fs, 0.45 * fs, CUTOFF_GRID)):
        obj = sum(fit_channels(**kw, cutoff_hz=fc)[-1] for kw in sensors)
        if obj < best_obj:
            best, best_obj = fc, obj
    return best


def level_stats(coeffs, pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean square (levels, channels) and count (levels,) of a block's Haar details over the
    given pieces (levels without a coefficient there are left out at the coarse end).

    Parameters
    ----------
    coeffs : BlockCoefficients
    pieces : (k,) int array
        Session-wide piece ids.

    Returns
    -------
    v : (levels, c) array
        Mean square per level and channel [unit²].
    n : (levels,) array
        Coefficients per level.
    """
    masks, _, _ = coeffs.masks(pieces)
    v, n = [], []
    for c, m in zip(coeffs.levels, masks):
        if not m.any():
            break
        v.append(np.mean(c.values[m] ** 2, axis=0))
        n.append(float(m.sum()))
    return np.array(v).reshape(len(v), -1), np.array(n)


def floor_stat(block, pieces: np.ndarray) -> np.ndarray:
    """The high-frequency floor per channel: the mean square of the fourth differences inside
    the given pieces, divided by 70 (its value for unit white noise, C(8, 4)).

    A fourth difference passes a signal of frequency f with the gain (2 sin(πf/fs))^8: a hand's
    tremor at 5 Hz sampled at 100 Hz reaches it 10^-6 times weaker than white noise does,
    where the finest Haar level (a first difference) lets 5 % of it through.

    Parameters
    ----------
    block : ResidualBlock
    pieces : (k,) int array
        Session-wide piece ids (pieces of 8 samples or fewer are skipped).

    Returns
    -------
    (c,) array
        [unit²] per channel; NaN without a usable piece.
    """
    keep = np.isin(block.piece, pieces)
    parts = [np.diff(block.values[a:b], n=4, axis=0)
             for a, b in zip(block.i0[keep], block.i1[keep]) if b - a > 8]
    d = np.concatenate(parts) if parts else np.zeros((0, block.values.shape[1]))
    return np.mean(d ** 2, axis=0) / 70.0 if len(d) else np.full(block.values.shape[1], np.nan)


@lru_cache(maxsize=512)
def floor_gain(fs: float, cutoff_hz: float | None) -> float:
    """floor_stat of unit white noise seen through the low-pass (1 without it).

    Parameters
    ----------
    fs : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Low-pass cut-off [Hz].

    Returns
    -------
    float
    """
    if cutoff_hz is None or cutoff_hz >= fs / 2:
        return 1.0
    w = _omega()
    g = _filter_power_gain(cutoff_hz, fs)
    return float(np.trapezoid((2 * np.sin(w / 2)) ** 8 * g, w) / np.pi / 70.0)


def _omega() -> np.ndarray:
    return np.linspace(1e-6, np.pi, N_FREQ)


def _filter_power_gain(cutoff_hz: float, fs: float) -> np.ndarray:
    """|H(ω)|² of the second-order Butterworth low-pass on the :func:`_omega` grid (scipy.signal
    imported here: only a model with a low-pass filter needs it, and its import costs 0.8 s)."""
    from scipy.signal import butter, freqz

    b, a = butter(2, cutoff_hz / (fs / 2))
    return np.abs(freqz(b, a, worN=_omega())[1]) ** 2


@lru_cache(maxsize=64)
def haar_gain(levels: int) -> np.ndarray:
    """|H_j(ω)|² = (2/m) sin⁴(mω/2) / sin²(ω/2) on the grid, (levels, N_FREQ) (cached: the
    grid is fixed; do not modify the returned array).

    Parameters
    ----------
    levels : int
        Number of levels (m = 1, 2, 4, ...).

    Returns
    -------
    (levels, N_FREQ) array
        On ω from 0 to π [rad/sample].
    """
    w = _omega()
    m = (2.0 ** np.arange(levels))[:, None]
    return (2.0 / m) * np.sin(m * w / 2) ** 4 / np.sin(w / 2) ** 2


@lru_cache(maxsize=512)
def lowpass_gain(levels: int, fs: float, cutoff_hz: float | None) -> np.ndarray:
    """L_j: Haar variance of unit white noise after the Butterworth low-pass, per level.

    Parameters
    ----------
    levels : int
    fs : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Low-pass cut-off [Hz] (None, or at or above fs/2: no filter).

    Returns
    -------
    (levels,) array
    """
    h = haar_gain(levels)
    if cutoff_hz is None or cutoff_hz >= fs / 2:
        g = np.ones(N_FREQ)
    else:
        g = _filter_power_gain(cutoff_hz, fs)
    return np.trapezoid(h * g, _omega(), axis=1) / np.pi


def random_walk_gain(levels: int, fs: float) -> np.ndarray:
    """Haar variance per unit q² of a discrete random walk, Δt·(2m² + 1)/6.

    Parameters
    ----------
    levels : int
    fs : float
        Sample rate [Hz].

    Returns
    -------
    (levels,) array
        [s].
    """
    m = 2.0 ** np.arange(levels)
    return (2 * m ** 2 + 1) / 6.0 / fs


def ml_variances(v: np.ndarray, n: np.ndarray, design: np.ndarray, fixed: np.ndarray,
                 iterations: int = 60) -> tuple[np.ndarray, float]:
    """Coefficients c ≥ 0 minimising Σ n (v / M + ln M), M = fixed + design·c (rows: levels of
    possibly several channels, or other variance statistics). Returns (c, objective).

    Fisher scoring: each step is the non-negative least-squares fit of v by M with weights
    n / M² from the previous step (the inverse variance of a mean square of n Gaussian
    terms), which converges to the maximum-likelihood point; bounded first-order optimisers
    stall here because the columns' scales differ by orders of magnitude.

    Parameters
    ----------
    v : (r,) array
        Variance statistics (mean squares).
    n : (r,) array
        Number of terms behind each.
    design : (r, k) array
        Model variance per unit coefficient.
    fixed : (r,) array
        Model variance that does not depend on c (e.g. rounding), in the unit of ``v``.
    iterations : int
        Most scoring steps.

    Returns
    -------
    c : (k,) array
        Coefficients, ≥ 0.
    objective : float
        Σ n (v / M + ln M) at c.
    """
    scale = np.maximum(design.max(axis=0), 1e-300)
    d = design / scale
    floor = 1e-12 * max(float(np.max(v)), 1e-300)
    # M ≥ fixed whatever c is: starting the weights below it (a squared difference of two
    # piece means that happens to be near zero) gave one row a weight so large that the
    # first NNLS step returned c = 0, a white noise of zero beside the rounding
    m = np.maximum(v, np.maximum(fixed, floor))
    c = np.zeros(d.shape[1])
    for _ in range(iterations):
        w = np.sqrt(n) / m
        c_new, _ = nnls(d * w[:, None], (v - fixed) * w)
        m = np.maximum(fixed + d @ c_new, floor)
        # np.allclose(c_new, c, rtol=1e-9, atol=1e-300) for finite c, without its checks
        # and broadcasting: a sixth of the diagnosis's time went into them
        if np.all(np.abs(c_new - c) <= 1e-300 + 1e-9 * np.abs(c)):
            c = c_new
            break
        c = c_new
    return c / scale, float(np.sum(n * (v / m + np.log(m))))


@dataclass
class MeanPairs:
    """Differences of consecutive piece means: what a random walk does between pieces.

    For a random walk of rate q [unit/√s] and white noise σ per sample, the difference of the
    means of two pieces (n_a, n_b samples lasting L_a, L_b [s], G [s] apart) has the variance
    σ²(1/n_a + 1/n_b) + q²(L_a/3 + L_b/3 + G) (the mean of a Wiener process over an interval
    sits a third of the interval from its end; the Allan variance's q²τ/3 is the case
    L_a = L_b = τ, G = 0).

    Attributes
    ----------
    squares : (P, 3) array
        Squared differences of consecutive piece means per axis [unit²].
    white : (P,) array
        1/n_a + 1/n_b.
    walk : (P,) array
        L_a/3 + L_b/3 + G [s].
    """

    squares: np.ndarray     # (P, 3) squared differences per axis
    white: np.ndarray       # (P,) 1/n_a + 1/n_b
    walk: np.ndarray        # (P,) L_a/3 + L_b/3 + G [s]

    @classmethod
    def of(cls, block, pieces: np.ndarray) -> "MeanPairs | None":
        """The pairs of consecutive pieces (in time) of ``block`` among the piece ids
        ``pieces``; None with fewer than three pieces."""
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
                 floor: np.ndarray, step: np.ndarray | None = None, random_walk: bool = False,
                 pairs: MeanPairs | None = None
                 ) -> tuple[np.ndarray, np.ndarray | None, float]:
    """One sensor's three channels: per-axis σ, per-axis q (or None) and the objective.

    With white noise alone (no random walk) the white level is anchored at the spectrum's
    high-frequency ``floor`` (:func:`floor_stat`), through the low-pass's gain there when one
    is modelled: σ² = (floor − Δ²/12) / gain. Slower power that is not modelled then shows as
    a gap where it lies instead of inflating the white level (and with it a gap at the
    finest scale), and a low-pass can only stand for the one spectral shape a filter gives,
    not for any slow excess. The objective is over all levels.

    Parameters
    ----------
    v : (levels, 3) array
        Mean square per level and axis [unit²] (:func:`level_stats`).
    n : (levels,) array
        Coefficients per level.
    fs : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Low-pass cut-off [Hz].
    floor : (3,) array
        :func:`floor_stat` [unit²].
    step : (3,) array, optional
        Quantization step [unit].
    random_walk : bool
        Fit a bias random walk q as well.
    pairs : MeanPairs, optional
        Piece-mean differences that also see the random walk.

    Returns
    -------
    sigma : (3,) array
        White noise per sample [unit].
    q : (3,) array or None
        Random walk [unit/√s] (None without ``random_walk``).
    objective : float
    """
    levels, axes = v.shape
    lp = lowpass_gain(levels, fs, cutoff_hz)
    quant = np.zeros(axes) if step is None else np.asarray(step) ** 2 / 12.0
    if not random_walk:                         # white only: anchored at the floor
        s2 = np.maximum(np.asarray(floor) - quant, 1e-300) / floor_gain(fs, cutoff_hz)
        m = np.maximum(np.outer(lp, s2) + quant, 1e-300)
        return np.sqrt(s2), None, float(np.sum(n[:, None] * (v / m + np.log(m))))
    rows_v, rows_n = [v], [n]
    white, walk = [lp], [random_walk_gain(levels, fs)]
    fixed = [np.ones(levels)]
    if pairs is not None:
        rows_v.append(pairs.squares)
        rows_n.append(np.ones(len(pairs.white)))
        white.append(pairs.white)
        walk.append(pairs.walk)
        fixed.append(pairs.white)       # a pair's rounding noise: Δ²/12 per mean, like σ²
    v_all, n_all = np.vstack(rows_v), np.concatenate(rows_n)
    white, walk, fixed = np.concatenate(white), np.concatenate(walk), np.concatenate(fixed)
    design = np.hstack([np.kron(np.eye(axes), white[:, None]),     # σ² per axis
                        np.kron(np.eye(axes), walk[:, None])])     # q² per axis
    coef, obj = ml_variances(v_all.T.ravel(), np.tile(n_all, axes), design,
                             np.kron(quant, fixed))
    return np.sqrt(coef[:axes]), np.sqrt(coef[axes:]), obj


def lattice_step(x: np.ndarray, min_fraction: float = 0.9) -> float | None:
    """The quantization step of samples on a lattice (their smallest non-zero successive
    difference, when ``min_fraction`` of the differences are multiples of it and their median
    is at most 50 steps), else None.

    Parameters
    ----------
    x : (n,) array
        Samples.
    min_fraction : float
        Share of the differences that must lie on the lattice.

    Returns
    -------
    float or None
        Step, in the unit of ``x``.
    """
    x = np.asarray(x, float)
    d = np.abs(np.diff(x))
    # differences at the float's own resolution are equal samples (means of rounded readings
    # carry a last-bit error), not a lattice step
    d = d[d > 1e-9 * max(float(np.max(np.abs(x))), 1e-300)]
    if len(d) < 100:
        return None
    step = float(np.min(d))
    rel = d / step
    on_lattice = np.abs(rel - np.round(rel)) < 1e-3 * np.maximum(rel, 1)
    if on_lattice.mean() < min_fraction or np.median(rel) > 50:
        return None
    return step
