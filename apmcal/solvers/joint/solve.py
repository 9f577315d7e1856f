"""Tightly-coupled joint self-calibration of accelerometer, gyroscope and magnetometer ([Chow]).

The 42 parameters of [Chow] §3.1 (:mod:`apmcal.solvers.joint.model`) from one session of
still poses with hand-held turns between them, by the implicit (Gauss-Helmert) least squares
of [Chow] §3.3 on the conditions of §3.2 (:mod:`apmcal.solvers.joint.residuals`):

* eq. 14-15: minimise vᵀ·C_l⁻¹·v subject to f(X, Y + v) = 0. Linearised, A·δX + B·v + w = 0,
  whose solution is the weighted least squares of the misclosures w with weight (B·C_l·Bᵀ)⁻¹.
  Each outer iteration evaluates B·C_l·Bᵀ at the current X and minimises the whitened
  misclosures over X with ``scipy.optimize.least_squares`` (its trust-region Gauss-Newton is
  the Gauss-Helmert iteration with a step control), the design matrix of the pass's start
  held fixed and the problem compressed to 43 rows (:class:`_Compressed`); only X (42
  values) is ever unknown.
* Robustness (§3.3): Huber weights for the accelerometer's conditions (static norm, levelling,
  ZUPT), Tukey's biweight for the magnetometer's, re-computed each outer iteration; each
  family's variance factor is re-estimated from its residuals over its redundancy (variance
  components), as the noise of a hand-held session is not the still periods' white noise; a
  factor never goes below 1 (see :func:`_variance_components`).
* §5.1: parameters not significant by a two-sided t-test at 95 % are fixed to their error-free
  value and the fit is repeated once. Added here: the dropped parameters' spread about nominal
  is carried into the refitted parameters' covariance (a consider covariance), without which
  the refit's σ ignore what fixing them costs (in sitl, a gyro matrix entry 5σ off).

Simplified against the paper, and why: see :mod:`apmcal.solvers.joint.residuals` (block means,
closed-form condition covariance, CUPT left out). The Earth rate is not modelled (the paper
conditions the still gyro to zero, eq. 6): it stays in the gyro bias, as in [Chow].
"""
from __future__ import annotations

import numpy as np
from scipy import special
from scipy.optimize import least_squares

from apmcal.core.errors import ApmcalError
from apmcal.solvers.joint import model as jm
from apmcal.solvers.joint.covariance import Whitener
from apmcal.solvers.joint.jacobian import jacobian
from apmcal.solvers.joint.residuals import DIM, layout, misclosures
from apmcal.solvers.joint.trajectory import Trajectory
from apmcal.solvers.report_types import CalibrationReport, JointFit, MagneticField
from apmcal.solvers.result import Calibration

HUBER_K = 1.345          # 95 % Gaussian efficiency
TUKEY_C = 4.685          # 95 % Gaussian efficiency
ACC_FAMILIES = ("acc_norm", "level", "zupt")      # Huber ([Chow] §3.3)
MAG_FAMILIES = ("mag",)                            # Tukey
MAX_OUTER = 6
MAX_INNER = 10
MIN_TURN_DEG = 30.0      # less turning between still poses than this is "no motion"
T_TEST_LEVEL = 0.95


def joint_calibration(t, acc, gyr, mag, holds, *, gravity: float,
                      field_mgauss: float | None = None, t_test: bool = True) -> Calibration:
    """[Chow]'s joint calibration of raw sensor-frame samples.

    Parameters
    ----------
    t : (n,) array, s
    acc : (n, 3) array, m/s²
    gyr : (n, 3) array, rad/s
    mag : (n, 3) array, mGauss, or None
        On the same time base, or None (accelerometer and gyro only: the
        magnetometer conditions and its 12 parameters are left out).
    holds : list of StaticSegment
        The still periods in time order.
    gravity : float
        Local gravity [m/s²].
    field_mgauss : float, optional
        Field magnitude [mGauss] fixing the scale of D_m (default: the samples' sphere fit).
    t_test : bool
        Drop insignificant parameters and refit ([Chow] §5.1).

    Returns
    -------
    Calibration
        "joint": sensors acc, gyr (mapping into the accelerometer frame, with its
        g-sensitivity), mag; report (:class:`~apmcal.solvers.report_types.JointFit`) with the
        parameters and their σ, fixed and dropped parameters, family statistics.

    Raises
    ------
    ApmcalError
        Without gyro samples, when the session has no turns between still poses, or when the
        t-test finds no parameter significant.
    """
    from apmcal.solvers.ellipsoid.fit import fit_ellipsoid_robust, sphere_fit

    if gyr is None:
        raise ApmcalError("joint calibration needs gyro samples")
    source = "the caller" if field_mgauss is not None else "sphere fit"
    if mag is not None and field_mgauss is None:
        field_mgauss = float(sphere_fit(mag)[1])
    d = layout(t, acc, gyr, mag, holds, gravity, field_mgauss)
    check_motion(d, len(holds))
    free = np.ones(jm.N_PARAMS, bool)
    x0 = jm.NOMINAL.copy()
    x0[jm.SLICES["b_w"]] = np.median([gyr[b].mean(axis=0) for b in d.blocks], axis=0)
    if mag is None:
        free[list(jm.MAG_PARAMS)] = False
    else:
        ell = fit_ellipsoid_robust(mag, field_mgauss)
        x0[jm.SLICES["D_m"]] = np.linalg.inv(ell.matrix).ravel()
        x0[jm.SLICES["o_m"]] = ell.offset
    fit = _solve(d, x0, free)
    dropped: list[str] = []
    if t_test:
        insignificant = free & (fit["t"] < fit["t_crit"])
        if np.array_equal(insignificant, free):
            raise ApmcalError(f"joint calibration: none of the {int(free.sum())} parameters "
                              f"differs from an error-free sensor at 95 % confidence; the session "
                              f"does not determine them (hold more still poses in other "
                              f"orientations, with turns between them)")
        if insignificant.any():
            dropped = [jm.NAMES[i] for i in np.flatnonzero(insignificant)]
            x1 = fit["x"].copy()
            x1[insignificant] = jm.NOMINAL[insignificant]
            # a dropped parameter is set to nominal, which the full fit put x̂ ± σ away: its
            # uncertainty is the RMS error of that choice, √(x̂² + σ²) about nominal, and it
            # is carried into the refitted parameters as a "consider" covariance
            idx = np.flatnonzero(insignificant)
            spread = (fit["x"][idx] - jm.NOMINAL[idx]) ** 2 + fit["sigma"][idx] ** 2
            fit = _solve(d, x1, free & ~insignificant, consider=(insignificant, spread),
                         start=fit)
    cal = _calibration(fit, d, dropped)
    if mag is not None:
        cal.report.magnetic_field = MagneticField(float(d.field), source)
    return cal


def check_motion(d, n_holds: int) -> None:
    """Refuse a session the method cannot use: no turns between still poses.

    Parameters
    ----------
    d : JointData
        The session's layout (:func:`apmcal.solvers.joint.residuals.layout`).
    n_holds : int
        Number of still periods (for the message).

    Raises
    ------
    ApmcalError
        Without a moving interval between two holds, or with less than ``MIN_TURN_DEG`` [deg]
        of turning in all of them.
    """
    if not d.intervals:
        raise ApmcalError(f"joint calibration needs still poses with turns between them; found "
                          f"{n_holds} still period(s) and no motion between two of them")
    turn = sum(np.degrees(np.linalg.norm((d.gyr[k0:k1] - d.gyr[d.blocks[i]].mean(axis=0)).T
                                         @ d.dt[k0:k1])) for i, _, k0, k1 in d.intervals)
    if turn < MIN_TURN_DEG:
        raise ApmcalError(f"joint calibration needs the vehicle turned between still poses; the "
                          f"gyro shows only {turn:.0f}° of turning (need {MIN_TURN_DEG:.0f}°)")


def _families(d) -> tuple[str, ...]:
    fam = ["acc_norm", "zaru"] + (["level", "zupt"] if d.intervals else [])
    return tuple(fam + (["mag", "mag_datum"] if d.mag is not None else []))


def _robust_weights(u: np.ndarray, family: str) -> np.ndarray:
    """Huber (accelerometer) or Tukey (magnetometer) weights of standardised residuals ``u``."""
    a = np.abs(u)
    if family in ACC_FAMILIES:
        return np.minimum(1.0, HUBER_K / np.maximum(a, 1e-12))
    if family in MAG_FAMILIES:
        return np.where(a < TUKEY_C, (1 - (a / TUKEY_C) ** 2) ** 2, 0.0)
    return np.ones_like(a)


def _solve(d, x0: np.ndarray, free: np.ndarray, consider=None, start=None) -> dict:
    """Gauss-Helmert iterations with robust re-weighting (module docstring).

    ``consider`` = (mask, variances): parameters held fixed whose uncertainty is carried into
    the covariance of the estimated ones (a consider covariance: x̂ moves by S·δc for a change
    δc of the fixed values, S = −(AᵀA)⁻¹AᵀA_c, so cov += S·C_c·Sᵀ). ``start``: the
    weights and variance factors of an earlier fit to begin with (the t-test's refit).
    """
    families = _families(d)
    x = x0.copy()
    memo: dict = {}

    def at(xx):
        """The Trajectory at ``xx``, kept for the last point asked: the Whitener, the design
        matrix and the misclosures of one point share its integration."""
        key = xx.tobytes()
        if memo.get("x") != key:
            memo.clear()
            memo["x"], memo["traj"] = key, Trajectory(xx, d)
        return memo["traj"]

    def wmis(xx):
        """The misclosures at ``xx``, kept with its Trajectory."""
        at(xx)
        if "w" not in memo:
            memo["w"] = misclosures(xx, d, families, memo["traj"])
        return memo["w"]

    w0 = wmis(x)
    weights = {k: np.ones(len(v)) for k, v in w0.items()}
    factor = {k: 1.0 for k in w0}
    if start is not None:
        weights, factor = dict(start["weights"]), dict(start["factor"])

    def full(xf):
        xx = x.copy()
        xx[free] = xf
        return xx

    jmemo: dict = {}

    def raw_jacobian(xx, cols):
        """∂w/∂X at ``xx`` (unwhitened: the same for every Whitener), computed once per point:
        the end of one pass is the start of the next and the point of the statistics."""
        key = (xx.tobytes(), cols.tobytes())
        if key not in jmemo:
            jmemo.clear()
            jmemo[key] = jacobian(xx, d, families, cols, at(xx))
        return jmemo[key]

    for outer in range(MAX_OUTER):
        white = Whitener(x, d, families, weights, factor, at(x))

        def fun(xf, white=white):
            return white(wmis(full(xf)))

        def jac(xf, white=white):
            return white.jacobian(raw_jacobian(full(xf), free))

        # the outer loop re-linearises: within a pass the design matrix of its start serves
        # every Gauss-Newton step (a chord method; the misclosures are exact, and the last
        # passes start where they end, so the fixed point is the same to ~1e-3 σ,
        # benchmarks/joint_speed.py), one Jacobian per pass instead of one per step
        small = _Compressed(fun, jac(x[free]))
        res = least_squares(small, x[free], jac=small.jacobian, x_scale="jac",
                            method="lm", xtol=1e-8, ftol=1e-8, max_nfev=MAX_INNER)
        step = res.x - x[free]
        x[free] = res.x
        old = dict(factor)
        _variance_components(white, jac(res.x), small.full(res.x), wmis(x), weights, factor)
        settled = all(abs(factor[k] / old[k] - 1) < 0.05 for k in factor)
        if outer > 0 and settled and np.all(np.abs(step) <= 0.05 * small.sigma):
            break
    white = Whitener(x, d, families, weights, factor, at(x))
    fit = _statistics(x, free, white.jacobian(raw_jacobian(x, free)),
                      white(wmis(x)), weights, factor, families)
    if consider is not None:
        mask, variances = consider
        both = free | mask
        j = white.jacobian(jacobian(x, d, families, both, at(x)))
        jf, jc = j[:, free[both]], j[:, mask[both]]
        sens = -np.linalg.pinv(jf.T @ jf, hermitian=True) @ (jf.T @ jc)   # ∂x̂/∂c
        cc = np.diag(variances)
        fi, ci = np.flatnonzero(free), np.flatnonzero(mask)
        fit["cov"][np.ix_(fi, fi)] += sens @ cc @ sens.T
        fit["cov"][np.ix_(fi, ci)] = sens @ cc
        fit["cov"][np.ix_(ci, fi)] = (sens @ cc).T
        fit["cov"][np.ix_(ci, ci)] = cc
        fit["sigma"] = np.sqrt(np.clip(np.diag(fit["cov"]), 0, None))
    return fit


def _variance_components(white, j, r, w, weights, factor) -> None:
    """Re-estimate each family's variance factor and robust weights, in place.

    Variance components (Förstner 1979, as used with Gauss-Helmert adjustments): a family's
    factor² is its weighted squared residuals over its redundancy Σ(1 − h_ii), h the diagonal
    of the hat matrix — not over its number of rows, since a family that carries most of the
    information about some parameters (levelling, ZUPT) keeps far smaller residuals than its
    noise. Weights: Huber or Tukey (:func:`_robust_weights`) of each condition's standardised
    residual.
    """
    h = np.sum((j @ np.linalg.pinv(j.T @ j, hermitian=True)) * j, axis=1)
    for k, rows in white.family_rows(w).items():
        if k == "mag_datum":
            continue
        dim = w[k].shape[1]
        used = np.repeat(weights[k], dim) > 1e-3
        redundancy = float(np.sum(1 - h[rows][used]))
        if redundancy > 1:
            # never below 1: a family cannot be quieter than the white noise of the still
            # periods; a smaller factor (a few dozen conditions, some parameters fitted mostly
            # by them) would only make the reported σ too small
            factor[k] = max(1.0, factor[k] * float(np.sqrt(np.sum(r[rows][used] ** 2)
                                                         / redundancy)))
        weights[k] = _robust_weights(white.standardised(w, k) / factor[k], k)


class _Compressed:
    """The whitened residuals r(x) (N rows) of a pass, seen by the least squares through the
    pass's fixed design matrix J₀ as p + 1 rows: r̃ = [R⁻ᵀ·J₀ᵀ·r; |r − J₀·(J₀ᵀJ₀)⁺·J₀ᵀ·r|]
    with RᵀR = J₀ᵀJ₀, and Jacobian [R; 0].

    Why: MINPACK's Levenberg-Marquardt re-factors the Jacobian it is given (Householder QR,
    N × p) at every iteration, most of the fit's time with N in the thousands, though the
    matrix does not change within a pass. Its steps depend on the Jacobian only through JᵀJ,
    Jᵀr and the column norms, and on the residuals through |r|; r̃ and [R; 0] give the same
    (|r̃| = |r|, [R; 0]ᵀ·r̃ = J₀ᵀ·r, RᵀR = J₀ᵀJ₀, so the same column norms): the same
    iterations, on a (p + 1) × p matrix. R = Λ^½·Vᵀ·S⁻¹ from the eigen-decomposition V·Λ·Vᵀ
    of J₀ᵀJ₀ equilibrated by its diagonal S⁻²; directions with no information (λ below
    1e-15·λ_max, as a pseudo-inverse) get none in r̃ either.

    Parameters
    ----------
    fun : callable
        x (p,) → whitened residuals r (N,).
    j0 : (N, p) array
        The pass's design matrix.

    Attributes
    ----------
    sigma : (p,) array
        √diag((J₀ᵀJ₀)⁺): σ of x for unit-variance residuals.
    """

    def __init__(self, fun, j0: np.ndarray):
        self.fun, self.j0 = fun, j0
        g = j0.T @ j0
        scale = 1.0 / np.sqrt(np.maximum(np.diag(g), 1e-300))
        lam, vec = np.linalg.eigh(g * np.outer(scale, scale))
        keep = lam > 1e-15 * max(float(lam.max()), 1e-300)
        root = np.sqrt(np.where(keep, lam, 0.0))
        self.r = root[:, None] * vec.T / scale                      # R, (p, p)
        self.project = np.where(keep, 1.0 / np.where(keep, root, 1.0), 0.0)[:, None] * (
            vec.T * scale)                                           # R⁻ᵀ, (p, p)
        self.sigma = np.sqrt(np.clip(np.einsum("ij,j,ij->i", vec, np.where(
            keep, 1.0 / np.where(keep, lam, 1.0), 0.0), vec), 0, None)) * scale
        self._last = (None, None)

    def full(self, x: np.ndarray) -> np.ndarray:
        """r(x), (N,): kept for the last point asked."""
        key = x.tobytes()
        if self._last[0] != key:
            self._last = (key, self.fun(x))
        return self._last[1]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """r̃(x), (p + 1,)."""
        r = self.full(x)
        head = self.project @ (self.j0.T @ r)
        rest = max(float(r @ r) - float(head @ head), 0.0)
        return np.append(head, np.sqrt(rest))

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """[R; 0], (p + 1, p), whatever ``x``."""
        return np.vstack([self.r, np.zeros((1, self.r.shape[1]))])


def _statistics(x, free, j, r, weights, factor, families) -> dict:
    """Parameter covariance σ₀²·(AᵀWA)⁻¹ and t values ([Chow] §5.1)."""
    n_eff = sum(float(weights[k].sum()) * DIM[k] for k in families if k != "mag_datum")
    dof = max(n_eff - int(free.sum()), 1.0)
    sigma0_sq = float(r @ r) / dof
    cov_free = sigma0_sq * np.linalg.pinv(j.T @ j, hermitian=True)
    cov = np.zeros((jm.N_PARAMS, jm.N_PARAMS))
    cov[np.ix_(free, free)] = cov_free
    sigma = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(free, np.abs(x - jm.NOMINAL) / sigma, np.inf)
    return {"x": x.copy(), "free": free.copy(), "cov": cov, "sigma": sigma, "t": t,
            "weights": {k: v.copy() for k, v in weights.items()},
            # the t quantile from scipy.special: scipy.stats would add ~1 s of import to every run
            "t_crit": float(special.stdtrit(dof, 0.5 + T_TEST_LEVEL / 2)), "dof": dof,
            "sigma0": float(np.sqrt(sigma0_sq)), "factor": dict(factor),
            "counts": {k: len(weights[k]) for k in families},
            "rejected": {k: int(np.sum(weights[k] < 0.01)) for k in families}}


def _calibration(fit: dict, d, dropped: list[str]) -> Calibration:
    sensors = ("acc", "gyr") + (("mag",) if d.mag is not None else ())
    cals, extra = jm.sensor_calibrations(fit["x"], fit["cov"], sensors)
    cals["gyr"].g_sensitivity = extra["gyr_g_sensitivity"]
    cals["gyr"].sigma["g_sensitivity"] = extra["gyr_g_sensitivity_sigma"]
    gyr_cost = float(np.linalg.norm(cals["gyr"].matrix - np.eye(3), 2))
    joint = JointFit(
        conditions=dict(fit["counts"]), rejected=dict(fit["rejected"]),
        noise_scale={k: float(v) for k, v in fit["factor"].items()},
        n_estimated=int(fit["free"].sum()), n_params=jm.N_PARAMS,
        parameters={n: [float(v), float(s)] for n, v, s, f in
                    zip(jm.NAMES, fit["x"], fit["sigma"], fit["free"]) if f or n in dropped},
        fixed=[n for n, f in zip(jm.NAMES, fit["free"]) if not f], dropped_t_test=dropped,
        gyr_matrix_cost_deg_per_turn=float(np.degrees(gyr_cost * 2 * np.pi)),
        gyr_g_sensitivity_at_1g=float(np.linalg.norm(extra["gyr_g_sensitivity"], 2) * d.gravity))
    return Calibration(method="joint", sensors=cals, report=CalibrationReport(joint=joint))
