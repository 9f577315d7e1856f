"""Fit ArduPilot's compass correction to a flight without trusting the logged heading.

The firmware's correction (ardupilot-facts.md, "How the firmware applies the parameters", 4.x
``correct_field``), body frame FRD, mGauss::

    B = M · (raw + OFS) + MOT · x            M = SCALE·[[DIA_X, ODI_X, ODI_Y], ...] symmetric

with ``raw`` the uncorrected body-frame field and ``x`` the battery current [A] (COMPASS_MOTCT 2)
or the throttle 0..1 (MOTCT 1). The field that should come out is the Earth's, ``B =
R_nbᵀ·B_ned`` with R_nb the attitude. The EKF's yaw in the log was made with the very compass
being fitted, so the fit uses only what does not depend on it: with R_lev = Ry(pitch)·Rx(roll)
(the logged roll and pitch; the accelerometers fix them, not the compass) the levelled field
v = R_lev·B must have, whatever the heading,

    v_z = F·sin(I)              and          |(v_x, v_y)| = F·cos(I),

two residuals per sample [mGauss], F the field's intensity and I its inclination. Heading turns
carry the hard and soft iron, tilts the vertical axis, changes of ``x`` the motor term. A
rotation of the field about the vertical would not change these residuals, but M is symmetric
and positive (bounded here like ArduPilot's own limits), so it cannot absorb one; a mount
rotated by a whole ArduPilot rotation is looked for separately (:func:`orientation_scores`).

**The local field is fitted too.** F and I are unknowns with the field model's values as a
prior of stated width (:class:`FieldPrior`; the WMM's own error model). F is never determined by
a flight: scaling M, MOT and F together leaves every residual unchanged, so F keeps its prior
and its σ reaches every DIA/ODI/MOT σ as a common scale. I is determined where the vehicle tilts
while it faces several headings (the tilted body axis then sees the horizontal field turn with
the heading); level flight leaves it to the prior, and its σ reaches OFS_Z and DIA_Z. Held
fixed at the model's values instead, a field a few mGauss off (ArduPilot's SITL, a crustal
anomaly) pushes its error into COMPASS_OFS_Z and DIA_Z as if it were known exactly.

**σ.** The samples are not independent (10 Hz compass samples, attitude errors and unmodelled
interference that last seconds), so σ is a sandwich: the bread the Gauss-Newton information
JᵀJ/s² (plus the prior's), the meat the variance of the summed per-sample scores gᵢ = Jᵢᵀ·rᵢ
estimated by overlapping batch means over batches of ⌊√n⌋ consecutive samples ([FlegalJones]
§2: the overlapping batch means estimator of the long-run variance, a Bartlett lag window; the
batch size of their recommendation), plus the prior's information. With white residuals it
reduces to s²·(JᵀJ)⁻¹. The prior is weighed against the data with the residual variance
inflated by the same long-run factor, so correlated samples do not outvote it. Samples whose
residual exceeds 5 robust σ are dropped once and the fit repeated.

**Identification** (:func:`select_free`): parameters whose σ would exceed a limit are held
fixed, worst first in a stated order (e.g. soft iron before offsets), each time the others' σ
re-evaluated with it held (the same sandwich restricted to the rest), until every free
parameter is within its limit.

Solver: Levenberg-Marquardt ([Marquardt]) with the analytic Jacobian (:func:`_solve` says why
not scipy's), bounds DIA 0.5..2, ODI ±0.5, OFS ±2000 mGauss, MOT ±1000 per unit.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PARAMS = ("OFS_X", "OFS_Y", "OFS_Z", "DIA_X", "DIA_Y", "DIA_Z", "ODI_X", "ODI_Y", "ODI_Z",
          "MOT_X", "MOT_Y", "MOT_Z")
FIELD_PARAMS = ("FIELD_MGAUSS", "INCLINATION_RAD")
ALL_PARAMS = PARAMS + FIELD_PARAMS
N_PARAMS = len(ALL_PARAMS)
FIELD = slice(12, 14)
_LOWER = np.array([-2000.0] * 3 + [0.5] * 3 + [-0.5] * 3 + [-1000.0] * 3 + [1.0, -np.pi / 2])
_UPPER = np.array([2000.0] * 3 + [2.0] * 3 + [0.5] * 3 + [1000.0] * 3 + [2000.0, np.pi / 2])
OUTLIER_SIGMAS = 5.0
# the cost is in units of the residuals' variance: a step that lowers it less than this moves
# the parameters by a thousandth of their σ or less, along the weakest direction included
CONVERGED_CHI2 = 1e-6


@dataclass(frozen=True)
class FieldPrior:
    """The Earth field the fit expects and how well it is known: intensity [mGauss] and
    inclination [rad, positive down] with their one-σ (the field model's own uncertainty)."""

    intensity_mgauss: float
    inclination_rad: float
    sigma_intensity_mgauss: float
    sigma_inclination_rad: float

    @classmethod
    def from_ned(cls, field_ned, sigma_intensity_mgauss: float,
                 sigma_inclination_rad: float) -> "FieldPrior":
        """From a field vector [mGauss, NED] and its σ."""
        b = np.asarray(field_ned, float)
        return cls(float(np.linalg.norm(b)), float(np.arctan2(b[2], np.hypot(b[0], b[1]))),
                   float(sigma_intensity_mgauss), float(sigma_inclination_rad))

    @property
    def mean(self) -> np.ndarray:
        """(F, I) [mGauss, rad]."""
        return np.array([self.intensity_mgauss, self.inclination_rad])

    @property
    def information(self) -> np.ndarray:
        """diag(1/σ²) of (F, I)."""
        return np.diag([self.sigma_intensity_mgauss ** -2.0, self.sigma_inclination_rad ** -2.0])


@dataclass(frozen=True)
class AttitudeUncertainty:
    """How well the roll and pitch the fit levels with are known [rad]: a level error constant
    over the flight, and one that changes from block to block of ``block_s`` seconds."""

    level_rad: float
    varying_rad: float
    block_s: float


# ArduPilot's EKF roll and pitch against the simulator's true attitude on ArduPilot SITL
# flights (benchmarks/flight_compass_coverage.py, docs/flight-compass.md): flight means of
# 0.05-0.18° in roll on square missions (the largest with the gyro drifting), 0.04° or less on
# calibration flights and rovers, 10 s means that scatter by 0.01-0.09° about them. The σ of
# the flight mean covers the largest within 1.2σ: which kind of flight a log is, and how its
# EKF fared, is not known here; a real vehicle's attitude is known no better
ATTITUDE = AttitudeUncertainty(np.radians(0.15), np.radians(0.07), 10.0)


@dataclass
class FlightFit:
    """Result of :func:`fit_flight`: parameter vector (``ALL_PARAMS`` order; M includes any
    COMPASS_SCALE; then F [mGauss] and I [rad]), its covariance, the residual rms [mGauss],
    samples used, the long-run variance factor of the scores (1 for independent samples),
    indices held fixed, and the sandwich's bread and meat (for :meth:`conditional_sigma`)."""

    x: np.ndarray
    cov: np.ndarray
    rms: float
    n_used: int
    correlation_factor: float
    fixed: tuple[int, ...] = ()
    bread: np.ndarray = field(default_factory=lambda: np.zeros((N_PARAMS, N_PARAMS)))
    meat: np.ndarray = field(default_factory=lambda: np.zeros((N_PARAMS, N_PARAMS)))

    @property
    def at_limits(self) -> bool:
        """True when a DIA/ODI entry sits on its bound (no soft-iron matrix within limits fits)."""
        return bool(np.any(np.isclose(self.x[3:9], _LOWER[3:9], atol=1e-3)
                           | np.isclose(self.x[3:9], _UPPER[3:9], atol=1e-3)))

    @property
    def sigma(self) -> np.ndarray:
        """One-σ of each parameter (0 for fixed ones)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def free(self) -> np.ndarray:
        """Boolean mask of the fitted parameters."""
        m = np.ones(N_PARAMS, bool)
        m[list(self.fixed)] = False
        return m

    def conditional_sigma(self, also_fixed=()) -> np.ndarray:
        """σ of each parameter had ``also_fixed`` (indices) been held too, from the same
        sandwich restricted to the remaining ones (0 for held parameters)."""
        keep = self.free.copy()
        keep[list(also_fixed)] = False
        out = np.zeros(N_PARAMS)
        if keep.any():
            a_inv = np.linalg.pinv(self.bread[np.ix_(keep, keep)])
            cov = a_inv @ self.meat[np.ix_(keep, keep)] @ a_inv
            out[keep] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        return out

    def matrix(self) -> np.ndarray:
        """M (3, 3)."""
        return soft_iron(self.x)

    def value(self, name: str) -> float:
        """One parameter by its ``ALL_PARAMS`` name."""
        return float(self.x[ALL_PARAMS.index(name)])


def soft_iron(x: np.ndarray) -> np.ndarray:
    """M from the DIA and ODI entries of a parameter vector."""
    d, o = x[3:6], x[6:9]
    return np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]])


def levelling(roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """(n, 3, 3) R_lev = Ry(pitch)·Rx(roll): body vectors into the frame that has the body's
    heading but is level (NED turned by the yaw) [angles in rad]."""
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    z = np.zeros_like(roll)
    return np.stack([np.stack([cp, sp * sr, sp * cr], -1),
                     np.stack([z, cr, -sr], -1),
                     np.stack([-sp, cp * sr, cp * cr], -1)], axis=-2)


def corrected(x: np.ndarray, raw: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """B = M·(raw + OFS) + MOT·x for every sample (n, 3) [mGauss]."""
    return (raw + x[0:3]) @ soft_iron(x).T + np.outer(drive, x[9:12])


def _parts(x, raw, drive, lev):
    """Levelled field v (n, 3), horizontal magnitude h, and the rows c_z, c_h (n, 3) that carry
    a raw-noise vector into the vertical and horizontal-magnitude residuals before M."""
    v = np.einsum("nij,nj->ni", lev, corrected(x, raw, drive))
    h = np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-9)
    c_z = lev[:, 2, :]
    c_h = (v[:, 0:1] * lev[:, 0, :] + v[:, 1:2] * lev[:, 1, :]) / h[:, None]
    return v, h, c_z, c_h


def _residuals(x, raw, drive, lev):
    """Vertical then horizontal-magnitude residuals against the field (F, I) of ``x``, each
    divided by the norm of the map from raw-sensor noise to it (|c·M|): gradient weighting.
    Without it the fit shrinks M along directions where the raw field barely varies (the
    vertical axis in level flight: the noise M·n is then most of what M scales), biasing DIA_Z
    by σ²/var(raw_z), 0.7 % on a short flight; with it each residual is in mGauss of raw noise
    and the bias is gone to first order."""
    v, h, c_z, c_h = _parts(x, raw, drive, lev)
    m = soft_iron(x)
    w_z = np.linalg.norm(c_z @ m, axis=1)
    w_h = np.linalg.norm(c_h @ m, axis=1)
    f, inc = x[12], x[13]
    return np.concatenate([(v[:, 2] - f * np.sin(inc)) / w_z, (h - f * np.cos(inc)) / w_h])


def _dweight(c, m):
    """|c·M| (n,) and its derivative (n, 14) with respect to the parameters (DIA, ODI only)."""
    a = c @ m
    w = np.linalg.norm(a, axis=1)
    da = np.zeros((len(c), 3, N_PARAMS))
    for k in range(3):
        da[:, k, 3 + k] = c[:, k]
    for j, (p, q) in enumerate(((0, 1), (0, 2), (1, 2))):
        da[:, p, 6 + j] = c[:, q]
        da[:, q, 6 + j] = c[:, p]
    return w, np.einsum("nk,nkp->np", a, da) / w[:, None]


def _jacobian(x, raw, drive, lev, free):
    n = len(raw)
    y = raw + x[0:3]
    v, h, c_z, c_h = _parts(x, raw, drive, lev)
    m = soft_iron(x)
    # dB/dθ (n, 3, 14)
    db = np.zeros((n, 3, N_PARAMS))
    db[:, :, 0:3] = m[None, :, :]
    for k in range(3):
        db[:, k, 3 + k] = y[:, k]
    for j, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
        db[:, a, 6 + j] = y[:, b]
        db[:, b, 6 + j] = y[:, a]
    for k in range(3):
        db[:, k, 9 + k] = drive
    dv = np.einsum("nij,njp->nip", lev, db)
    jz = dv[:, 2, :]
    jh = (v[:, 0:1] * dv[:, 0, :] + v[:, 1:2] * dv[:, 1, :]) / h[:, None]
    f, inc = x[12], x[13]
    jz[:, 12], jz[:, 13] = -np.sin(inc), -f * np.cos(inc)
    jh[:, 12], jh[:, 13] = -np.cos(inc), f * np.sin(inc)
    w_z, dw_z = _dweight(c_z, m)
    w_h, dw_h = _dweight(c_h, m)
    r_z, r_h = v[:, 2] - f * np.sin(inc), h - f * np.cos(inc)
    jz = jz / w_z[:, None] - (r_z / w_z ** 2)[:, None] * dw_z
    jh = jh / w_h[:, None] - (r_h / w_h ** 2)[:, None] * dw_h
    return np.concatenate([jz, jh])[:, free]


def initial_guess(raw: np.ndarray, lev: np.ndarray, prior: FieldPrior) -> np.ndarray:
    """Start values: a circle through the levelled horizontal field (Kåsa's linear fit) for
    OFS_X/Y and the horizontal scale, the mean vertical misfit for OFS_Z; no cross terms, no
    motor term; the field at its prior."""
    f0, i0 = prior.mean
    b_h, b_d = f0 * np.cos(i0), f0 * np.sin(i0)
    v = np.einsum("nij,nj->ni", lev, raw)
    a = np.column_stack([v[:, 0], v[:, 1], np.ones(len(v))])
    sol, *_ = np.linalg.lstsq(a, v[:, 0] ** 2 + v[:, 1] ** 2, rcond=None)
    cx, cy = sol[0] / 2, sol[1] / 2
    radius = np.sqrt(max(sol[2] + cx ** 2 + cy ** 2, 1.0))
    x = np.zeros(N_PARAMS)
    x[0:2] = -cx, -cy
    scale = float(np.clip(b_h / radius, 0.6, 1.6))
    x[3:6] = scale
    x[2] = float(np.mean(b_d / scale - v[:, 2]))
    x[12:14] = f0, i0
    return x


def fit_flight(raw: np.ndarray, roll: np.ndarray, pitch: np.ndarray, drive: np.ndarray,
               prior: FieldPrior, *, fixed: dict[int, float] | None = None,
               x0: np.ndarray | None = None, quick: bool = False,
               t: np.ndarray | None = None,
               attitude: AttitudeUncertainty | None = None) -> FlightFit:
    """Fit OFS, DIA, ODI (M includes SCALE), MOT and the local field to one compass's samples.

    Parameters
    ----------
    raw : (n, 3) uncorrected body-frame field [mGauss] (calibration in force undone), in time
        order (the σ treats neighbours as correlated).
    roll, pitch : (n,) attitude [rad] at the instants the compass samples stand for.
    drive : (n,) current [A] or throttle 0..1 (zeros when there is none).
    prior : the field model's intensity and inclination with their σ.
    fixed : parameter index (``ALL_PARAMS``) → value held instead of fitted.
    x0 : optional start vector (``ALL_PARAMS`` order).
    quick : one pass without outlier rejection, at most 30 iterations and no covariance (for
        scoring rotations).
    t : (n,) sample times [s] (for the attitude error's blocks); 10 Hz assumed when None.
    attitude : the uncertainty of the roll and pitch the fit levels with (default
        :data:`ATTITUDE`); its effect on the parameters is added to their covariance.

    Returns
    -------
    FlightFit
    """
    lev = levelling(roll, pitch)
    x = initial_guess(raw, lev, prior) if x0 is None else np.array(x0, float)
    fixed = dict(fixed or {})
    for k, v in fixed.items():
        x[k] = v
    free = np.ones(N_PARAMS, bool)
    free[list(fixed)] = False
    keep = np.ones(len(raw), bool)
    s_eff = _robust_scale(_residuals(x, raw, drive, lev))
    factor = 1.0
    for _ in range(1 if quick else 2):
        args = (raw[keep], drive[keep], lev[keep])
        x = _solve(x, free, args, prior, s_eff, 30 if quick else 200)
        if quick:
            break
        r = _residuals(x, raw, drive, lev).reshape(2, -1)
        scale = _robust_scale(r[:, keep].ravel())
        new_keep = np.all(np.abs(r) <= OUTLIER_SIGMAS * max(scale, 1e-6), axis=0)
        if new_keep.sum() >= 20:
            keep = new_keep
        args = (raw[keep], drive[keep], lev[keep])
        r = _residuals(x, *args)
        j = _jacobian(x, *args, free)
        s2 = float(r @ r) / max(len(r) - int(free.sum()), 1)
        factor = _long_run_factor(j, r, s2)
        s_eff = np.sqrt(s2 * factor)
    args = (raw[keep], drive[keep], lev[keep])
    r = _residuals(x, *args)
    rms = float(np.sqrt(np.mean(r ** 2)))
    if quick:
        return FlightFit(x, np.zeros((N_PARAMS, N_PARAMS)), rms, int(keep.sum()), 1.0,
                         tuple(sorted(fixed)))
    j = _jacobian(x, *args, free)
    s2 = float(r @ r) / max(len(r) - int(free.sum()), 1)
    se2 = s2 * factor
    p_info = _prior_information(prior, free)
    bread_f = j.T @ j / se2 + p_info
    meat_f = _score_variance(j, r) / se2 ** 2 + p_info
    if attitude is None:
        attitude = ATTITUDE
    times = (np.arange(len(raw)) * 0.1 if t is None else np.asarray(t, float))[keep]
    meat_f = meat_f + _attitude_meat(x, args, roll[keep], pitch[keep], j, times, attitude) / se2 ** 2
    a_inv = np.linalg.pinv(bread_f)
    bread, meat, cov = (np.zeros((N_PARAMS, N_PARAMS)) for _ in range(3))
    bread[np.ix_(free, free)] = bread_f
    meat[np.ix_(free, free)] = meat_f
    cov[np.ix_(free, free)] = a_inv @ meat_f @ a_inv
    return FlightFit(x, cov, rms, int(keep.sum()), factor, tuple(sorted(fixed)), bread, meat)


def _attitude_meat(x, args, roll, pitch, j, t, attitude: "AttitudeUncertainty") -> np.ndarray:
    """Var(Jᵀ·δr) of the residual changes δr that roll and pitch errors cause: a level error
    constant over the flight (σ ``attitude.level_rad``) and one constant within blocks of
    ``attitude.block_s`` but independent between them (σ ``attitude.varying_rad``), each
    axis apart. With the bread A: the parameters move by A⁻¹·Jᵀ·δr / s² for such an error."""
    raw, drive, _ = args
    base = _residuals(x, raw, drive, levelling(roll, pitch))
    n = len(raw)
    block = np.floor((t - t[0]) / attitude.block_s).astype(int)
    out = np.zeros((j.shape[1], j.shape[1]))
    eps = 1e-5
    for d_roll, d_pitch in ((eps, 0.0), (0.0, eps)):
        dr = (_residuals(x, raw, drive, levelling(roll + d_roll, pitch + d_pitch)) - base) / eps
        u = j[:n] * dr[:n, None] + j[n:] * dr[n:, None]          # per sample, per parameter
        total = u.sum(axis=0)
        out += attitude.level_rad ** 2 * np.outer(total, total)
        sums = np.zeros((block.max() + 1, u.shape[1]))
        np.add.at(sums, block, u)
        out += attitude.varying_rad ** 2 * sums.T @ sums
    return out


def _robust_scale(r: np.ndarray) -> float:
    """1.4826 × median absolute deviation (the σ of Gaussian residuals), at least 1e-6."""
    return max(1.4826 * float(np.median(np.abs(r - np.median(r)))), 1e-6)


def _prior_information(prior: FieldPrior, free: np.ndarray) -> np.ndarray:
    """The prior's information on the free parameters (zero outside F and I)."""
    info = np.zeros((N_PARAMS, N_PARAMS))
    info[FIELD, FIELD] = prior.information
    return info[np.ix_(free, free)]


def _scores(j: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Per-sample scores gᵢ = J_zᵢᵀ·r_zᵢ + J_hᵢᵀ·r_hᵢ (n, p), centred."""
    n = len(r) // 2
    g = j[:n] * r[:n, None] + j[n:] * r[n:, None]
    return g - g.mean(axis=0)


def _score_variance(j: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Var(Σ gᵢ) by overlapping batch means ([FlegalJones] §2) over batches of ⌊√n⌋
    consecutive samples: n / (b (n − b + 1)) · Σₖ Bₖ·Bₖᵀ with Bₖ the sum of batch k."""
    g = _scores(j, r)
    n = len(g)
    b = max(1, int(np.sqrt(n)))
    c = np.concatenate([np.zeros((1, g.shape[1])), np.cumsum(g, axis=0)])
    sums = c[b:] - c[:-b]
    return sums.T @ sums * (n / (b * (n - b + 1)))


def _long_run_factor(j: np.ndarray, r: np.ndarray, s2: float) -> float:
    """How many times the summed scores vary more than independent samples would make them
    (the median over parameters of Var(Σg)ⱼⱼ / (s²·JᵀJ)ⱼⱼ), at least 1."""
    white = s2 * np.einsum("ij,ij->j", j, j)
    ok = white > 0
    if not ok.any():
        return 1.0
    ratio = np.diag(_score_variance(j, r))[ok] / white[ok]
    return float(max(1.0, np.median(ratio)))


def _solve(x, free, args, prior: FieldPrior, s_eff: float, max_iter: int = 200) -> np.ndarray:
    """Levenberg-Marquardt ([Marquardt]) on the normal equations of the data residuals over
    ``s_eff`` and the field prior's, bounds by clipping.

    Hand-written rather than scipy's least_squares: its trust-region step takes an SVD of the
    whole (2n × 14) Jacobian at every iteration (~90 ms for 3000 samples, the orientation search
    runs 40 fits), and its default tolerances stop before the weakly determined vertical-axis
    direction (DIA_Z against OFS_Z) has converged. Here each step costs one JᵀJ.
    """
    lo, hi = _LOWER[free], _UPPER[free]
    full = x.copy()
    full[free] = np.clip(full[free], lo, hi)
    p_info = _prior_information(prior, free)
    mean = np.zeros(N_PARAMS)
    mean[FIELD] = prior.mean
    mean = mean[free]

    def cost_of(vec, r):
        d = vec[free] - mean
        return float(r @ r) / s_eff ** 2 + float(d @ p_info @ d)

    r = _residuals(full, *args)
    cost = cost_of(full, r)
    lam = 1e-3
    for _ in range(max_iter):
        j = _jacobian(full, *args, free)
        p = full[free]
        h = j.T @ j / s_eff ** 2 + p_info
        g = j.T @ r / s_eff ** 2 + p_info @ (p - mean)
        d = np.diag(h).copy()
        d[d <= 0] = 1.0
        # active set: a parameter on its bound whose descent direction leaves the box stays put
        move = ~(((p <= lo) & (g > 0)) | ((p >= hi) & (g < 0)))
        hm, gm, dm = h[np.ix_(move, move)], g[move], d[move]
        improved = done = False
        for _ in range(20):
            try:
                step = np.zeros(len(p))
                step[move] = np.linalg.solve(hm + lam * np.diag(dm), -gm)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = full.copy()
            trial[free] = np.clip(p + step, lo, hi)
            r_new = _residuals(trial, *args)
            c_new = cost_of(trial, r_new)
            if c_new <= cost:
                improved = True
                done = cost - c_new <= CONVERGED_CHI2
                full, r, cost = trial, r_new, c_new
                lam = max(lam / 5, 1e-12)
                break
            lam *= 5
        if not improved or done:
            break
    return full


def select_free(fit: FlightFit, limits: np.ndarray, order: list[list[int]],
                reference: np.ndarray | None = None, rule_out: float = 3.0) -> list[int]:
    """The parameters to hold so that every other one is identified: σ within ``limits``
    (one per ``ALL_PARAMS`` entry; inf for no limit).

    ``order`` lists groups of indices, held first to last: within the first group that still
    has a parameter over its limit, the one furthest over (σ / limit) is held, the σ of the
    rest re-evaluated with it held (:meth:`FlightFit.conditional_sigma`), and so on until none
    is over. With ``reference`` (the values a held parameter would keep), a parameter whose
    reference value lies more than ``rule_out`` σ from the fitted one is never held: the flight
    rules that value out, so it stays fitted, weakly determined. Returns the indices to hold,
    in the order chosen.
    """
    held: list[int] = []
    while True:
        sig = fit.conditional_sigma(held)
        over = sig / limits
        over[list(fit.fixed) + held] = 0.0
        if reference is not None:
            ruled_out = np.abs(fit.x - reference) > rule_out * np.maximum(sig, 1e-300)
            over[ruled_out] = 0.0
        if not np.any(over > 1.0):
            return held
        for group in order:
            cand = [k for k in group if over[k] > 1.0]
            if cand:
                held.append(max(cand, key=lambda k: over[k]))
                break
        else:
            return held


def orientation_scores(raw_sensor: np.ndarray, rotations: dict[int, np.ndarray],
                       roll: np.ndarray, pitch: np.ndarray, drive: np.ndarray,
                       prior: FieldPrior, fixed: dict[int, float]) -> dict[int, float]:
    """Residual rms [mGauss] of the fit with each candidate rotation (code → R, v_body = R·v)
    applied to the sensor-frame samples; inf where the fit hits its bounds (a mount that only a
    negative or degenerate soft-iron matrix could undo)."""
    out = {}
    for code, rot in rotations.items():
        raw = raw_sensor @ rot.T
        fit = fit_flight(raw, roll, pitch, drive, prior, fixed=fixed, quick=True)
        out[code] = float("inf") if fit.at_limits else fit.rms
    return out
