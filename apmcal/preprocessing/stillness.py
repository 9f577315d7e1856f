"""Which samples are still: moving standard deviation against a threshold set by the noise.

The building blocks of :func:`apmcal.preprocessing.static.find_static_segments`: a moving std
that never reaches across a logging hole, Otsu's split between "still" and "moving" windows
bounded by the noise floor, a two-level hysteresis, and a constant-rate test for steady turns.
"""
from __future__ import annotations

import numpy as np

NOISE_FACTOR = 3.0      # "enter still" threshold ≥ NOISE_FACTOR × robust static noise floor
MAX_NOISE_FACTOR = 10.0  # ... and ≤ MAX_NOISE_FACTOR × floor (see noise_threshold)
NOISE_QUANTILE = 5.0    # percentile of the moving std taken as the noise floor
GAP_FACTOR = 5.0        # a time step > GAP_FACTOR × median interval is a logging gap


def uniform_filter1d(x: np.ndarray, w: int, axis: int = 0, mode: str = "reflect") -> np.ndarray:
    """Centred moving mean of (n, k) ``x`` over ``w`` samples along axis 0, as
    ``scipy.ndimage.uniform_filter1d`` (window ``[i − w//2, i − w//2 + w − 1]``; ``mode``
    "reflect": mirrored ends d c b a | a b c d, "nearest": repeated end values).

    Why not scipy's: it imports ``scipy.ndimage`` (~0.3 s, and with it scipy's array-API layer),
    a tenth of an ``apmcal log`` run, for a cumulative sum. Same values to ~1e-13 relative.

    Parameters
    ----------
    x : numpy.ndarray, shape (n, k)
        Samples, any unit.
    w : int
        Window length [samples].
    axis : int, optional
        Must be 0.
    mode : str, optional
        "reflect" or "nearest".

    Returns
    -------
    numpy.ndarray, shape (n, k)
        Moving mean, in the unit of ``x``.
    """
    assert axis == 0
    left = w // 2
    pad = {"reflect": "symmetric", "nearest": "edge"}[mode]
    xp = np.pad(np.asarray(x, dtype=float), ((left, w - 1 - left), (0, 0)), mode=pad)
    c = np.zeros((xp.shape[0] + 1, xp.shape[1]))
    np.cumsum(xp, axis=0, out=c[1:])
    return (c[w:] - c[:-w]) / w


def moving_std(x: np.ndarray, w: int, blocks: list[tuple[int, int]] | None = None) -> np.ndarray:
    """Centred moving standard deviation of (n, 3) ``x`` over ``w`` samples, root-sum-square over axes.

    Summing per-axis variances (rather than taking the std of the norm) also catches slow
    rotations, during which the accelerometer norm stays at g but its components change.
    The window never reaches across a logging gap: each of ``blocks`` (half-open index ranges,
    default the whole record) is filtered on its own, mirrored at its ends. Blocks shorter than
    3 samples get ``inf`` (never still).

    Parameters
    ----------
    x : numpy.ndarray, shape (n, 3)
        Samples, any unit (e.g. m/s², rad/s).
    w : int
        Window length [samples].
    blocks : list of (int, int), optional
        Gap-free half-open index ranges (:func:`gap_free_blocks`).

    Returns
    -------
    numpy.ndarray, shape (n,)
        Moving std, in the unit of ``x``.
    """
    x = np.asarray(x, dtype=float)
    out = np.full(x.shape[0], np.inf)
    for b0, b1 in blocks or [(0, x.shape[0])]:
        if b1 - b0 < 3:
            continue
        xb = x[b0:b1] - np.median(x[b0:b1], axis=0)     # centre first: E[x²] − E[x]² cancels less
        wb = min(w, b1 - b0)
        m = uniform_filter1d(xb, wb, axis=0, mode="reflect")
        m2 = uniform_filter1d(xb * xb, wb, axis=0, mode="reflect")
        out[b0:b1] = np.sqrt(np.maximum(m2 - m * m, 0.0).sum(axis=1) * wb / max(wb - 1, 1))
    return out


def otsu_log(s: np.ndarray, bins: int = 128) -> float:
    """Otsu's split of ``log(s)``: the level that best separates "still" from "moving" windows.

    Otsu (1979): maximise the between-class variance w0·w1·(μ0 − μ1)² over the histogram.
    On a log axis the still mode (noise) and the motion mode (10-1000 × noise) are well apart.

    Parameters
    ----------
    s : numpy.ndarray, shape (n,)
        Moving std (non-positive and non-finite values are ignored).
    bins : int, optional
        Histogram bins.

    Returns
    -------
    float
        The split level, in the unit of ``s``.
    """
    ls = np.log(s[(s > 0) & np.isfinite(s)])
    if ls.size < 2 or np.ptp(ls) == 0:
        return float(np.exp(ls[0])) if ls.size else 0.0
    h, e = np.histogram(ls, bins)
    c = 0.5 * (e[:-1] + e[1:])
    w0 = np.cumsum(h) / h.sum()
    m0 = np.cumsum(h * c) / h.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (m0[-1] * w0 - m0) ** 2 / (w0 * (1.0 - w0))
    return float(np.exp(c[np.nanargmax(between)]))


def noise_threshold(s: np.ndarray, x: np.ndarray, factor: float = NOISE_FACTOR,
                    max_factor: float = MAX_NOISE_FACTOR) -> float:
    """Noise-adapted "enter still" threshold for the moving std ``s`` of signal ``x``.

    The noise floor is a low percentile of the moving std (robust to the motion that fills the
    rest of the recording). The threshold is Otsu's split of log(s) between still and moving
    windows, kept within [``factor``, ``max_factor``] × floor: hand-held holds are 1.5-10 ×
    noisier than a bench rest (mpu6050 example: gyro std 6-10 × its bench floor), while a
    record with no motion at all has no second mode and gets ``factor`` × floor. A floor of
    1.5 quantisation steps keeps integer telemetry (RAW_IMU, 1 mG steps, ardupilot-facts.md)
    from giving a zero threshold.

    Parameters
    ----------
    s : numpy.ndarray, shape (n,)
        Moving std of ``x`` (:func:`moving_std`).
    x : numpy.ndarray, shape (n, 3)
        The signal, any unit.
    factor, max_factor : float, optional
        Bounds on the threshold, in multiples of the noise floor.

    Returns
    -------
    float
        Threshold (> 0), in the unit of ``x``.
    """
    finite = s[np.isfinite(s)]
    floor = float(np.percentile(finite, NOISE_QUANTILE)) if finite.size else 0.0
    thr = float(np.clip(otsu_log(finite), factor * floor, max_factor * floor)) if finite.size else 0.0
    steps = np.abs(np.diff(x, axis=0))
    steps = steps[steps > 0]
    quantum = float(steps.min()) if steps.size else 0.0
    return max(thr, 1.5 * quantum, np.finfo(float).tiny)


def hysteresis_mask(s: np.ndarray, enter: float, leave: float) -> np.ndarray:
    """Two-level test: runs of ``s < leave`` that dip below ``enter``, trimmed to their first and
    last sample below ``enter``.

    The higher ``leave`` level only bridges short noisy stretches inside a hold; the edges stay
    where the stricter ``enter`` level puts them, so a hold does not creep into the slow start
    or end of the next motion.

    Parameters
    ----------
    s : numpy.ndarray, shape (n,)
        Moving std.
    enter, leave : float
        The two levels (``enter`` ≤ ``leave``), in the unit of ``s``.

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
    """
    low = s < leave
    run = np.cumsum(low & ~np.concatenate([[False], low[:-1]]))   # run number of each sample
    core = np.flatnonzero((s < enter) & low)
    if core.size == 0:
        return np.zeros(s.shape, bool)
    r = run[core]                              # non-decreasing: runs in order
    change = r[1:] != r[:-1]
    first = core[np.concatenate([[True], change])]     # first core sample of each run
    last = core[np.concatenate([change, [True]])]      # ... and its last
    edges = np.zeros(s.size + 1, np.int32)
    np.add.at(edges, first, 1)
    np.add.at(edges, last + 1, -1)
    return np.cumsum(edges[:-1]) > 0


# the gyro bias a turn is measured against is the median of the still samples within this many
# moving-std windows around each sample (2 minutes at the default 0.5 s window): long beside a
# turn, short beside a warming board's bias drift, which moves most in its first minutes
BIAS_WINDOWS = 240


def slow_mask(gyr: np.ndarray, w: int, still: np.ndarray, max_rate: float,
              blocks: list[tuple[int, int]]) -> np.ndarray:
    """Samples whose moving-mean rate stays within ``max_rate`` of the bias.

    A turn at constant rate (a turntable, or a steady hand) has a small moving std; only its
    mean betrays it. The bias is the median rate of the samples the std test kept, which are
    mostly true holds, taken near each sample (:func:`local_bias`): a warming board's gyro
    bias drifts by more than a slow turn's rate (ArduPilot's SITL with an injected temperature
    drift: 0.4 °/s over its warm-up), and against one median for the whole record the cold
    start of a warm-up read as a turn.

    Parameters
    ----------
    gyr : numpy.ndarray, shape (n, 3)
        Gyroscope, any unit.
    w : int
        Window length [samples].
    still : numpy.ndarray of bool, shape (n,)
        Samples the std test kept.
    max_rate : float
        Largest |moving-mean rate − bias|, in the unit of ``gyr``.
    blocks : list of (int, int)
        Gap-free half-open index ranges.

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
    """
    if not np.any(still):
        return still
    bias = local_bias(gyr, still, w, BIAS_WINDOWS)
    mean = np.empty_like(gyr)
    for b0, b1 in blocks:                   # as moving_std: no window across a logging hole
        mean[b0:b1] = uniform_filter1d(gyr[b0:b1] - bias[b0:b1], min(w, b1 - b0), axis=0,
                                       mode="nearest")
    return np.linalg.norm(mean, axis=1) < max_rate


def local_bias(gyr: np.ndarray, still: np.ndarray, w: int, windows: int) -> np.ndarray:
    """The median rate of the ``still`` samples within ``windows`` chunks of ``w`` samples
    around each sample, per axis (n, 3).

    Median of chunk medians, for speed on long logs: each chunk of ``w`` samples gives the
    median of its still samples (none: no vote), and each sample takes the median of the votes
    of the ``windows`` chunks centred on its own; where none voted, the nearest chunk that did.
    """
    n = len(gyr)
    starts = np.arange(0, n, w)
    votes = np.full((len(starts), 3), np.nan)
    for k, i0 in enumerate(starts):
        kept = gyr[i0:i0 + w][still[i0:i0 + w]]
        if len(kept):
            votes[k] = np.median(kept, axis=0)
    voted = np.flatnonzero(~np.isnan(votes[:, 0]))
    half = windows // 2
    chunk_bias = np.empty_like(votes)
    for k in range(len(starts)):
        lo, hi = np.searchsorted(voted, [k - half, k + half + 1])
        near = voted[lo:hi] if hi > lo else voted[[np.argmin(np.abs(voted - k))]]
        chunk_bias[k] = np.median(votes[near], axis=0)
    return np.repeat(chunk_bias, w, axis=0)[:n]


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open index ranges of the True runs of a boolean array."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def gap_free_blocks(t: np.ndarray, dt: float) -> list[tuple[int, int]]:
    """Half-open ranges of samples without a logging gap (> GAP_FACTOR × the median interval).

    Dataflash logs stop writing IMU while disarmed (pxf_copter_mag.BIN: 13 gaps of 5-363 s);
    a window or a segment must not reach across such a hole.

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    dt : float
        Median sample interval [s].

    Returns
    -------
    list of (int, int)
    """
    cut = np.flatnonzero(np.diff(t) > GAP_FACTOR * dt) + 1
    b = np.concatenate(([0], cut, [t.size]))
    return list(zip(b[:-1].tolist(), b[1:].tolist()))
