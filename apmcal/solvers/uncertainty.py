"""Uncertainty helpers shared by the solvers: covariance from a Jacobian, bootstrap.

Both return one-sigma figures in the units of the estimated parameters.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from apmcal.solvers.result import SensorCalibration


def covariance_from_jacobian(J: np.ndarray, residuals: np.ndarray, n_params: int | None = None,
                             *, weights: np.ndarray | None = None, rcond: float = 1e-10
                             ) -> tuple[np.ndarray, int]:
    """Least-squares parameter covariance σ²·(JᵀWJ)⁻¹ at the solution.

    σ² is estimated from the residuals with the degrees-of-freedom correction
    ``Σ w·r² / (Σ w − p)`` (for unit weights: ``Σ r² / (n − p)``). A pseudo-inverse is used so
    that a rank-deficient problem still returns a matrix; the rank tells whether to trust it.

    Parameters
    ----------
    J : (n, p) array
        Jacobian of the residuals with respect to the parameters, at the solution.
    residuals : (n,) array
        Residuals at the solution (same units as the measurements).
    n_params : int, optional
        Number of free parameters for the dof correction (default ``p``).
    weights : (n,) array, optional
        IRLS weights of a robust loss (e.g. Huber ``min(1, k/|r|)``), 1 by default.
    rcond : float
        Relative singular-value cut-off of the pseudo-inverse.

    Returns
    -------
    cov : (p, p) array
        Covariance of the parameters; rows/columns of non-determinable directions are not
        meaningful when ``rank < p``.
    rank : int
        Numerical rank of ``J`` (after weighting).
    """
    J = np.asarray(J, dtype=float)
    r = np.asarray(residuals, dtype=float).ravel()
    n, p = J.shape
    k = p if n_params is None else int(n_params)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float).ravel()
    dof = w.sum() - k
    if dof <= 0:
        return np.full((p, p), np.nan), int(np.linalg.matrix_rank(J))
    sigma2 = float(np.sum(w * r * r) / dof)
    Jw = J * np.sqrt(w)[:, None]
    s = np.linalg.svd(Jw, compute_uv=False)
    rank = int(np.sum(s > rcond * s[0])) if s.size and s[0] > 0 else 0
    cov = sigma2 * np.linalg.pinv(Jw.T @ Jw, rcond=rcond ** 2, hermitian=True)
    return cov, rank


def covariance_from_normal_equations(A: np.ndarray, weighted_rss: float, dof: float, *,
                                     rcond: float = 1e-10) -> tuple[np.ndarray, int]:
    """:func:`covariance_from_jacobian` from the normal matrix instead of the Jacobian.

    For fits that never form an n×p Jacobian: ``σ²·A⁺`` with ``A = JᵀWJ`` (p, p) and
    ``σ² = Σ w·r² / dof``; the same pseudo-inverse as there. The rank counts the singular
    values √λ of √W·J above ``rcond`` × the largest, from the eigenvalues λ of A, so a
    direction weaker than ~1e-8 of the strongest (below A's float64 resolution) still counts.

    Parameters
    ----------
    A : (p, p) array
        JᵀWJ at the solution [1 / parameter units²].
    weighted_rss : float
        Σ w·r² [residual units²].
    dof : float
        Σ w − number of parameters.
    rcond : float
        Relative singular-value cut-off, as in :func:`covariance_from_jacobian`.

    Returns
    -------
    cov : (p, p) array
    rank : int
    """
    A = 0.5 * (A + A.T)
    p = A.shape[0]
    lam = np.clip(np.linalg.eigvalsh(A), 0.0, None)
    s = np.sqrt(lam[::-1])
    rank = int(np.sum(s > rcond * s[0])) if p and s[0] > 0 else 0
    if dof <= 0:
        return np.full((p, p), np.nan), rank
    sigma2 = weighted_rss / dof
    return sigma2 * np.linalg.pinv(A, rcond=rcond ** 2, hermitian=True), rank


def _as_vector(est) -> np.ndarray:
    """A fit result as one flat vector: SensorCalibration → offset (3) + matrix (9, row-major)."""
    if isinstance(est, SensorCalibration):
        return np.concatenate([est.offset, est.matrix.ravel()])
    return np.asarray(est, dtype=float).ravel()


def bootstrap(fit_fn: Callable[[np.ndarray], object], samples: np.ndarray, n: int = 200,
              rng: np.random.Generator | int | None = None) -> dict:
    """Non-parametric bootstrap: refit on ``n`` resamples (with replacement) of the rows.

    Parameters
    ----------
    fit_fn : callable
        ``fit_fn(samples) -> SensorCalibration or array``; must accept the resampled rows.
    samples : (m, ...) array
        The data; rows are resampled.
    n : int
        Number of bootstrap replicates.
    rng : Generator or seed, optional

    Returns
    -------
    dict
        ``estimates`` (n, p), ``mean`` (p,), ``std`` (p,) one-sigma; when ``fit_fn`` returns a
        SensorCalibration also ``sigma`` = {"offset": (3,), "matrix": (3, 3)}. Replicates whose fit
        raised an exception are dropped and counted in ``failed``.
    """
    rng = np.random.default_rng(rng)
    samples = np.asarray(samples)
    m = len(samples)
    est, failed, is_cal = [], 0, False
    for _ in range(n):
        idx = rng.integers(0, m, m)
        try:
            out = fit_fn(samples[idx])
        except Exception:  # noqa: BLE001 — a failed replicate is data about stability
            failed += 1
            continue
        is_cal = isinstance(out, SensorCalibration)
        est.append(_as_vector(out))
    est = np.array(est)
    res = {"estimates": est, "failed": failed,
           "mean": est.mean(axis=0) if len(est) else np.array([]),
           "std": est.std(axis=0, ddof=1) if len(est) > 1 else np.array([])}
    if is_cal and len(est) > 1:
        res["sigma"] = {"offset": res["std"][:3], "matrix": res["std"][3:12].reshape(3, 3)}
    return res


def jacobian_sigma(fun, x: np.ndarray, sx: np.ndarray, rel_step: float = 1e-6) -> np.ndarray:
    """First-order propagation of independent input sigmas ``sx`` through ``fun`` (central differences).

    Parameters
    ----------
    fun : callable
        (k,) array → array of any shape (m values).
    x : (k,) array
        The inputs (flattened).
    sx : (k,) array
        Their one-sigma, in their units.
    rel_step : float
        Difference step relative to max(|x_i|, 1).

    Returns
    -------
    (m,) array
        One-sigma of each output, in its units.
    """
    x = np.asarray(x, dtype=float).ravel()
    y0 = np.asarray(fun(x)).ravel()
    var = np.zeros_like(y0)
    for i in range(x.size):
        h = rel_step * max(abs(x[i]), 1.0)
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        d = (np.asarray(fun(xp)).ravel() - np.asarray(fun(xm)).ravel()) / (2 * h)
        var += (d * sx.ravel()[i]) ** 2
    return np.sqrt(var)
