"""Robust geometric ellipsoid fit with uncertainty and the numbers it is judged by.

Improves on [Niespodziany]'s two estimators in three ways:

1. start: the general algebraic quadric LS fit (10 coefficients, as in Li & Griffiths 2004 but
   without their ellipsoid constraint; rejected when not an ellipsoid), or [Niespodziany]'s sphere fit
   when the directions cover the sphere poorly;
2. fit: bounded least squares (``least_squares``' cost, minimised on 9×9 normal equations by
   :mod:`apmcal.solvers.ellipsoid.lm`) on the *geometric* residual ``|M(s − o)| − r`` with a
   Huber loss (outliers, motion during "static" holds), then plain LS on the samples within 4
   robust sigmas (full Gaussian efficiency, no pull from gross outliers) — [Niespodziany] minimises the
   same residual but on all samples unweighted (Fig. 4) or an algebraic one (Fig. 2); bounds
   and a weak prior toward the sphere keep it out of the degenerate valley (see :func:`_solve`);
3. honesty: when the directions do not span the sphere (few poses, one plane) the off-diagonal
   terms are not determined, so the fit falls back to a diagonal M and says so; the covariance
   σ²(JᵀWJ)⁻¹ at the solution gives one-sigma figures (apmcal/solvers/uncertainty.py).

Convention: ``calibrated = M @ (measured − o)`` (apmcal/solvers/result.py), ``offset = o``,
``matrix = M`` (= [Niespodziany]'s W⁻¹ for the symmetric parameterisation).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.solvers.coverage import MIN_SCATTER_FULL, direction_coverage
from apmcal.solvers.ellipsoid.lm import Problem, loss_weights, residual, residual_jacobian
from apmcal.solvers.ellipsoid.lm import solve as lm_solve
from apmcal.solvers.ellipsoid.paper import (
    DIAGONAL_ENTRIES,
    SYMMETRIC_ENTRIES,
    UPPER_ENTRIES,
    check_samples,
    params_to_matrix,
    sphere_fit,
)
from apmcal.solvers.report_types import Coverage, EllipsoidFit, Residuals
from apmcal.solvers.result import SensorCalibration
from apmcal.solvers.uncertainty import bootstrap, covariance_from_normal_equations

ENTRIES = {"symmetric": SYMMETRIC_ENTRIES, "upper": UPPER_ENTRIES, "diagonal": DIAGONAL_ENTRIES}
MAX_COND = 1e6             # Jacobian condition number above which the full fit is not trusted
PRESOLVE_SAMPLES = 20_000  # samples of the first, subsampled pass of a fit from a far start


def algebraic_ellipsoid(samples) -> tuple[np.ndarray, np.ndarray] | None:
    """General quadric LS fit → (centre o, shape A) with ``(s − o)ᵀA(s − o) = 1``, or None.

    Fits ``[x², y², z², 2xy, 2xz, 2yz, 2x, 2y, 2z]·v = 1`` on centred, scaled data (conditioning);
    None when the quadric is not an ellipsoid (A not positive definite) or the design is singular.

    Parameters
    ----------
    samples : (n, 3) array
        Samples [sensor units].

    Returns
    -------
    o : (3,) array
        Centre [sensor units].
    A : (3, 3) array
        Shape, symmetric positive definite [1/sensor units²].
    """
    s = np.asarray(samples, dtype=float)
    mu, scale = s.mean(axis=0), s.std() or 1.0
    x, y, z = ((s - mu) / scale).T
    D = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z])
    v, _, rank, _ = np.linalg.lstsq(D, np.ones(len(s)), rcond=None)
    if rank < 9:
        return None
    Q = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    try:
        oc = -np.linalg.solve(Q, v[6:9])
    except np.linalg.LinAlgError:
        return None
    k = 1.0 + oc @ Q @ oc
    A = Q / k
    if k <= 0 or np.any(np.linalg.eigvalsh(A) <= 0):
        return None
    return mu + scale * oc, A / scale ** 2


def _start(s: np.ndarray, radius: float, use_quadric: bool) -> tuple[np.ndarray, np.ndarray, str]:
    """Start (offset, M) from the quadric fit, else [Niespodziany]'s sphere fit (M = r/S · I)."""
    if use_quadric:
        q = algebraic_ellipsoid(s)
        if q is not None:
            o, A = q
            lam, V = np.linalg.eigh(A)
            return o, radius * (V * np.sqrt(lam)) @ V.T, "algebraic quadric"
    o, S = sphere_fit(s)
    return o, np.eye(3) * radius / S, "sphere ([Niespodziany] step 1)"


def _solve(s, radius, o0, M0, entries, loss, f_scale, w, bounds, prior=None,
           presolve: bool = False):
    """One bounded fit in units of the radius; returns (x, r (n,), J (p, n)) of the data rows.

    ``prior = (m_prior, weight)`` appends rows ``weight·(m − m_prior)`` for the matrix
    parameters. They are needed: with a free matrix the geometric cost has a degenerate valley
    (M → 0 with |o| → ∞ maps every sample to one point at distance r, residual → 0), which an
    optimiser follows whenever the directions do not pin M down (partial coverage).
    ``bounds = (lo, hi)`` in the same units keep the solution physical (see :func:`_bounds`).
    The minimiser is :func:`apmcal.solvers.ellipsoid.lm.solve` (the cost least_squares had,
    on p×p normal equations). ``presolve``: from a far start (the quadric) on many samples,
    first converge on every k-th sample (≤ ``PRESOLVE_SAMPLES``), so that the full set only
    pays for the last few steps; the minimum reached is the full set's either way.
    """
    sT = np.ascontiguousarray((np.asarray(s, dtype=float) / radius).T)
    x0 = np.concatenate([o0 / radius, [M0[c[0]] for c in entries]])
    lo, hi = bounds
    problem = Problem(sT, entries, np.sqrt(w), loss, f_scale, lo, hi, prior)
    n = sT.shape[1]
    if presolve and n > 2 * PRESOLVE_SAMPLES:
        k = n // PRESOLVE_SAMPLES
        x0 = lm_solve(replace(problem, sT=np.ascontiguousarray(sT[:, ::k]),
                              sw=problem.sw[::k]), x0)
    x = lm_solve(problem, x0)
    r, J = residual_jacobian(x, sT, entries)
    return x, r, J


def _cond(J: np.ndarray) -> float:
    """Condition number of the (p, n) Jacobian from its p×p Gram matrix: √(λmax/λmin).

    The same number as ``np.linalg.cond(J.T)`` (an n×p SVD) to ~1e-4 relative for condition
    numbers up to 1e6 (MAX_COND), where JᵀJ's eigenvalues are still resolved in float64.
    """
    lam = np.linalg.eigvalsh(J @ J.T)
    return float(np.sqrt(lam[-1] / lam[0])) if lam[0] > 0 else float("inf")


def _bounds(o_sph, S_sph, radius, entries) -> tuple[np.ndarray, np.ndarray]:
    """Physical box in radius units: offset within ±S/2 of the sphere centre, diagonal of M in
    [0.5, 2]·r/S, cross terms within ±0.5·r/S (ArduPilot accepts diag 0.2..5, |offdiag| < 1 for
    the compass; accelerometer scale 0.8..1.2 — ardupilot-facts.md). A solution on the box edge
    is reported as poorly determined."""
    k = r_s = radius / S_sph
    diag = np.array([len(c) == 1 and c[0][0] == c[0][1] for c in entries])
    lo = np.concatenate([(o_sph - 0.5 * S_sph) / radius, np.where(diag, 0.5 * k, -0.5 * r_s)])
    hi = np.concatenate([(o_sph + 0.5 * S_sph) / radius, np.where(diag, 2.0 * k, 0.5 * r_s)])
    return lo, hi


HUBER_K = 1.345                          # Huber's 95 %-efficiency constant
ONE_SIGMA_OF_UNIFORM = 1.0 / np.sqrt(12.0)   # σ of a rounding error, per step


def _default_f_scale(s, radius, o0, M0, entries) -> float:
    """1.345 × the MAD noise of the start's residuals [radius units] (Huber's 95 %-efficiency
    constant), at least 1e-9."""
    r0 = residual(np.concatenate([o0 / radius, [M0[c[0]] for c in entries]]),
                  np.ascontiguousarray(s.T / radius), entries)
    mad = 1.4826 * np.median(np.abs(r0 - np.median(r0)))
    return max(1.345 * mad, 1e-9)


def _covariance(J: np.ndarray, r: np.ndarray, irls: np.ndarray, prior) -> tuple[np.ndarray, int]:
    """σ²(JᵀWJ + λ²·I_m)⁻¹ at the solution, and the rank (radius units).

    J (p, n) and r (n,) are the data rows, ``irls`` their loss × sample weights. The prior rows
    (zero residual, unit weight, counted as parameters so that the dof stay n − p) are
    information too and enter the normal matrix as λ² on the matrix block.
    """
    A = J @ J.T if np.all(irls == 1.0) else (J * irls) @ J.T    # LS stage: unit weights
    if prior is not None:
        A[3:, 3:] += prior[1] ** 2 * np.eye(A.shape[0] - 3)
    return covariance_from_normal_equations(A, float(np.sum(irls * r * r)),
                                            float(np.sum(irls)) - A.shape[0])


def fit_ellipsoid_robust(samples, radius: float, *, loss: str = "huber",
                         f_scale: float | None = None, weights=None,
                         parameterisation: str = "symmetric", n_bootstrap: int = 0,
                         rng=None, prior_sigma: float | None = 0.3,
                         reject_sigma: float | None = 4.0, start: SensorCalibration | None = None,
                         sphere: tuple | None = None, resolution: float | None = None,
                         info: dict | None = None) -> SensorCalibration:
    """Robust geometric ellipsoid fit: offset (3) + symmetric/upper-triangular M (6).

    Parameters
    ----------
    samples : (n, 3) array
        Sensor output (mGauss, m/s², counts).
    radius : float
        Known field magnitude, same units (|g|, WMM total intensity).
    loss : {"huber", "soft_l1", "cauchy", "linear"}
        Robust loss, as scipy.optimize.least_squares defines it.
    f_scale : float, optional
        Residual scale [sensor units] where the loss turns robust; default 1.345 × the MAD-based
        noise estimate of the start residuals (Huber's 95 %-efficiency constant).
    weights : (n,) array, optional
        Per-sample weights (e.g. to balance sample density over the sphere).
    parameterisation : {"symmetric", "upper", "diagonal"}
        M symmetric ([Niespodziany]), upper-triangular ([Oppong] F) or diagonal (ArduPilot INS_ACCSCAL).
        A full M is reduced to "diagonal" when the directions do not span the sphere or the
        Jacobian is ill-conditioned; ``info["notes"]`` says so.
    prior_sigma : float or None
        One-sigma prior on each matrix term around the sphere solution (r/S)·I; it removes the
        degenerate valley of the geometric cost under partial coverage and is negligible against
        hundreds of well-spread samples. None switches it off.
    reject_sigma : float or None
        After the robust fit, samples whose residual deviates by more than this many robust
        sigmas (MAD) are dropped and the fit is finished by plain LS on the rest (None: skip).
    n_bootstrap : int
        If > 0, also bootstrap sigma (``info["bootstrap_sigma"]``).
    rng : int or numpy.random.Generator, optional
        Seed or generator of the bootstrap resamples.
    start : SensorCalibration, optional
        Start (offset, matrix) instead of the quadric fit: a fit already known to be close
        (refits on a subset or on simulated samples of a fitted model) needs a few steps only.
        With ``f_scale`` given, the cost minimised is the same whatever the start.
    sphere : tuple, optional
        (offset (3,), radius) of :func:`sphere_fit` on the same ``samples``,
        when the caller has it already (it sets the box and the prior).
    resolution : float, optional
        Quantization step of the samples [sensor units] (whole mGauss: 1). A sample's radial
        error from rounding is at most step·√3/2, its σ step/√12: the robust scale and the
        outlier test never go below that σ, so rounding is not called an outlier (noise-free
        whole-unit readings otherwise have a MAD near 0).
    info : dict, optional
        Filled with rms, cond, rank, start, parameterisation, coverage, notes, cov.

    Returns
    -------
    SensorCalibration
        with ``sigma = {"offset": (3,), "matrix": (3, 3)}`` (sensor units / dimensionless).

    Raises
    ------
    ApmcalError
        On invalid weights, a radius ≤ 0, an unknown parameterisation or too few samples.
    """
    s, w, radius = _checked_inputs(samples, weights, radius, parameterisation)
    notes: list[str] = []
    o_sph, S_sph = sphere_fit(s) if sphere is None else sphere
    # the fraction is for info only (the verdict scores the calibrated samples): from ≤ 40 000
    cov0 = direction_coverage(s, o_sph, fraction=info is not None,
                              fraction_samples=2 * PRESOLVE_SAMPLES)
    flat = min(cov0["scatter_eig"][0], cov0["spread_eig"][0])
    mode = _parameterisation_for(parameterisation, flat, len(s), notes)
    if start is None:
        o0, M0, start_name = _start(s[::max(1, len(s) // PRESOLVE_SAMPLES)], radius,
                                    use_quadric=flat >= MIN_SCATTER_FULL)
    else:
        o0, M0, start_name = start.offset, start.matrix, "given"
    if mode == "diagonal":
        M0 = np.diag(np.abs(np.diag(M0)))
    quant_n = (float(resolution) * ONE_SIGMA_OF_UNIFORM / radius) if resolution else 0.0
    f_scale_n = (max(_default_f_scale(s, radius, o0, M0, ENTRIES[mode]), HUBER_K * quant_n)
                 if f_scale is None else float(f_scale) / radius)
    fit = _Fit(s, w, radius, o_sph, S_sph, f_scale_n, prior_sigma)
    finish_ls = loss != "linear" and bool(reject_sigma)
    x, r, J, cond, mode = _robust_stage(fit, o0, M0, mode, loss, finish_ls,
                                        presolve=start is None, notes=notes)
    entries = ENTRIES[mode]
    keep = np.ones(len(s), dtype=bool)
    if finish_ls:
        x, r, J, cond, keep = _inlier_stage(fit, x, r, entries, loss, reject_sigma, notes,
                                            quant_n)
    notes += _edge_notes(x, fit.bounds(entries), entries)
    lw = "linear" if reject_sigma else loss
    irls = loss_weights(r * np.sqrt(w[keep]), f_scale_n, lw) * w[keep]
    cov, rank = _covariance(J, r, irls, fit.prior(entries))
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    cal = SensorCalibration(offset=x[:3] * radius, matrix=params_to_matrix(x[3:], entries),
                            sigma={"offset": sd[:3] * radius,
                                   "matrix": params_to_matrix(sd[3:], entries)})
    if info is not None:
        info.update({"rms": float(np.sqrt(np.mean(r * r))) * radius, "cond": cond, "rank": rank,
                     "n_params": J.shape[0], "start": start_name, "parameterisation": mode,
                     "coverage": cov0, "notes": notes, "f_scale": f_scale_n * radius,
                     "outlier_fraction": float(np.mean(~keep)), "inliers": keep,
                     "cov": cov, "method": f"robust geometric ({loss} + LS on inliers)",
                     "prior": fit.prior(entries)})
    if n_bootstrap > 0:
        _bootstrap_sigma(fit, loss, mode, reject_sigma, n_bootstrap, rng, info)
    return cal


def _checked_inputs(samples, weights, radius, parameterisation):
    """(finite samples (n, 3), their weights (n,), radius) or a one-line ApmcalError."""
    raw = np.asarray(samples, dtype=float)
    if weights is not None:
        weights = np.asarray(weights, dtype=float).ravel()
        if raw.ndim != 2 or len(weights) != len(raw) or np.any(~np.isfinite(weights)) \
                or np.any(weights < 0):
            raise ApmcalError(f"ellipsoid fit: weights must be {len(raw)} finite values ≥ 0")
        weights = weights[np.all(np.isfinite(raw), axis=1)]
    s = check_samples(raw, 7)
    radius = float(radius)
    if not np.isfinite(radius) or radius <= 0:
        raise ApmcalError(f"ellipsoid fit: radius must be positive, got {radius}")
    if parameterisation not in ENTRIES:
        raise ApmcalError(f"unknown parameterisation {parameterisation!r}")
    return s, (np.ones(len(s)) if weights is None else weights), radius


def _parameterisation_for(asked: str, flat: float, n: int, notes: list[str]) -> str:
    """``asked``, or "diagonal" (with a note) when the directions do not span the sphere
    (smallest scatter/spread eigenvalue ``flat``) or there are fewer than 18 samples."""
    if asked == "diagonal" or (flat >= MIN_SCATTER_FULL and n >= 18):
        return asked
    why = (f"samples do not span the sphere (min scatter/spread eigenvalue {flat:.3f})"
           if flat < MIN_SCATTER_FULL else f"only {n} samples (< 18 = 2 per unknown)")
    notes.append(f"{why}: off-diagonal terms not determinable, fitted a diagonal matrix")
    return "diagonal"


@dataclass
class _Fit:
    """What every stage of one fit shares: the samples, their weights, the radius, the sphere
    fit (offset, radius) that sets the box and the prior, the loss scale [radius units] and
    the prior's σ per matrix term (None: no prior)."""

    s: np.ndarray
    w: np.ndarray
    radius: float
    o_sph: np.ndarray
    S_sph: float
    f_scale_n: float
    prior_sigma: float | None

    def bounds(self, entries):
        return _bounds(self.o_sph, self.S_sph, self.radius, entries)

    def prior(self, entries):
        """Pull toward the sphere solution M = (r/S)·I, σ_prior per matrix term (None: off)."""
        if self.prior_sigma is None:
            return None
        m_p = np.array([self.radius / self.S_sph if len(c) == 1 and c[0][0] == c[0][1] else 0.0
                        for c in entries])
        return m_p, (self.f_scale_n / 1.345) / self.prior_sigma

    def solve(self, keep, o0, M0, entries, loss, presolve=False):
        """:func:`_solve` on the samples ``keep`` (an index or slice)."""
        return _solve(self.s[keep], self.radius, o0, M0, entries, loss, self.f_scale_n,
                      self.w[keep], self.bounds(entries), self.prior(entries), presolve=presolve)


def _robust_stage(fit: _Fit, o0, M0, mode: str, loss: str, finish_ls: bool, *, presolve: bool,
                  notes: list[str]):
    """The robust-loss fit; (x, r over all samples, J, condition number, parameterisation).

    With an LS stage to follow, it only has to find the outliers: on many samples it runs on
    every k-th one (≤ 2·PRESOLVE_SAMPLES) and every sample is then judged by its residual at
    that fit; the estimate is the LS stage on all inliers. A full matrix whose Jacobian is
    ill-conditioned is refitted diagonal.
    """
    n = len(fit.s)
    k = n // PRESOLVE_SAMPLES if finish_ls and n > 2 * PRESOLVE_SAMPLES else 1
    x, r, J = fit.solve(slice(None, None, k), o0, M0, ENTRIES[mode], loss, presolve)
    cond = _cond(J)                                    # data rows only
    if mode != "diagonal" and not cond < MAX_COND:
        notes.append(f"Jacobian condition number {cond:.2g} > {MAX_COND:.0g}: full matrix not "
                     "determinable from these samples, fitted a diagonal matrix")
        mode = "diagonal"
        x, r, J = fit.solve(slice(None, None, k), o0, np.diag(np.abs(np.diag(M0))),
                            ENTRIES[mode], loss, presolve)
        cond = _cond(J)
    if k > 1:
        r = residual(x, np.ascontiguousarray(fit.s.T / fit.radius), ENTRIES[mode])
    if fit.prior_sigma is not None and not cond < MAX_COND:
        notes.append(f"still ill-conditioned (condition number {cond:.2g}): the result leans on "
                     f"the prior toward a sphere (σ_prior = {fit.prior_sigma}) — poorly "
                     "determined")
    return x, r, J, cond, mode


def _inlier_stage(fit: _Fit, x, r, entries, loss: str, reject_sigma: float, notes: list[str],
                  quant_sigma: float = 0.0):
    """Plain LS on the samples the robust fit calls inliers (within ``reject_sigma`` robust σ,
    the MAD's but never below ``quant_sigma``, the rounding's σ): the ML fit's Gaussian
    efficiency (Huber alone: ≈ 0.95) without the pull of gross outliers.
    Returns (x, r, J, condition number, inlier mask)."""
    dev = np.abs(r - np.median(r))
    keep = dev <= reject_sigma * max(1.4826 * np.median(dev), quant_sigma, 1e-12)
    x, r, J = fit.solve(keep, x[:3] * fit.radius, params_to_matrix(x[3:], entries), entries,
                        "linear")
    if not keep.all():
        notes.append(f"{np.sum(~keep)} of {len(fit.s)} samples rejected as outliers "
                     f"(> {reject_sigma}σ after the {loss} fit)")
    return x, r, J, _cond(J), keep


def _edge_notes(x, bounds, entries) -> list[str]:
    """A note naming the parameters that stopped on the physical box (not determined)."""
    lo, hi = bounds
    at_edge = np.isclose(x, lo, rtol=0, atol=1e-6) | np.isclose(x, hi, rtol=0, atol=1e-6)
    if not np.any(at_edge):
        return []
    names = [f"offset_{a}" for a in "xyz"] + [f"M_{'xyz'[c[0][0]]}{'xyz'[c[0][1]]}"
                                              for c in entries]
    return ["POORLY DETERMINED: " + ", ".join(n for n, e in zip(names, at_edge) if e)
            + " stopped at the physical bound — the samples do not determine it"]


def _bootstrap_sigma(fit: _Fit, loss, mode, reject_sigma, n_bootstrap: int, rng,
                     info: dict | None) -> None:
    """Resample and refit ``n_bootstrap`` times; σ (and failures) into ``info``."""
    bs = bootstrap(lambda d: fit_ellipsoid_robust(d, fit.radius, loss=loss,
                                                  f_scale=fit.f_scale_n * fit.radius,
                                                  parameterisation=mode,
                                                  prior_sigma=fit.prior_sigma,
                                                  reject_sigma=reject_sigma),
                   fit.s, n=n_bootstrap, rng=rng)
    if info is None:
        return
    info["bootstrap_failed"] = bs["failed"]
    if "sigma" in bs:
        info["bootstrap_sigma"] = bs["sigma"]
    if bs["failed"]:
        # a resample the fit cannot handle says the data barely determine the ellipsoid
        info.setdefault("notes", []).append(
            f"{bs['failed']} of {n_bootstrap} bootstrap refits failed: the bootstrap "
            "sigma describes only the resamples that could be fitted")


def fit_report(samples, cal: SensorCalibration, radius: float, info: dict | None = None,
               method: str = "") -> EllipsoidFit:
    """The numbers an ellipsoid calibration is judged by (:func:`apmcal.report.lines.
    ellipsoid_lines` words them): coverage and residuals of the calibrated ``samples``
    [sensor units], and the fit's internals from its ``info`` on these same samples.

    The coverage eigenvalues are the smaller of the calibrated samples' scatter (which exposes a
    collapsed fit) and the raw samples' own shape (``info``'s ``spread_eig``, whatever the centre).

    Parameters
    ----------
    samples : (n, 3) array
        The raw samples the fit used [sensor units].
    cal : SensorCalibration
        The fit.
    radius : float
        Field magnitude the fit scales to [sensor units].
    info : dict, optional
        The fit's ``info``.
    method : str
        Method name, when ``info`` has none.

    Returns
    -------
    EllipsoidFit
        Coverage, residuals [sensor units] and the fit's internals.
    """
    s = check_samples(samples, 1)
    info = info or {}
    calibrated = cal.apply(s)
    cov = direction_coverage(calibrated, np.zeros(3))
    shape_eig = (info["coverage"]["spread_eig"] if "coverage" in info
                 else direction_coverage(s, cal.offset, fraction=False)["spread_eig"])
    e = np.linalg.norm(calibrated, axis=1) - radius
    spread = float(1.4826 * np.median(np.abs(e - np.median(e))))     # robust σ (MAD)
    n_out = int(np.sum(np.abs(e - np.median(e)) > 5 * max(spread, 1e-12 * radius)))
    return EllipsoidFit(
        radius=float(radius), method=info.get("method", method),
        parameterisation=info.get("parameterisation", ""), samples=len(s),
        n_params=info.get("n_params"), rms=info.get("rms"), cond=info.get("cond"),
        rank=info.get("rank"), start=info.get("start"), f_scale=info.get("f_scale"),
        outlier_fraction=info.get("outlier_fraction"), notes=list(info.get("notes", [])),
        coverage=Coverage(cov["fraction"], np.minimum(cov["scatter_eig"], shape_eig)),
        residuals=Residuals(len(s), float(np.sqrt(np.mean(e ** 2))), spread, n_out))
