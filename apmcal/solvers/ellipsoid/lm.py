"""Bounded Levenberg-Marquardt for the geometric ellipsoid residual, on p×p normal equations.

Why hand-written: ``scipy.optimize.least_squares(method="trf")`` factorises the whole n×p
Jacobian at every iteration (an SVD, plus several n×p copies for scaling and the loss). The
geometric residual ``|M(s − o)| − r`` has only p ≤ 9 parameters, so a Gauss-Newton step needs
only JᵀWJ (p×p) and JᵀWr (p,), formed in one BLAS product over the samples, and a p×p solve:
on 250 000 magnetometer samples a step costs ~10 ms instead of ~1 s.

What is minimised is exactly what ``least_squares`` minimised: ½ Σ ρ(fᵢ²) over the weighted
data residuals and the prior rows, with scipy's loss ρ scaled by ``f_scale``
(``ρ(z) = C²·ρ₀(z/C²)``). Each step uses that cost's exact gradient Σ ρ'(fᵢ²)·fᵢ·∇fᵢ and a
Gauss-Newton normal matrix Σ cᵢ·∇fᵢ∇fᵢᵀ weighted by the loss's curvature (Huber: 1 inside
f_scale, 0 beyond; :func:`curvature_weights`), so it stops where least_squares stops (zero
gradient), in a few steps; Marquardt's damping (diagonal scaling, Moré 1978) keeps each
accepted step a descent step, and bounds are handled by projection with an active set
(variables held at a bound while the gradient pushes them out of the box, Bertsekas 1982).
Iterations stop when a step moves the estimate by less than 1e-2 of its standard deviation
(the variance that leaves is 1e-4 of the estimate's own).

Layout: samples are passed transposed, ``sT`` (3, n) C-contiguous, and Jacobians are (p, n),
so that every per-sample operation runs on contiguous rows.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.solvers.ellipsoid.paper import params_to_matrix

XTOL = 1e-10        # relative step below which the iteration stops
SD_TOL = 1e-2       # ... or a step below this many standard deviations of the parameters
FTOL = 1e-13        # relative cost decrease below which it stops
MAX_ITER = 200
MU_START = 1e-4     # Marquardt damping, relative to diag(JᵀWJ)
MU_MAX = 1e12


def loss_weights(f: np.ndarray, f_scale: float, loss: str) -> np.ndarray:
    """IRLS weights ρ'(f²) of scipy's robust losses at residuals ``f`` (1 for "linear").

    Parameters
    ----------
    f : (n,) array
        Residuals [radius units].
    f_scale : float
        Soft margin C of the loss [radius units].
    loss : {"linear", "huber", "soft_l1", "cauchy"}

    Returns
    -------
    (n,) array
        The weights.

    Raises
    ------
    ValueError
        For an unknown ``loss``.
    """
    if loss == "linear":
        return np.ones_like(f)
    z = np.abs(f) / f_scale
    if loss == "huber":
        return np.minimum(1.0, 1.0 / np.maximum(z, 1e-300))
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1 + z * z)
    if loss == "cauchy":
        return 1.0 / (1 + z * z)
    raise ValueError(f"unknown loss {loss!r}")


def curvature_weights(f: np.ndarray, f_scale: float, loss: str) -> np.ndarray:
    """Weights of the loss's second derivative in f, ``d(ρ'(f²)·f)/df``, for the normal matrix.

    Huber: 1 inside ``f_scale``, 0 beyond (ρ is linear in |f| there). Used instead of the IRLS
    weights ρ'(f²), this is Newton's step in the loss (Gauss-Newton in the model) and converges
    in a few steps where IRLS creeps linearly (factor ~7 per step on a magnetometer with 7 %
    outliers); the gradient, and so the minimum, is unchanged. Other losses keep ρ'(f²).

    Parameters
    ----------
    f, f_scale, loss
        As for :func:`loss_weights`.

    Returns
    -------
    (n,) array
        The weights.
    """
    if loss != "huber":
        return loss_weights(f, f_scale, loss)
    inside = (np.abs(f) <= f_scale).astype(float)
    # most samples beyond f_scale: too little curvature left to step with, fall back to IRLS
    return inside if inside.sum() > 0.5 * f.size else loss_weights(f, f_scale, loss)


def loss_cost(f: np.ndarray, f_scale: float, loss: str) -> float:
    """½ Σ ρ(f²) with scipy's scaling ``ρ(z) = C²·ρ₀(z/C²)`` [residual units²].

    Parameters
    ----------
    f, f_scale, loss
        As for :func:`loss_weights` (``C`` = ``f_scale``).

    Returns
    -------
    float
        The cost [residual units²].

    Raises
    ------
    ValueError
        For an unknown ``loss``.
    """
    if loss == "linear":
        return 0.5 * float(f @ f)
    z = (f / f_scale) ** 2
    if loss == "huber":
        rho = np.where(z <= 1, z, 2 * np.sqrt(z) - 1)
    elif loss == "soft_l1":
        rho = 2 * (np.sqrt(1 + z) - 1)
    elif loss == "cauchy":
        rho = np.log1p(z)
    else:
        raise ValueError(f"unknown loss {loss!r}")
    return 0.5 * f_scale ** 2 * float(np.sum(rho))


def residual(x: np.ndarray, sT: np.ndarray, entries) -> np.ndarray:
    """``|M(s − o)| − 1`` (n,) for ``x = [o (3), m (k)]`` and samples ``sT`` (3, n), in units
    of the radius.

    Parameters
    ----------
    x : (3 + k,) array
        Offset o [radius units] and the k free matrix parameters m.
    sT : (3, n) array
        Samples, transposed [radius units].
    entries : list
        Layout of the matrix parameters (:func:`apmcal.solvers.ellipsoid.paper.params_to_matrix`).

    Returns
    -------
    (n,) array
        The residuals [radius units].
    """
    M = params_to_matrix(x[3:], entries)
    # einsum, not M @ c: a 3×3 by 3×n BLAS product is threaded, which on a busy 2-core
    # machine costs 4× the single-threaded loop
    u = np.einsum("ij,jn->in", M, sT - x[:3, None])
    return np.sqrt(np.einsum("in,in->n", u, u)) - 1.0


def residual_jacobian(x: np.ndarray, sT: np.ndarray, entries) -> tuple[np.ndarray, np.ndarray]:
    """(r (n,), J (p, n)): the residual of :func:`residual` and its transposed Jacobian.

    [Niespodziany]'s geometric residual; ``∂r/∂o = −Mᵀn``, ``∂r/∂M_ab = n_a·c_b`` with
    ``c = s − o``, ``n = Mc/|Mc|`` (as :func:`apmcal.solvers.ellipsoid.paper.geometric_residual`,
    which returns the (n, p) layout).

    Parameters
    ----------
    x, sT, entries
        As for :func:`residual` (p = 3 + k parameters).

    Returns
    -------
    r : (n,) array
        The residuals [radius units].
    J : (p, n) array
        Their transposed Jacobian.
    """
    M = params_to_matrix(x[3:], entries)
    c = sT - x[:3, None]
    u = np.einsum("ij,jn->in", M, c)            # (see residual: no threaded BLAS here)
    norm = np.sqrt(np.einsum("in,in->n", u, u))
    nrm = u / np.where(norm > 0, norm, 1.0)
    J = np.empty((3 + len(entries), sT.shape[1]))
    np.einsum("ji,jn->in", -M, nrm, out=J[:3])
    for k, cells in enumerate(entries):
        (a, b), rest = cells[0], cells[1:]
        np.multiply(nrm[a], c[b], out=J[3 + k])
        for a, b in rest:
            J[3 + k] += nrm[a] * c[b]
    return norm - 1.0, J


def gradient(x: np.ndarray, sT: np.ndarray, entries) -> np.ndarray:
    """``Jᵀr`` (p,) of the geometric residual without forming J (p, n): ``−Mᵀ Σ nᵢrᵢ`` for the
    offset, ``Σ rᵢ n_a c_b`` (one 3×3 product of (3, n) arrays) for the matrix entries.

    Parameters
    ----------
    x, sT, entries
        As for :func:`residual` (p = 3 + k parameters).

    Returns
    -------
    (p,) array
        The gradient of ½ Σ r² [radius units²].
    """
    M = params_to_matrix(x[3:], entries)
    c = sT - x[:3, None]
    u = np.einsum("ij,jn->in", M, c)
    norm = np.sqrt(np.einsum("in,in->n", u, u))
    nr = u * ((norm - 1.0) / np.where(norm > 0, norm, 1.0))       # nᵢ·rᵢ
    G = np.einsum("an,bn->ab", nr, c)                              # Σ rᵢ n_a c_b
    return np.concatenate([-(M.T @ nr.sum(axis=1)), [sum(G[a, b] for a, b in cells)
                                                      for cells in entries]])


@dataclass
class Problem:
    """One weighted, optionally regularised geometric fit (everything in radius units).

    ``sw`` (n,) are the square roots of the sample weights; ``prior = (m_p, λ)`` adds rows
    ``λ·(m − m_p)`` for the matrix parameters (see ``ellipsoid_robust._solve``); ``lo, hi``
    (p,) are the box bounds.

    Attributes
    ----------
    sT : (3, n) array
        Samples, transposed, over the radius.
    entries : list
        Layout of the matrix parameters.
    sw : (n,) array
        Square roots of the sample weights.
    loss : str
        scipy's loss name ("linear", "huber", "soft_l1", "cauchy").
    f_scale : float
        Soft margin of the loss [radius units].
    lo, hi : (p,) array
        Box bounds.
    prior : tuple (m_p (k,) array, λ float), optional
        Prior on the matrix parameters.
    """

    sT: np.ndarray
    entries: list
    sw: np.ndarray
    loss: str
    f_scale: float
    lo: np.ndarray
    hi: np.ndarray
    prior: tuple | None = None

    def __post_init__(self):
        self.unit_weights = bool(np.all(self.sw == 1.0))

    def prior_rows(self, x: np.ndarray) -> np.ndarray:
        """λ·(m − m_p) (k,), or an empty array without a prior."""
        if self.prior is None or not self.prior[1]:
            return np.zeros(0)
        m_p, lam = self.prior
        return lam * (x[3:] - m_p)

    def cost(self, x: np.ndarray) -> float:
        """½ Σ ρ(f²) over data and prior rows, as least_squares defines it."""
        f = residual(x, self.sT, self.entries)
        if not self.unit_weights:
            f *= self.sw
        return (loss_cost(f, self.f_scale, self.loss)
                + loss_cost(self.prior_rows(x), self.f_scale, self.loss))

    def normal_equations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(A (p, p), g = ∇cost (p,), cost) at ``x``.

        ``g = Σ ρ'(f²)·f·∇f`` and ``A = Σ c·∇f∇fᵀ`` with c the loss curvature
        (:func:`curvature_weights`), f = √w·r: one (p, n) product each.

        Parameters
        ----------
        x : (p,) array
            Parameters ``[o (3), m (k)]``.

        Returns
        -------
        A : (p, p) array
            Normal matrix.
        g : (p,) array
            Gradient of the cost.
        cost : float
            ½ Σ ρ(f²) over data and prior rows.
        """
        r, J = residual_jacobian(x, self.sT, self.entries)
        unit = self.unit_weights
        f = r if unit else r * self.sw
        if self.loss == "linear":        # ρ' = ρ'' = 1: no per-sample weights to apply
            g = J @ (f if unit else self.sw * f)
            if not unit:
                J *= self.sw
            A = J @ J.T
        else:
            g = J @ (loss_weights(f, self.f_scale, self.loss) * (f if unit else self.sw * f))
            if not unit:
                J *= self.sw             # J of f, in place: no second (p, n) array
            A = (J * curvature_weights(f, self.f_scale, self.loss)) @ J.T
        fp = self.prior_rows(x)
        if fp.size:
            lam = self.prior[1]
            A[3:, 3:] += np.diag(curvature_weights(fp, self.f_scale, self.loss) * lam * lam)
            g[3:] += loss_weights(fp, self.f_scale, self.loss) * lam * fp
        cost = loss_cost(f, self.f_scale, self.loss) + loss_cost(fp, self.f_scale, self.loss)
        return A, g, cost


def _free(x: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Variables not held at a bound: a variable on its bound stays there while the descent
    direction −g points out of the box."""
    return ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))


def _damped_step(A, g, free, mu) -> np.ndarray:
    """Solve ``(A + μ·diag(A)) δ = −g`` on the free variables (zeros elsewhere)."""
    step = np.zeros_like(g)
    Af = A[np.ix_(free, free)]
    d = np.maximum(np.diag(Af), 1e-300)
    try:
        step[free] = np.linalg.solve(Af + mu * np.diag(d), -g[free])
    except np.linalg.LinAlgError:
        step[free] = -g[free] / (d * (1 + mu))
    return step


def solve(problem: Problem, x0: np.ndarray, max_iter: int = MAX_ITER) -> np.ndarray:
    """Minimise ``problem``'s cost from ``x0`` (clipped into the box); returns x (p,).

    Each iteration forms the normal equations once; rejected steps only raise the damping and
    cost one residual evaluation.

    Parameters
    ----------
    problem : Problem
        The fit.
    x0 : (p,) array
        Start ``[o (3), m (k)]`` [radius units for o].
    max_iter : int
        Iterations at most.

    Returns
    -------
    (p,) array
        The parameters at the minimum found.
    """
    lo, hi = problem.lo, problem.hi
    x = np.clip(np.asarray(x0, dtype=float), lo, hi)
    mu = MU_START
    for _ in range(max_iter):
        A, g, cost = problem.normal_equations(x)
        free = _free(x, g, lo, hi)
        if not free.any():
            break
        while mu <= MU_MAX:
            x_new = np.clip(x + _damped_step(A, g, free, mu), lo, hi)
            new_cost = problem.cost(x_new)
            if new_cost <= cost:
                break
            mu *= 8.0
        else:
            break                            # no descent left at any damping: a minimum
        step = x_new - x
        x, mu = x_new, max(mu / 8.0, 1e-12)
        if _settled(step, A, cost, problem.sT.shape[1], x) or cost - new_cost <= FTOL * cost:
            break
    return x


def _settled(step: np.ndarray, A: np.ndarray, cost: float, n: int, x: np.ndarray) -> bool:
    """True when the last step was below ``SD_TOL`` standard deviations of the parameters
    (``δᵀAδ ≤ SD_TOL²·σ²`` with σ² = 2·cost/(n − p), the residual variance), or negligible
    relative to x: iterating on cannot move the estimate by anything its noise could show,
    and saves the pass over the samples that would only confirm it."""
    sigma2 = 2.0 * cost / max(n - len(x), 1)
    return (float(step @ A @ step) <= SD_TOL ** 2 * sigma2
            or np.linalg.norm(step) <= XTOL * (XTOL + np.linalg.norm(x)))
