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
* The start is the ellipsoid and static results (:func:`start_point`: the accelerometer's
  and the compass's robust ellipsoid fits, the gyro offset of the still poses, identity gyro
  matrix), and each pass is solved to its minimum before the weights below are re-estimated:
  a step is kept only when the pass's objective, the whitened misclosures re-evaluated
  exactly at the new point, decreases (the Levenberg-Marquardt ratio test, checked again
  after each run), and the design matrix is re-computed at the point reached whenever a run
  ends short of convergence or far (more than ``RELINEARISE_SIGMA`` σ) from where it was
  computed. Re-estimating the weights at a point short of the pass's minimum is how a fit
  drifts away: the families it has not yet fitted look noisy, are down-weighted, and then
  stop holding the fit (a hand-held session near a laptop: levelling and ZUPT noise scales of
  74 and 133, a gyro scale 20 % off). Outer passes stop when the noise scales have settled
  and a pass lowers its objective by less than ``OBJECTIVE_TOL``.
* The result is checked against its start (:func:`explained`): per condition family, the
  median standardised misclosure under each; a fit that explains some family more than
  ``WORSE_FACTOR`` times worse than the start (``WORSE_FACTOR_OWN`` for the two the start
  fits by construction) is not used — the start is returned, the reason
  in the report (``JointFit.fallback``).
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

from dataclasses import replace

import numpy as np
from scipy import special
from scipy.optimize import least_squares

from apmcal.core.errors import ApmcalError
from apmcal.solvers.holds import MIN_ELLIPSOID_HOLDS, MIN_ORIENTATIONS, distinct_orientations
from apmcal.solvers.joint import model as jm
from apmcal.solvers.joint.covariance import DATUM_SIGMA, Whitener
from apmcal.solvers.joint.jacobian import jacobian
from apmcal.solvers.joint.residuals import DIM, layout, misclosures
from apmcal.solvers.joint.trajectory import Trajectory
from apmcal.solvers.report_types import CalibrationReport, JointFit, MagneticField
from apmcal.solvers.result import Calibration, SensorCalibration

HUBER_K = 1.345          # 95 % Gaussian efficiency
TUKEY_C = 4.685          # 95 % Gaussian efficiency
ACC_FAMILIES = ("acc_norm", "level", "zupt")      # Huber ([Chow] §3.3)
MAG_FAMILIES = ("mag",)                            # Tukey
MAX_OUTER = 10           # outer passes (weights and noise scales re-estimated) per fit
MAX_INNER = 10           # misclosure evaluations per Levenberg-Marquardt run
MAX_LINEARISATIONS = 6   # design matrices per pass
RELINEARISE_SIGMA = 10.0  # a run that moved further than this [σ] is re-linearised and re-run
OBJECTIVE_TOL = 0.1      # a pass lowering its whitened objective less than this has converged
#                          (a tenth of what a one-σ step of one parameter lowers it by)
SETTLED = 0.05           # ... when no noise scale changed by more than this (relative)
WORSE_FACTOR = 2.0       # a family explained this many times worse than at the start: fallback
# ... except the two the start fits by construction (the ellipsoid: the static norms; the
# static gyro offset: the still gyro), which the joint fit trades a little of for the turns
# (a firmware session whose holds end in a damped stop: the still gyro 2.7 times the start's)
WORSE_FACTOR_OWN = {"acc_norm": 5.0, "zaru": 5.0}
FAMILY_WORDS = {"acc_norm": "static norm", "zaru": "still gyro",
                "level": "gravity carried by the gyro from pose to pose",
                "zupt": "velocity change between poses", "mag": "compass turned by the gyro"}
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
        The still periods in time order (of these samples).
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
        parameters and their σ, fixed and dropped parameters, family statistics, passes and
        convergence. When the fit explains the session worse than its start, the sensors are
        the start's (the ellipsoid and static results, :func:`start_point`), with the reason
        in ``JointFit.fallback`` and in the warnings.

    Raises
    ------
    ApmcalError
        Without gyro samples, when the session has no turns between still poses, or when the
        t-test finds no parameter significant.
    """
    from apmcal.solvers.ellipsoid.fit import sphere_fit

    if gyr is None:
        raise ApmcalError("joint calibration needs gyro samples")
    source = "the caller" if field_mgauss is not None else "sphere fit"
    if mag is not None and field_mgauss is None:
        field_mgauss = float(sphere_fit(mag)[1])
    d = layout(t, acc, gyr, mag, holds, gravity, field_mgauss)
    check_motion(d, len(holds))
    x0, start = start_point(d, holds)
    free = np.ones(jm.N_PARAMS, bool)
    if mag is None:
        free[list(jm.MAG_PARAMS)] = False
    fit = _solve(d, x0, free)
    passes, converged = fit["passes"], fit["converged"]
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
            # the refit is the result: its convergence is the one that counts
            passes, converged = passes + fit["passes"], fit["converged"]
    fit.update(passes=passes, converged=converged,
               explained=explained(d, fit["yardstick"], fit["x"]))
    cal = _calibration(fit, d, dropped)
    worse = worse_than_start(fit["explained"])
    if worse:
        cal = _fallback(cal, start, worse)
    elif not converged:
        cal.report.warnings.append(
            f"joint fit: its passes had not settled after {passes} (the result explains the "
            f"session at least as well as the ellipsoid and static results it started from)")
    if mag is not None:
        cal.report.magnetic_field = MagneticField(float(d.field), source)
    return cal


def start_point(d, holds) -> tuple[np.ndarray, Calibration]:
    """Where the fit starts: the ellipsoid and static results (the robust ellipsoid fit of the
    holds' accelerometer means and the gyro offset of the held samples, as
    :func:`apmcal.solvers.holds.ellipsoid_on_holds` makes them, and the robust ellipsoid fit of
    the compass samples), as the parameter vector and as the Calibration a fallback returns.

    Without the holds an ellipsoid needs (seven, in four orientations or more) the
    accelerometer starts error-free and is left out of the Calibration (it was not estimated);
    the gyro offset is then the median of the still blocks' means.

    Parameters
    ----------
    d : JointData
        The session's layout (:func:`apmcal.solvers.joint.residuals.layout`).
    holds : list of StaticSegment
        Its still periods.

    Returns
    -------
    (42,) array
        The start's parameters (:func:`apmcal.solvers.joint.model.from_board`).
    Calibration
        Method "joint": the start's sensors in the board frame, with their σ.
    """
    from apmcal.solvers.ellipsoid.fit import ellipsoid_calibration, fit_ellipsoid_robust

    samples = {"gyr": np.concatenate([d.gyr[h.kept()] for h in holds])}
    radius = {}
    if len(holds) >= MIN_ELLIPSOID_HOLDS and distinct_orientations(holds) >= MIN_ORIENTATIONS:
        samples["acc"], radius["acc"] = np.array([h.acc_mean for h in holds]), d.gravity
    # as apmcal.solvers.holds.ellipsoid_on_holds, with the sample order fixed (rng): the same
    # session always starts, and so ends, at the same point
    start = ellipsoid_calibration(samples, radius, rng=0)
    acc = start.sensors.get("acc", SensorCalibration())
    mag = fit_ellipsoid_robust(d.mag, d.field) if d.mag is not None else None
    if mag is not None:
        start.sensors["mag"] = mag
    x0 = jm.from_board(acc.offset, acc.matrix, start.sensors["gyr"].offset,
                       None if mag is None else mag.offset, None if mag is None else mag.matrix)
    return x0, replace(start, method="joint")


def yardstick(d, x_start: np.ndarray, traj: Trajectory | None = None) -> tuple:
    """What :func:`explained` measures by: the whitening at the start with unit weights and
    noise scales (each condition's residual over its white noise), and the start's
    misclosures.

    Parameters
    ----------
    d : JointData
    x_start : (42,) array
        The start's parameters.
    traj : Trajectory, optional
        Of ``x_start``, when the caller has it.

    Returns
    -------
    (Whitener, dict)
    """
    families = tuple(f for f in _families(d) if f != "mag_datum")
    tr = Trajectory(x_start, d) if traj is None else traj
    w = misclosures(x_start, d, families, tr)
    ones = {k: np.ones(len(v)) for k, v in w.items()}
    return Whitener(x_start, d, families, ones, dict.fromkeys(w, 1.0), tr), w


def explained(d, stick: tuple, x: np.ndarray) -> dict[str, list[float]]:
    """How well the start and the fit explain the session: per condition family, the median
    standardised misclosure (each condition's residual over its white-noise σ, the covariance
    evaluated at the start with unit weights and noise scales: one yardstick for both,
    :func:`yardstick`).

    Parameters
    ----------
    d : JointData
    stick : tuple
        :func:`yardstick` of the start.
    x : (42,) array
        The fit's parameters.

    Returns
    -------
    dict
        family → [start, fit] (dimensionless; 1 = the still periods' white noise).
    """
    white, w0 = stick
    w1 = misclosures(x, d, tuple(w0))
    return {f: [float(np.median(white.standardised(w0, f))),
                float(np.median(white.standardised(w1, f)))]
            for f in w0 if f in FAMILY_WORDS}


def worse_than_start(table: dict[str, list[float]]) -> str:
    """Why the fit explains the session worse than its start, or "" when it does not: the
    families whose median standardised misclosure (:func:`explained`) grew by more than
    ``WORSE_FACTOR`` over the start's (or over 1, the white noise, when the start's was less);
    ``WORSE_FACTOR_OWN`` for the static norm and still gyro, which the start fits by
    construction.

    Parameters
    ----------
    table : dict
        family → [start, fit].

    Returns
    -------
    str
    """
    worse = [f"{FAMILY_WORDS[f]} {fit:.3g} against {start:.3g}"
             for f, (start, fit) in table.items()
             if fit > WORSE_FACTOR_OWN.get(f, WORSE_FACTOR) * max(start, 1.0)]
    if not worse:
        return ""
    return ("it explains the session worse than the ellipsoid and static results it started "
            "from (median misclosure in units of the still periods' noise: "
            + "; ".join(worse) + ")")


def _fallback(cal: Calibration, start: Calibration, reason: str) -> Calibration:
    """The start's sensors in place of the fit's, the fit's report kept with the reason."""
    joint = replace(cal.report.joint, fallback=reason)
    given = "the ellipsoid and static results are given instead"
    if "acc" not in start.sensors:
        parts = ["the gyro offset of the still poses"] + (
            ["the compass's ellipsoid fit"] if "mag" in start.sensors else [])
        given = (f"{' and '.join(parts)} {'are' if len(parts) > 1 else 'is'} given instead; the "
                 f"accelerometer is not calibrated (its ellipsoid needs {MIN_ELLIPSOID_HOLDS} "
                 f"still poses in {MIN_ORIENTATIONS} orientations or more)")
    report = replace(start.report, joint=joint, warnings=start.report.warnings + [
        f"joint fit not used: {reason}; {given}"])
    return Calibration(method="joint", sensors=dict(start.sensors), report=report)


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
    if not d.intervals and d.clipped:
        raise ApmcalError(f"joint calibration: the gyro or accelerometer was at its range limit "
                          f"in every turn between still poses ({d.clipped}); turn more slowly")
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
    # the datum fixes only D_m's scale, which no other condition sees: it is met exactly by
    # rescaling D_m (:func:`_on_datum`) instead of being fitted, and enters the statistics
    passing = tuple(f for f in families if f != "mag_datum")
    x = _on_datum(x0.copy(), d)
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
            memo["w"] = misclosures(xx, d, passing, memo["traj"])
        return memo["w"]

    w0 = wmis(x)
    weights = {k: np.ones(len(w0[k]) if k in w0 else 1) for k in families}
    factor = dict.fromkeys(families, 1.0)
    if start is not None:
        weights, factor = dict(start["weights"]), dict(start["factor"])
        stick = start["yardstick"]
    else:
        # unit weights and scales at the start: the yardstick of :func:`explained` too
        stick = yardstick(d, x, at(x))

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
            jmemo[key] = jacobian(xx, d, passing, cols, at(xx))
        return jmemo[key]

    converged, adapting = False, True
    for outer in range(MAX_OUTER):
        white = Whitener(x, d, passing, weights, factor, at(x))

        def fun(xf, white=white):
            return white(wmis(full(xf)))

        def jac(xf, white=white):
            return white.jacobian(raw_jacobian(full(xf), free))

        r = fun(x[free])
        f_start = float(r @ r)
        f_end = _descend(fun, jac, x, free, f_start, d)
        if not adapting and f_start - f_end <= OBJECTIVE_TOL:
            converged = True
            break
        if adapting:
            old = dict(factor)
            _variance_components(white, raw_jacobian(x, free), wmis(x), weights, factor)
            # once the noise scales have settled they (and the robust weights) are held, and
            # the passes go on until the objective they define stops falling (a refit starts
            # from settled scales: its first pass may already find them unchanged)
            adapting = ((outer == 0 and start is None)
                        or any(abs(factor[k] / old[k] - 1) >= SETTLED for k in factor))
    if not converged:                  # else the last pass's weights hold: its whitening
        white = Whitener(x, d, passing, weights, factor, at(x))
    datum = families[len(passing):]    # the compass datum: a constraint in the statistics
    scale = 1.0 / (DATUM_SIGMA * d.noise["mag"]) if datum else 0.0

    def whitened_design(cols, a):
        j = white.jacobian(a)
        if datum:
            j = np.vstack([j, scale * jacobian(x, d, datum, cols, at(x))["mag_datum"][0]])
        return j

    r = white(wmis(x))
    if datum:
        r = np.append(r, scale * misclosures(x, d, datum, at(x))["mag_datum"][0])
    fit = _statistics(x, free, whitened_design(free, raw_jacobian(x, free)), r, weights, factor,
                      families)
    fit.update(passes=outer + 1, converged=converged, yardstick=stick)
    if consider is not None:
        mask, variances = consider
        both = free | mask
        j = whitened_design(both, jacobian(x, d, passing, both, at(x)))
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


def _on_datum(x: np.ndarray, d) -> np.ndarray:
    """``x`` with D_m scaled so that the calibrated field's mean magnitude is the datum F
    (``mag_datum`` met exactly) and its determinant positive; the compass conditions, the only
    others D_m enters, are unchanged by any scale of D_m, a negative one included — which would
    turn the calibrated field round (a sitl session beside a laptop ended at D_m ≈ −0.65·I
    before the sign was held). Unchanged without a compass.

    Fitted as a condition ~1000 times tighter than the data, the datum made the objective a
    narrow curved valley (its second-order change under a few per cent of soft iron alone
    costs thousands of σ²) along which the steps crept by about 1 σ per run.
    """
    if d.mag is None:
        return x
    mats = jm.matrices(x)
    scale = float(np.mean(np.linalg.norm(jm.correct_mag(d.mag, mats), axis=1)))
    out = x.copy()
    out[jm.SLICES["D_m"]] *= np.sign(np.linalg.det(mats["D_m"])) * scale / d.field
    return out


def _descend(fun, jac, x: np.ndarray, free: np.ndarray, f_now: float, d) -> float:
    """One pass's minimisation of |fun|² (the pass's whitened misclosures), in place on
    ``x[free]``; returns the objective reached.

    Each run is Levenberg-Marquardt on the design matrix of the point it starts from (chord
    steps: MINPACK re-evaluates the misclosures exactly at every trial point and keeps a step
    only when they decrease, :class:`_Compressed`); its end is kept only if the objective there
    is lower (checked here as well). A run that stopped at its evaluation budget, or ended
    more than ``RELINEARISE_SIGMA`` σ from where its design matrix was computed, is followed by
    another from the point reached, with the design matrix computed there; a run that finds no
    lower point ends the pass.
    """
    for _ in range(MAX_LINEARISATIONS):
        small = _Compressed(fun, jac(x[free]))
        res = least_squares(small, x[free], jac=small.jacobian, x_scale="jac",
                            method="lm", xtol=1e-8, ftol=1e-8, max_nfev=MAX_INNER)
        r = small.full(res.x)
        f_new = float(r @ r)
        if not f_new < f_now:
            break
        moved = float(np.max(np.abs(res.x - x[free]) / np.maximum(small.sigma, 1e-300)))
        x[free], f_now = res.x, f_new
        x[:] = _on_datum(x, d)
        if res.status > 0 and moved <= RELINEARISE_SIGMA:
            break
    return f_now


def _variance_components(white, a: dict, w: dict, weights: dict, factor: dict) -> None:
    """Re-estimate each family's variance factor and robust weights, in place.

    Variance components (Förstner 1979, as used with Gauss-Helmert adjustments), on each
    condition's residual standardised by its own white-noise covariance M_i·M_iᵀ (factor 1,
    weight 1): u_i = M_i⁻¹·w_i. With factor f and weight ω_i the model says cov(u_i) =
    (f²/ω_i)·I, and after the fit E[ω_i·|û_i|²] = f²·(dim − (ω_i/f²)·tr(P_i·Σ_x·P_iᵀ)),
    P_i = M_i⁻¹·A_i the condition's standardised design rows and Σ_x = (JᵀJ)⁻¹ of the
    whitened design matrix J; so f² = Σω_i·|u_i|² / Σ(dim − (ω_i/f²)·tr(P_i·Σ_x·P_iᵀ)), the
    redundancy of the family in the denominator (not its number of rows: a family that
    carries most of the information about some parameters, the levelling or ZUPT, keeps far
    smaller residuals than its noise).

    Why each condition's own covariance and not the rows of the whitened vector: the static
    norm, levelling and ZUPT share the still blocks' noise and are whitened together (one
    Cholesky factor), so a ZUPT row there is the part of its condition the static norms and
    levelling before it do not predict — and that prediction grows with the ZUPT's own factor.
    Estimated from those rows, the ZUPT factor fed on the other families' misfit and grew by
    the same ratio every pass (1.6× per pass, to 2590 on a sitl hand-held session whose ZUPT
    misclosures were 1.4 times their white noise). Standardised alone, a condition scales
    with its own factor and no other. Weights: Huber or Tukey (:func:`_robust_weights`) of
    each condition's standardised residual.

    Parameters
    ----------
    white : Whitener
        The pass's whitening (its weights and factors those in ``weights``, ``factor``).
    a : dict
        family → (n_c, dim, p) ∂w/∂X over the free parameters, at the point reached.
    w : dict
        family → (n_c, dim) misclosures there.
    weights, factor : dict
        Updated in place.
    """
    j = white.jacobian(a)
    cov_x = np.linalg.pinv(j.T @ j, hermitian=True)
    for k in white.family_rows(w):
        if k == "mag_datum":
            continue
        dim = w[k].shape[1]
        u = white.standardised(w, k)
        u2 = dim * u ** 2                                         # Σ over components of u²
        p = white.unit(k) @ a[k]                                  # P_i, (n_c, dim, p)
        lev = (np.sum((p.reshape(-1, p.shape[2]) @ cov_x).reshape(p.shape) * p, axis=(1, 2))
               * weights[k] / factor[k] ** 2)                     # tr(P_i·Σ_x·P_iᵀ)·ω/f²
        used = weights[k] > 1e-3
        redundancy = float(np.sum(dim - lev[used]))
        if redundancy > 1:
            # never below 1: a family cannot be quieter than the white noise of the still
            # periods; a smaller factor (a few dozen conditions, some parameters fitted mostly
            # by them) would only make the reported σ too small
            factor[k] = max(1.0, float(np.sqrt(np.sum(weights[k][used] * u2[used])
                                               / redundancy)))
        weights[k] = _robust_weights(u / factor[k], k)


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
        gyr_g_sensitivity_at_1g=float(np.linalg.norm(extra["gyr_g_sensitivity"], 2) * d.gravity),
        passes=int(fit.get("passes", 0)), converged=bool(fit.get("converged", True)),
        explained=dict(fit.get("explained", {})), clipped_turns=int(d.clipped))
    return Calibration(method="joint", sensors=cals, report=CalibrationReport(joint=joint))
