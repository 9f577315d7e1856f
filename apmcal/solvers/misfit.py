"""How far the six-face (Ferraris) accelerometer model misses its own redundant data.

The Ferraris accelerometer model ([Oppong] §4.1) says every still hold on face j with sign s
(s = +1 for "x_p", −1 for "x_a", …) reads, on sensor axis i::

    m_i = b_i + s · g · (K R)_ij

Six faces give 18 such equations for 12 unknowns (b: 3, K R: 9); the Ferraris estimator uses 12
of them exactly (b_i from the pair along axis i, (K R)_ij from the pair along axis j), so the
other 6 — each face pair's mean on the two axes across gravity, which must also equal b_i — and
every further hold in a known face (the pauses of the rotations, say) are free checks.

The checks see what the linear model leaves out: a quadratic scale error k2·g² shifts only the
along-gravity readings (so b_i from the axis-i pair is off by k2·g², the across pairs are not);
a temperature drift shifts each hold by c·ΔT of its own time; faces that are not square shift the
across-gravity readings by g·sin(tilt). None of that is in the white-noise σ of the hold means
(std/√n), which is why on the bundled sample the accelerometer x offset came out 0.3176 ± 0.0004
m/s² against a truth of 0.365.

The misfit is turned into a σ as a random effect (the method of moments of DerSimonian & Laird,
as for a meta-analysis of studies that disagree beyond their stated errors): each hold mean on
axis i is taken to scatter about the model by an extra τ_i, the same for every hold, independent
between holds. With r = P·y the residuals of the axis-i readings y of all holds (P = I − H, H
the linear map from the readings to the model's prediction through the Ferraris estimator) and V
the holds' noise variances::

    E[rᵀr] = tr(P V Pᵀ) + τ_i² · tr(P Pᵀ)   ⇒   τ_i² = max(0, (rᵀr − tr(P V Pᵀ)) / tr(P Pᵀ))

and the Ferraris σ is then propagated from hold-mean variances V + τ_i² instead of V. τ is a
floor on honesty, not a model of the effect: it widens σ to the scatter the data show, and the
Birge ratio sqrt(χ²/dof) of the checks (1 when the model fits) says how badly it fits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

AXES = "xyz"
PAIR = {"x": ("x_p", "x_a"), "y": ("y_p", "y_a"), "z": ("z_p", "z_a")}
# Holds further than this from a face are not checks of the face model: a 10° tilt moves the
# across-gravity readings by 1.7 m/s², which is the hold's fault, not the sensor model's.
# pipeline.FERRARIS_MAX_TILT_DEG is the same limit for choosing the method.
CHECK_MAX_TILT_DEG = 10.0


@dataclass
class HoldMisfit:
    """The Ferraris accelerometer model against its redundant holds.

    Attributes
    ----------
    tau : (3,) array, m/s² (input units)
        Extra scatter of one hold mean per sensor axis beyond its noise: from the repeated holds
        of a face when the session has any (temperature drift, faces not put back square),
        else from every check (0 when none is seen).
    offset_spread : (3,) array, m/s²
        RMS distance, beyond noise, of the other estimates of each offset b_i (one per check on
        axis i) from the fitted one: a quadratic scale error, seen only along gravity, shows here.
    chi2 : float
        Σ r²/var(r) over the checks, with var(r) from the holds' noise alone (dimensionless).
    dof : int
        Number of independent checks (18 − 12 for six holds, + 3 per further hold).
    n_holds : int
        Holds used: the six of the fit and every further hold within CHECK_MAX_TILT_DEG of a face.
    worst : float
        Largest |residual| of a check [m/s²], the most visible sign of the misfit.
    """

    tau: np.ndarray
    offset_spread: np.ndarray
    chi2: float
    dof: int
    n_holds: int
    worst: float

    @property
    def birge_ratio(self) -> float:
        """sqrt(χ²/dof): 1 when the holds agree with the model to within their noise."""
        return float(np.sqrt(self.chi2 / self.dof)) if self.dof > 0 else float("nan")

    def to_dict(self) -> dict:
        """The fields and the Birge ratio as a dict (arrays kept as numpy)."""
        return {"tau": self.tau, "offset_spread": self.offset_spread, "chi2": self.chi2,
                "dof": self.dof, "n_holds": self.n_holds, "birge_ratio": self.birge_ratio,
                "worst_residual": self.worst}


def check_holds(poses: dict, segments) -> list:
    """The six holds the fit uses, then every other hold near a face (each once).

    Parameters
    ----------
    poses : dict
        pose ("x_p" … "z_a") → StaticSegment.
    segments : list of StaticSegment or None
        Every hold of the session.

    Returns
    -------
    list of StaticSegment
        x_p, x_a, y_p, y_a, z_p, z_a, then the further checks.
    """
    used = [poses[p] for a in AXES for p in PAIR[a]]
    ids = {id(s) for s in used}
    extra = [s for s in (segments or []) if id(s) not in ids and s.pose is not None
             and s.tilt_deg <= CHECK_MAX_TILT_DEG]
    return used + extra


def axis_map(holds: list, axis: int) -> np.ndarray:
    """H (n, n) for sensor axis ``axis``: the model's prediction of every hold's reading on it.

    Holds 0..5 are x_p, x_a, y_p, y_a, z_p, z_a as the fit used them. A hold on face j with sign
    s is predicted as b_i + s·g·(K R)_ij = (y_ip + y_ia)/2 + s·(y_jp − y_ja)/2, with i = ``axis``
    and y the readings on that axis: linear in the readings, hence a matrix.

    Parameters
    ----------
    holds : list of StaticSegment
        From :func:`check_holds` (n of them).
    axis : int
        Sensor axis, 0..2.

    Returns
    -------
    (n, n) array
    """
    n = len(holds)
    h = np.zeros((n, n))
    bi = 2 * axis                     # x_p, x_a of this axis sit at 2·axis, 2·axis + 1
    for k, seg in enumerate(holds):
        j = AXES.index(seg.pose[0])
        s = 1.0 if seg.pose.endswith("_p") else -1.0
        h[k, bi] += 0.5
        h[k, bi + 1] += 0.5
        h[k, 2 * j] += 0.5 * s
        h[k, 2 * j + 1] -= 0.5 * s
    return h


def _excess(sq: np.ndarray, noise: np.ndarray) -> float:
    """sqrt(max(0, mean(sq − noise))): the part of a mean square its noise does not explain."""
    return float(np.sqrt(max(0.0, float(np.mean(sq - noise))))) if sq.size else 0.0


def repeat_scatter(holds: list, var: np.ndarray) -> np.ndarray | None:
    """τ per axis from holds repeating a fitted face (None when no face was held twice).

    A repeat h of the fitted hold u differs from it by d = y_h − y_u; with an extra scatter τ
    per hold, E[d²] = var_h + var_u + 2τ².

    Parameters
    ----------
    holds : list of StaticSegment
        From :func:`check_holds` (n of them).
    var : (n, 3) array
        Noise variance of each hold mean [(m/s²)²].

    Returns
    -------
    (3,) array or None
        τ [m/s²].
    """
    used = {seg.pose: k for k, seg in enumerate(holds[:6])}
    pairs = [(k, used[seg.pose]) for k, seg in enumerate(holds[6:], start=6)]
    if not pairs:
        return None
    y = np.array([s.acc_mean for s in holds])
    d2 = np.array([(y[k] - y[u]) ** 2 for k, u in pairs])
    nv = np.array([var[k] + var[u] for k, u in pairs])
    return np.array([_excess(d2[:, i], nv[:, i]) for i in range(3)]) / np.sqrt(2.0)


def hold_misfit(poses: dict, segments=None) -> HoldMisfit:
    """Residuals of the Ferraris accelerometer model on its redundant holds.

    Parameters
    ----------
    poses : dict pose -> StaticSegment
        The six holds the fit used ("x_p" … "z_a").
    segments : list of StaticSegment, optional
        Every hold of the session; those near a face besides the six are further checks.

    Returns
    -------
    HoldMisfit
    """
    holds = check_holds(poses, segments)
    y = np.array([s.acc_mean for s in holds])                       # (n, 3) readings
    var = np.array([s.acc_std ** 2 / max(s.n, 1) for s in holds])   # noise of each mean
    tau, spread, fits = np.zeros(3), np.zeros(3), np.ones(3, bool)
    chi2, dof, worst = 0.0, 0, 0.0
    for i in range(3):
        p = np.eye(len(holds)) - axis_map(holds, i)
        r = p @ y[:, i]
        noise = p @ np.diag(var[:, i]) @ p.T
        ppt = p @ p.T
        checks = np.diag(ppt) > 1e-12            # the fitted pair's own rows are exact
        tr_pp = float(np.trace(ppt))
        if tr_pp <= 1e-12:
            continue
        tau[i] = np.sqrt(max(0.0, (r @ r - np.trace(noise)) / tr_pp))
        spread[i] = _excess(r[checks] ** 2, np.diag(noise)[checks])
        # χ² with the residuals' own noise covariance (rank-deficient: pseudo-inverse)
        chi2_i = float(r @ np.linalg.pinv(noise, rcond=1e-10, hermitian=True) @ r)
        dof_i = int(np.linalg.matrix_rank(p))
        fits[i] = model_fits(chi2_i, dof_i)
        chi2, dof = chi2 + chi2_i, dof + dof_i
        worst = max(worst, float(np.abs(r).max()))
    repeats = repeat_scatter(holds, var)
    tau = tau if repeats is None else repeats
    # the PDG's rule for a scale factor: no widening where the checks agree within their noise
    # (else the moment estimates' own noise would inflate σ on a clean session by up to 3×)
    return HoldMisfit(tau=np.where(fits, 0.0, tau), offset_spread=np.where(fits, 0.0, spread),
                      chi2=chi2, dof=dof, n_holds=len(holds), worst=worst)


FIT_P_VALUE = 0.01     # χ² beyond its 99th percentile: the checks disagree beyond their noise


def model_fits(chi2: float, dof: int) -> bool:
    """True when χ² on ``dof`` checks is within what noise alone gives 99 % of the time.

    Parameters
    ----------
    chi2 : float
    dof : int

    Returns
    -------
    bool
        Also True when ``dof`` ≤ 0 (nothing to check).
    """
    return dof <= 0 or chi2_survival(chi2, dof) >= FIT_P_VALUE


def chi2_survival(x: float, dof: int) -> float:
    """P(χ²_dof ≥ x) for a whole number of degrees of freedom, in closed form (Abramowitz &
    Stegun 26.4.4 for even, 26.4.5 for odd ``dof``): finite sums, equal to scipy.stats.chi2.sf
    to rounding, without loading scipy.stats (1 s of a 2 s `apmcal log`).

    Parameters
    ----------
    x : float
        χ² value (negative counts as 0).
    dof : int
        Degrees of freedom, ≥ 1.

    Returns
    -------
    float
        The probability, 0..1.
    """
    half = 0.5 * max(float(x), 0.0)
    if dof % 2 == 0:
        terms = [j * math.log(half) - math.lgamma(j + 1) for j in range(dof // 2)] \
            if half > 0 else [0.0]
        return min(1.0, math.exp(-half) * sum(math.exp(t) for t in terms))
    tail = math.erfc(math.sqrt(half))
    if half > 0:
        tail += math.exp(-half) * sum(math.exp((j - 0.5) * math.log(half) - math.lgamma(j + 0.5))
                                      for j in range(1, (dof - 1) // 2 + 1))
    return min(1.0, tail)
