"""ArduPilot's temperature polynomial fitted by weighted least squares, with uncertainties.

Model (ArduPilot AP_InertialSensor_tempcal.cpp ``polynomial_eval``: a 3rd-order
polynomial without constant term in d = T − 35 °C, coefficients stored × 1e6; its learner fits
the same cubic plus a constant, ``Learn::add_sample`` / ``save_calibration``), per axis::

    y_i = a_g(i) + (c1·d_i + c2·d_i² + c3·d_i³)·1e-6 + e_i,     d_i = T_i − 35 [K]

y_i: the mean raw sensor-frame sample of block i [m/s² or rad/s] (the firmware corrects the raw
sample by P(T) − P(T_cal), so the raw drift is what P must describe); a_g: one free constant per
orientation group (gravity, bias); weights w_i = samples in the block. The σ of each coefficient
is the least-squares covariance (XᵀWX)⁻¹ scaled by the weighted residual variance (the noise is
read from the data), times a batch-means factor ≥ 1 when the residuals are correlated over many
blocks (quantization steps swept by the drift; :func:`_batch_means_factor`), plus the
covariance of a random walk whose intensity the short-lag residual differences show
(:func:`random_walk_q2`): during a warm-up the temperature rises monotonically in time, so a
gyro random walk is confounded with the polynomial and invisible in the residual scatter.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.core.errors import ApmcalError

TEMP_REFERENCE_C = 35.0     # AP_InertialSensor_tempcal.cpp TEMP_REFERENCE
SCALE_FACTOR = 1.0e6        # ... SCALE_FACTOR (parameters hold the coefficients × 1e6)
MAX_INFLATION = 100.0       # cap of the batch-means variance factor
MIN_DOF = 4                 # blocks beyond the parameters needed to read the noise
MIN_BATCHES = 10            # the longest batches: a tenth of the blocks
WALK_SHOWS = 0.3            # a random walk counts when it adds ≥ this × the white part


@dataclass
class TcalFit:
    """One sensor's fitted polynomial (3 axes).

    Attributes
    ----------
    coeffs : (3, 3) array
        Row k−1 = c_k for X, Y, Z in ArduPilot's parameter units: 1e-6 m/s²/K^k (accelerometer)
        or 1e-6 rad/s/K^k (gyro).
    sigma : (3, 3) array
        One-sigma uncertainty of ``coeffs``, same units.
    residual_rms : (3,) array
        Weighted RMS of the block residuals [m/s² or rad/s].
    inflation : (3,) array
        The correlation factor applied to each axis's variance (1: none).
    n_blocks, n_samples : int
        Blocks and samples fitted.
    random_walk : (3,) array
        Random-walk intensity q read from the residuals [unit/√s] (0: none seen), whose
        covariance is included in ``sigma``.
    """

    coeffs: np.ndarray
    sigma: np.ndarray
    residual_rms: np.ndarray
    inflation: np.ndarray
    n_blocks: int
    n_samples: int
    random_walk: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def to_dict(self) -> dict:
        """The fit as plain JSON values (coefficients in ArduPilot's parameter units)."""
        return {"c1_c2_c3_xyz": self.coeffs.tolist(), "sigma": self.sigma.tolist(),
                "residual_rms": self.residual_rms.tolist(),
                "sigma_inflation": self.inflation.tolist(),
                "random_walk_per_sqrt_s": self.random_walk.tolist(), "blocks": self.n_blocks,
                "samples": self.n_samples}


def fit_tcal(temp_c: np.ndarray, values: np.ndarray, weights: np.ndarray,
             group: np.ndarray | None = None, t_s: np.ndarray | None = None) -> TcalFit:
    """Weighted least-squares fit of ArduPilot's cubic (see the module docstring).

    Parameters
    ----------
    temp_c : (m,) array
        Temperature of each block [°C].
    values : (m, 3) array
        Mean raw sensor-frame sample of each block [m/s² or rad/s], in time order.
    weights : (m,) array
        Samples per block (or any weight ∝ 1/variance).
    group : (m,) int array, optional
        Orientation group of each block (one free constant each); default all 0.
    t_s : (m,) array, optional
        Time of each block [s]: with it, a random walk read from the residuals is added to the
        covariance (:func:`random_walk_q2`).

    Returns
    -------
    TcalFit
        Coefficients c1..c3 (3, 3) and their σ in ArduPilot's parameter units.

    Raises
    ------
    ApmcalError
        Too few blocks to fit the polynomial and read the noise.
    """
    temp_c = np.asarray(temp_c, dtype=float)
    y = np.asarray(values, dtype=float)
    w = np.asarray(weights, dtype=float)
    group = np.zeros(len(temp_c), int) if group is None else np.asarray(group, int)
    labels, g = np.unique(group, return_inverse=True)
    d = temp_c - TEMP_REFERENCE_C
    x = np.column_stack([(g == k).astype(float) for k in range(len(labels))]
                        + [d, d ** 2, d ** 3])
    m, p = x.shape
    if m < p + MIN_DOF:
        raise ApmcalError(f"only {m} still blocks to fit {p} parameters: record a longer "
                          f"still warm-up")
    scale = np.sqrt(np.mean(x ** 2, axis=0))          # columns of comparable size
    scale[scale == 0] = 1.0
    sw = np.sqrt(w)[:, None]
    xs = x / scale * sw
    beta, _, rank, _ = np.linalg.lstsq(xs, y * sw, rcond=None)
    if rank < p:
        raise ApmcalError("the temperatures do not determine a cubic (too few distinct "
                          "temperatures in the still data)")
    beta = beta / scale[:, None]
    resid = y - x @ beta
    wr = resid * sw
    s2 = np.sum(wr ** 2, axis=0) / (m - p)
    q, _ = np.linalg.qr(xs)
    inflation = _batch_means_factor(wr, q, s2)
    xtwx_inv = np.linalg.inv((x * w[:, None]).T @ x)
    var = np.outer(np.diag(xtwx_inv)[-3:], s2 * inflation)
    q2 = np.zeros(3)
    if t_s is not None:
        t_s = np.asarray(t_s, dtype=float)
        q2 = np.array([random_walk_q2(t_s, resid[:, j]) for j in range(3)])
        if np.any(q2 > 0):
            # a random walk of variance q²·t: cov = A Σ Aᵀ, A = (XᵀWX)⁻¹XᵀW, Σ_ij = q²·min(t)
            a = (xtwx_inv @ (x * w[:, None]).T)[-3:]
            t0 = t_s - t_s.min()
            walk = a @ np.minimum.outer(t0, t0) @ a.T
            var = var + np.outer(np.diag(walk), q2)
    return TcalFit(coeffs=beta[-3:] * SCALE_FACTOR, sigma=np.sqrt(var) * SCALE_FACTOR,
                   residual_rms=np.sqrt(np.sum(w[:, None] * resid ** 2, axis=0) / w.sum()),
                   inflation=inflation, n_blocks=m, n_samples=int(w.sum()),
                   random_walk=np.sqrt(q2))


def random_walk_q2(t_s: np.ndarray, r: np.ndarray, max_lag: int | None = None) -> float:
    """Random-walk intensity q² [unit²/s] read from the residuals ``r`` of the blocks at times
    ``t_s``; 0 when none shows.

    For a random walk, the mean squared difference of residuals k blocks apart grows as
    V(k) = 2σ_b² + q²·Δt(k), white noise alone keeps it flat: q² is the slope of V against
    the mean Δt, over k = 1 .. ``max_lag`` (default a tenth of the blocks: short enough
    that the polynomial has not absorbed the walk yet). It counts only when the walk adds at least
    0.3 × the white part at the longest lag (WALK_SHOWS): V(k) of white noise scatters by
    about 10 %, so noise alone seldom passes. A walk confounds with the drift whenever the
    temperature rises monotonically in time; the residual scatter alone cannot see it.

    Parameters
    ----------
    t_s : (m,) array
        Time of each block [s], increasing.
    r : (m,) array
        Residuals of one axis [unit].
    max_lag : int, optional
        Longest lag in blocks.

    Returns
    -------
    float
        q² [unit²/s], ≥ 0.
    """
    m = len(r)
    lags = [k for k in range(1, max(3, (max_lag or m // 10)) + 1) if k < m - 1]
    if len(lags) < 3:
        return 0.0
    dt = np.array([np.mean(t_s[k:] - t_s[:-k]) for k in lags])
    v = np.array([np.mean((r[k:] - r[:-k]) ** 2) for k in lags])
    slope, white = np.polyfit(dt, v, 1)
    if slope <= 0 or slope * dt[-1] < WALK_SHOWS * max(white, v[0]):
        return 0.0
    return float(slope)


def _batch_means_factor(wr: np.ndarray, q: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """Variance factor (≥ 1, capped) for residuals correlated over many blocks, per column.

    Batch means (e.g. Flegal & Jones 2010): the weighted residuals ``wr`` (m, 3), in time
    order, are summed over batches of L consecutive blocks (L = √m, and L = m/10 for the
    slowest noise; the larger factor is kept); for independent noise of
    variance s² the sum of the squared batch sums has expectation s²·tr(Bᵀ(I − H)B), B the
    batch-summing matrix, H = QQᵀ the hat matrix of the weighted design (``q``: its orthonormal
    basis). The ratio of the observed sum to that expectation measures how much slow noise
    (a gyro random walk, quantization steps swept by the drift) the block-to-block scatter
    hides.
    """
    m = wr.shape[0]
    factor = np.ones(wr.shape[1])
    for size in sorted({max(2, int(round(np.sqrt(m)))), max(2, m // MIN_BATCHES)}):
        batch = np.arange(m) // size
        nb = int(batch[-1]) + 1
        if nb < MIN_BATCHES // 2:
            continue
        sums = np.zeros((nb, wr.shape[1]))
        np.add.at(sums, batch, wr)
        qb = np.zeros((nb, q.shape[1]))
        np.add.at(qb, batch, q)
        expected = m - float(np.sum(qb ** 2))        # tr(BᵀB) − ‖BᵀQ‖²_F
        if expected <= 0:
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.sum(sums ** 2, axis=0) / (expected * s2)
        factor = np.maximum(factor, np.nan_to_num(ratio, nan=1.0))
    return np.clip(factor, 1.0, MAX_INFLATION)
