"""Fit ArduPilot's compass correction to a flight without trusting the logged heading.

The firmware's correction (ardupilot-facts.md, "How the firmware applies the parameters", 4.x
``correct_field``), body frame FRD, mGauss::

    B = M · (raw + OFS) + MOT · x            M = SCALE·[[DIA_X, ODI_X, ODI_Y], ...] symmetric

with ``raw`` the uncorrected body-frame field and ``x`` the battery current [A] (COMPASS_MOTCT 2)
or the throttle 0..1 (MOTCT 1). The field that should come out is the World Magnetic Model's,
``B = R_nbᵀ·B_ned`` with R_nb the attitude. The EKF's yaw in the log was made with the very
compass being fitted, so the fit uses only what does not depend on it: with R_lev = Ry(pitch)·
Rx(roll) (the logged roll and pitch; the accelerometers fix them, not the compass) the levelled
field v = R_lev·B must have, whatever the heading,

    v_z = B_down                and          |(v_x, v_y)| = B_horizontal,

two residuals per sample [mGauss]. Heading turns then carry the hard and soft iron, tilts the
vertical axis, and changes of ``x`` the motor term. A rotation of the field about the vertical
would not change these residuals, but M is symmetric and positive (bounded here like
ArduPilot's own limits), so it cannot absorb one; a mount rotated by a whole ArduPilot rotation
is looked for separately (:func:`orientation_scores`).

σ: from the Gauss-Newton covariance s²·(JᵀJ)⁻¹ with s² the residual variance, inflated by the
AR(1) factor (1+ρ)/(1−ρ) of the residuals' lag-one correlation ρ (real flights' residuals are
correlated in time; a white simulation gives ρ ≈ 0). Samples whose residual exceeds 5 robust σ
are dropped once and the fit repeated.

Solver: Levenberg-Marquardt with the analytic Jacobian (:func:`_solve` says why not scipy's),
bounds DIA 0.5..2, ODI ±0.5, OFS ±2000 mGauss, MOT ±1000 per unit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PARAMS = ("OFS_X", "OFS_Y", "OFS_Z", "DIA_X", "DIA_Y", "DIA_Z", "ODI_X", "ODI_Y", "ODI_Z",
          "MOT_X", "MOT_Y", "MOT_Z")
_LOWER = np.array([-2000.0] * 3 + [0.5] * 3 + [-0.5] * 3 + [-1000.0] * 3)
_UPPER = np.array([2000.0] * 3 + [2.0] * 3 + [0.5] * 3 + [1000.0] * 3)
OUTLIER_SIGMAS = 5.0


@dataclass
class FlightFit:
    """Result of :func:`fit_flight`: parameter vector (``PARAMS`` order; M includes any
    COMPASS_SCALE), its covariance, the residual rms [mGauss], samples used, lag-one
    correlation of the residuals and which parameters were held fixed."""

    x: np.ndarray
    cov: np.ndarray
    rms: float
    n_used: int
    rho: float
    fixed: tuple[str, ...] = ()

    @property
    def at_limits(self) -> bool:
        """True when a DIA/ODI entry sits on its bound (no soft-iron matrix within limits fits)."""
        return bool(np.any(np.isclose(self.x[3:9], _LOWER[3:9], atol=1e-3)
                           | np.isclose(self.x[3:9], _UPPER[3:9], atol=1e-3)))

    @property
    def sigma(self) -> np.ndarray:
        """One-σ of each parameter (0 for fixed ones)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    def matrix(self) -> np.ndarray:
        """M (3, 3)."""
        return soft_iron(self.x)

    def value(self, name: str) -> float:
        """One parameter by its ``PARAMS`` name."""
        return float(self.x[PARAMS.index(name)])


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


def _residuals(x, raw, drive, lev, b_h, b_d):
    """Vertical then horizontal-magnitude residuals, each divided by the norm of the map from
    raw-sensor noise to it (|c·M|): gradient weighting. Without it the fit shrinks M along
    directions where the raw field barely varies (the vertical axis in level flight: the
    noise M·n is then most of what M scales), biasing DIA_Z by σ²/var(raw_z), 0.7 % on a short
    flight; with it each residual is in mGauss of raw noise and the bias is gone to first
    order."""
    v, h, c_z, c_h = _parts(x, raw, drive, lev)
    m = soft_iron(x)
    w_z = np.linalg.norm(c_z @ m, axis=1)
    w_h = np.linalg.norm(c_h @ m, axis=1)
    return np.concatenate([(v[:, 2] - b_d) / w_z, (h - b_h) / w_h])


def _dweight(c, m):
    """|c·M| (n,) and its derivative (n, 12) with respect to the parameters (DIA, ODI only)."""
    a = c @ m
    w = np.linalg.norm(a, axis=1)
    da = np.zeros((len(c), 3, 12))
    for k in range(3):
        da[:, k, 3 + k] = c[:, k]
    for j, (p, q) in enumerate(((0, 1), (0, 2), (1, 2))):
        da[:, p, 6 + j] = c[:, q]
        da[:, q, 6 + j] = c[:, p]
    return w, np.einsum("nk,nkp->np", a, da) / w[:, None]


def _jacobian(x, raw, drive, lev, b_h, b_d, free):
    n = len(raw)
    y = raw + x[0:3]
    v, h, c_z, c_h = _parts(x, raw, drive, lev)
    m = soft_iron(x)
    # dB/dθ (n, 3, 12)
    db = np.zeros((n, 3, 12))
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
    w_z, dw_z = _dweight(c_z, m)
    w_h, dw_h = _dweight(c_h, m)
    r_z, r_h = v[:, 2] - b_d, h - b_h
    jz = jz / w_z[:, None] - (r_z / w_z ** 2)[:, None] * dw_z
    jh = jh / w_h[:, None] - (r_h / w_h ** 2)[:, None] * dw_h
    return np.concatenate([jz, jh])[:, free]


def initial_guess(raw: np.ndarray, lev: np.ndarray, b_h: np.ndarray,
                  b_d: np.ndarray) -> np.ndarray:
    """Start values: a circle through the levelled horizontal field (Kåsa's linear fit) for
    OFS_X/Y and the horizontal scale, the mean vertical misfit for OFS_Z; no cross terms, no
    motor term."""
    v = np.einsum("nij,nj->ni", lev, raw)
    a = np.column_stack([v[:, 0], v[:, 1], np.ones(len(v))])
    sol, *_ = np.linalg.lstsq(a, v[:, 0] ** 2 + v[:, 1] ** 2, rcond=None)
    cx, cy = sol[0] / 2, sol[1] / 2
    radius = np.sqrt(max(sol[2] + cx ** 2 + cy ** 2, 1.0))
    x = np.zeros(12)
    x[0:2] = -cx, -cy
    scale = float(np.clip(np.mean(b_h) / radius, 0.6, 1.6))
    x[3:6] = scale
    x[2] = float(np.mean(b_d / scale - v[:, 2]))
    return x


def fit_flight(raw: np.ndarray, roll: np.ndarray, pitch: np.ndarray, drive: np.ndarray,
               b_h: np.ndarray, b_d: np.ndarray, *, fit_motor: bool = True,
               motor_fixed: np.ndarray | None = None, x0: np.ndarray | None = None,
               quick: bool = False) -> FlightFit:
    """Fit OFS, DIA, ODI (M includes SCALE) and MOT to one compass's flight samples.

    Parameters
    ----------
    raw : (n, 3) uncorrected body-frame field [mGauss] (calibration in force undone).
    roll, pitch : (n,) logged attitude [rad] at the compass samples.
    drive : (n,) current [A] or throttle 0..1 (zeros when there is none).
    b_h, b_d : (n,) WMM horizontal magnitude and down component [mGauss].
    fit_motor : fit MOT; when False it is held at ``motor_fixed`` (default 0).
    x0 : optional start vector (``PARAMS`` order).
    quick : one pass without outlier rejection and at most 30 iterations (for scoring).

    Returns
    -------
    FlightFit
    """
    lev = levelling(roll, pitch)
    x = initial_guess(raw, lev, b_h, b_d) if x0 is None else np.array(x0, float)
    fixed = () if fit_motor else PARAMS[9:12]
    if not fit_motor:
        x[9:12] = 0.0 if motor_fixed is None else motor_fixed
    free = np.array([p not in fixed for p in PARAMS])
    keep = np.ones(len(raw), bool)
    for _ in range(1 if quick else 2):
        args = (raw[keep], drive[keep], lev[keep], b_h[keep], b_d[keep])
        x = _solve(x, free, args, 30 if quick else 200)
        if quick:
            break
        r = _residuals(x, raw, drive, lev, b_h, b_d).reshape(2, -1)
        scale = 1.4826 * np.median(np.abs(r[:, keep] - np.median(r[:, keep], axis=1,
                                                                  keepdims=True)))
        new_keep = np.all(np.abs(r) <= OUTLIER_SIGMAS * max(scale, 1e-6), axis=0)
        if new_keep.sum() < 20 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    args = (raw[keep], drive[keep], lev[keep], b_h[keep], b_d[keep])
    r = _residuals(x, *args)
    j = _jacobian(x, *args, free)
    n_res, p = len(r), int(free.sum())
    s2 = float(r @ r) / max(n_res - p, 1)
    rho = _lag_one(r.reshape(2, -1))
    inflate = (1 + rho) / (1 - rho) if rho > 0 else 1.0
    cov = np.zeros((12, 12))
    cov[np.ix_(free, free)] = np.linalg.pinv(j.T @ j) * s2 * inflate
    return FlightFit(x, cov, float(np.sqrt(np.mean(r ** 2))), int(keep.sum()), rho, fixed)


def _solve(x, free, args, max_iter: int = 200) -> np.ndarray:
    """Levenberg-Marquardt on the 12×12 normal equations, bounds by clipping.

    Hand-written rather than scipy's least_squares: its trust-region step takes an SVD of the
    whole (2n × 12) Jacobian at every iteration (~90 ms for 3000 samples, the orientation search
    runs 40 fits), and its default tolerances stop before the weakly determined vertical-axis
    direction (DIA_Z against OFS_Z) has converged. Here each step costs one JᵀJ.
    """
    lo, hi = _LOWER[free], _UPPER[free]
    full = x.copy()
    full[free] = np.clip(full[free], lo, hi)
    r = _residuals(full, *args)
    cost = float(r @ r)
    lam = 1e-3
    for _ in range(max_iter):
        j = _jacobian(full, *args, free)
        h = j.T @ j
        g = j.T @ r
        d = np.diag(h).copy()
        d[d <= 0] = 1.0
        p = full[free]
        # active set: a parameter on its bound whose descent direction leaves the box stays put
        move = ~(((p <= lo) & (g > 0)) | ((p >= hi) & (g < 0)))
        hm, gm, dm = h[np.ix_(move, move)], g[move], d[move]
        improved = False
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
            c_new = float(r_new @ r_new)
            if c_new <= cost:
                improved = True
                done = cost - c_new <= 1e-12 * cost + 1e-18
                full, r, cost = trial, r_new, c_new
                lam = max(lam / 5, 1e-12)
                break
            lam *= 5
        if not improved or done:
            break
    return full


def _lag_one(r: np.ndarray) -> float:
    """Mean lag-one autocorrelation of the rows of ``r`` (each a residual series in time)."""
    vals = []
    for row in r:
        d = row - row.mean()
        den = float(d @ d)
        if den > 0 and len(d) > 2:
            vals.append(float(d[:-1] @ d[1:]) / den)
    return float(np.clip(np.mean(vals), 0.0, 0.98)) if vals else 0.0


def orientation_scores(raw_sensor: np.ndarray, rotations: dict[int, np.ndarray],
                       roll: np.ndarray, pitch: np.ndarray, drive: np.ndarray,
                       b_h: np.ndarray, b_d: np.ndarray, fit_motor: bool) -> dict[int, float]:
    """Residual rms [mGauss] of the fit with each candidate rotation (code → R, v_body = R·v)
    applied to the sensor-frame samples; inf where the fit hits its bounds (a mount that only a
    negative or degenerate soft-iron matrix could undo)."""
    out = {}
    for code, rot in rotations.items():
        raw = raw_sensor @ rot.T
        fit = fit_flight(raw, roll, pitch, drive, b_h, b_d, fit_motor=fit_motor, quick=True)
        out[code] = float("inf") if fit.at_limits else fit.rms
    return out
