"""How many degrees of heading a compass calibration costs along a flight.

The heading a compass gives is that of its tilt-compensated horizontal field: with
v = Ry(pitch)·Rx(roll)·B (body field into the level frame that keeps the body's heading),
heading = atan2(−v_y, v_x) + declination. A field error e therefore turns the heading by about
e_⊥ / B_horizontal (e_⊥ the part of the levelled error across the horizontal field), which is
why the same error in mGauss costs more degrees where the inclination is steep.

**The reference** (:func:`fit_reference`). The true heading is not in the log (the EKF's yaw
used the compass under test). The gyro gives the heading's changes, ψ̇ = (q·sinφ + r·cosφ)/cosθ,
but a gyro drifts (ArduPilot's SITL by a triangle wave up to 0.25 °/s by default, a real one
with temperature), and a compass sample stands for an earlier instant than its time stamp
(ArduPilot averages the samples since the last read, 10 Hz on a copter: about 50 ms, which is
2° in a 45 °/s turn). So the reference is fitted, not assumed:

    ψ_anchor(tᵢ) = ψ₀ + G(tᵢ − τ) − ∫₀^(tᵢ−τ) (b_y(s)·sinφ + b_z(s)·cosφ)/cosθ ds + eᵢ

with G the integrated gyro heading, b_y, b_z the body gyro biases as piecewise-linear functions
of time (knots every ``knot_s``; a random-walk prior on their steps and a prior on their size),
ψ₀ the anchor's mean offset and τ the compass's sample delay (searched on a grid, the rest a
linear least-squares problem for each τ, Huber-weighted ([Huber]) against outliers). The anchor
is the proposed calibration's compass heading: eᵢ is then what the gyro says about the proposal,
and every other calibration's heading error is measured against ψ₀ + G − ∫b. A heading error
that varies faster than the bias may (turns, headings flown in turn) shows; a constant heading
offset common to every calibration (a compass twisted on its mount by a few degrees) cannot,
nor can a declination error.

Verdict on the 95th percentile of |heading error| (``verdict``):

* good ≤ 2°: below the wind-crab and GNSS-course noise a pilot can see on a straight leg, and
  about what a careful onboard calibration reaches;
* usable ≤ 5°: the EKF's innovations stay small, position-hold circles ("toilet bowling") that
  start with yaw errors of tens of degrees are far off, but legs and loiter show it;
* redo above 5°.

These thresholds are apmcal's choice, not ArduPilot's (its own checks reject only far larger
inconsistencies between compasses).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.solvers.compass_flight import levelling

GOOD_DEG = 2.0
USABLE_DEG = 5.0
KNOT_S = 30.0                         # spacing of the gyro-bias knots [s]
BIAS_SIGMA = np.radians(1.0)          # prior σ of a gyro bias [rad/s]
BIAS_STEP_SIGMA = np.radians(0.1)     # prior σ of its change from one knot to the next [rad/s]
DELAYS_S = np.arange(-0.1, 0.3001, 0.02)   # sample delays tried [s], then refined to 5 ms
HUBER_K = 1.345
MIN_GAP_S = 0.15                      # a rate record missing this long ...
GAP_FACTOR = 4.0                      # ... and this many typical steps: the heading may jump
GAP_BRIDGE_RAD = np.radians(0.25)     # ... unless a straight line bridges it within this


def verdict(p95_deg: float) -> str:
    """"good", "usable" or "redo" for a 95 % heading error [deg] (see the module docstring)."""
    if not np.isfinite(p95_deg):
        return "redo"
    return "good" if p95_deg <= GOOD_DEG else "usable" if p95_deg <= USABLE_DEG else "redo"


def compass_heading(field_body: np.ndarray, roll: np.ndarray, pitch: np.ndarray,
                    declination: float) -> np.ndarray:
    """Tilt-compensated heading [rad] of body-frame fields (n, 3) [mGauss]; angles [rad]."""
    v = np.einsum("nij,nj->ni", levelling(roll, pitch), field_body)
    return np.arctan2(-v[:, 1], v[:, 0]) + declination


def _cumtrapz(t: np.ndarray, y: np.ndarray, skip: np.ndarray | None = None) -> np.ndarray:
    """Cumulative trapezoid integral of y over t, 0 at the first sample; steps marked in
    ``skip`` (gaps, :func:`gap_steps`) or backwards add nothing."""
    dt = np.diff(t)
    ok = dt > 0 if skip is None else (dt > 0) & ~skip
    dt = np.where(ok, dt, 0.0)
    return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * dt)])


def gap_steps(t: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Which steps between consecutive rate samples are gaps the heading may jump across:
    longer than ``MIN_GAP_S`` and ``GAP_FACTOR`` typical steps (a log that dropped records),
    with a rate [rad/s] that changed so much across it that a straight line between its ends
    could be ``GAP_BRIDGE_RAD`` off (a steady turn is bridged)."""
    dt = np.diff(t)
    if len(dt) == 0:
        return np.zeros(0, bool)
    long = dt > max(MIN_GAP_S, GAP_FACTOR * float(np.median(dt)))
    return long & (np.abs(np.diff(rate)) * dt / 2.0 > GAP_BRIDGE_RAD)


@dataclass
class RateSource:
    """Heading changes to fit a reference to: at times ``t`` [s], the integrated heading G
    [rad, 0 at the first sample], and the cumulative integrals of the factors that carry a body
    y / z gyro bias into the heading rate (sinφ/cosθ, cosφ/cosθ), plain and times (t − t[0])
    (for the piecewise-linear bias). ``gyro`` False: G is a logged heading (no bias factors
    beyond a heading-rate bias). Across a gap in the gyro record (:func:`gap_steps`) G is held
    and the reference gets a free jump there; a logged heading needs none (it is absolute on
    both sides)."""

    t: np.ndarray
    g: np.ndarray
    c0: np.ndarray            # (n, k) ∫ c ds per bias axis
    c1: np.ndarray            # (n, k) ∫ (s − t0)·c ds
    gyro: bool
    gap_ends: np.ndarray = field(default_factory=lambda: np.zeros(0))   # [s]

    def step_basis(self, t: np.ndarray) -> np.ndarray:
        """(len(t), k): 1 after a gap's end, 0 before (an unknown jump of G there), one column
        per interval of ``t`` that holds gap ends."""
        first = np.unique(np.searchsorted(t, self.gap_ends))
        first = first[(first > 0) & (first < len(t))]
        return (np.arange(len(t))[:, None] >= first[None, :]).astype(float)

    @classmethod
    def from_gyro(cls, gyr_t: np.ndarray, gyr: np.ndarray, att_t: np.ndarray,
                  roll: np.ndarray, pitch: np.ndarray) -> "RateSource":
        """From body rates (n, 3) [rad/s] at ``gyr_t``, roll/pitch [rad] interpolated from
        ``att_t``."""
        phi = np.interp(gyr_t, att_t, roll)
        cth = np.cos(np.interp(gyr_t, att_t, pitch))
        c = np.stack([np.sin(phi) / cth, np.cos(phi) / cth], axis=1)
        rate = gyr[:, 1] * c[:, 0] + gyr[:, 2] * c[:, 1]
        skip = gap_steps(gyr_t, rate)
        s = (gyr_t - gyr_t[0])[:, None]
        return cls(gyr_t, _cumtrapz(gyr_t, rate, skip), _cumtrapz_cols(gyr_t, c, skip),
                   _cumtrapz_cols(gyr_t, c * s, skip), True, gyr_t[1:][skip])

    @classmethod
    def from_heading(cls, t: np.ndarray, heading: np.ndarray) -> "RateSource":
        """From a logged heading [rad] (unwrapped here); one heading-rate bias."""
        psi = np.unwrap(heading)
        s = t - t[0]
        one = np.ones((len(t), 1))
        return cls(t, psi - psi[0], _cumtrapz_cols(t, one), _cumtrapz_cols(t, one * s[:, None]),
                   False)


    def heading(self, t: np.ndarray) -> np.ndarray:
        """G at ``t`` [rad]."""
        return np.interp(t, self.t, self.g)

    def bias_basis(self, t: np.ndarray, knots: np.ndarray) -> np.ndarray:
        """(len(t), k·len(knots)): ∫₀ᵗ hat_j(s)·c(s) ds for every knot j and bias axis, the hat
        functions being the piecewise-linear interpolants between ``knots`` [s]."""
        s0 = self.t[0]
        cols = []
        for a in range(self.c0.shape[1]):
            c0 = lambda u, a=a: np.interp(u, self.t, self.c0[:, a])     # noqa: E731
            c1 = lambda u, a=a: np.interp(u, self.t, self.c1[:, a])     # noqa: E731
            out = np.zeros((len(t), len(knots)))
            for i in range(len(knots) - 1):
                lo, hi = knots[i], knots[i + 1]
                u = np.clip(t, lo, hi)
                i0 = c0(u) - c0(lo)
                i1 = c1(u) - c1(lo)
                width = hi - lo
                # hat i falls from 1 at lo to 0 at hi, hat i+1 rises: (s − s0) is c1's weight
                out[:, i] += ((hi - s0) * i0 - i1) / width
                out[:, i + 1] += (i1 - (lo - s0) * i0) / width
            cols.append(out)
        return np.concatenate(cols, axis=1)


def _cumtrapz_cols(t: np.ndarray, y: np.ndarray, skip: np.ndarray | None = None) -> np.ndarray:
    return np.stack([_cumtrapz(t, y[:, k], skip) for k in range(y.shape[1])], axis=1)


def wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles [deg] into [−180, 180)."""
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@dataclass
class HeadingReference:
    """A fitted heading reference (:func:`fit_reference`): at the compass sample times ``t``
    [s] the reference heading ``psi`` [rad] (for the instants the samples stand for), the
    sample delay [s], the gyro bias [rad/s] at ``knots_t`` per axis (y, z; or one axis for a
    logged heading), the anchor's residual against it [rad], and the reference before the
    bias was taken out (``anchor_free``, [rad])."""

    t: np.ndarray
    psi: np.ndarray
    delay_s: float
    knots_t: np.ndarray
    bias: np.ndarray
    residual: np.ndarray
    gyro: bool
    anchor_free: np.ndarray = field(default_factory=lambda: np.zeros(0))   # ψ₀ + G + jumps

    def error_deg(self, psi_compass: np.ndarray) -> np.ndarray:
        """A compass heading's error [deg] against the reference, sample by sample."""
        return wrap_deg(np.degrees(psi_compass - self.psi))

    @property
    def bias_rate(self) -> np.ndarray:
        """The heading-rate bias the fit took out of the gyro heading [rad/s], per sample."""
        removed = self.psi - self.anchor_free
        return np.gradient(removed, self.t) if len(self.t) > 1 else np.zeros(len(self.t))

    def describe(self, anchor: str = "the proposed calibration") -> str:
        """One line: what the reference is, what was estimated, and what it is anchored to."""
        peak = float(np.degrees(np.max(np.abs(self.bias_rate)))) if len(self.t) else 0.0
        what = "gyro-integrated heading" if self.gyro else "logged heading change (it used this " \
                                                          "compass)"
        return (f"{what}, its bias fitted along the flight (up to {peak:.2f} °/s) with the "
                f"compass's sample delay ({1000 * self.delay_s:.0f} ms), anchored to {anchor} "
                f"(a constant offset common to all calibrations is not seen)")


def fit_reference(t: np.ndarray, anchor: np.ndarray, source: RateSource,
                  heading_at=None, knot_s: float = KNOT_S,
                  delays_s: np.ndarray = DELAYS_S) -> HeadingReference:
    """Fit the reference heading to the anchor's compass headings (see the module docstring).

    Parameters
    ----------
    t : (n,) compass sample times [s], increasing.
    anchor : (n,) the anchor calibration's compass heading [rad] at them.
    source : the gyro's (or a logged heading's) integrated heading.
    heading_at : optional callable delay [s] → anchor headings (n,) recomputed with the
        attitude at t − delay (the tilt compensation at the instants the samples stand for);
        ``anchor`` is used for every delay when None.
    knot_s : spacing of the bias knots [s].
    delays_s : the sample delays tried [s]; the best is refined to 5 ms.
    """
    t0 = min(t[0] - max(delays_s.max(), 0.0), source.t[-1])
    span = max(t[-1] - t0, 1e-3)
    n_knots = max(2, int(np.ceil(span / knot_s)) + 1)
    knots = t0 + np.linspace(0.0, span, n_knots)

    def solve(delay):
        head = anchor if heading_at is None else heading_at(delay)
        return _fit_at_delay(t, head, source, knots, delay)

    tried = {float(d): solve(float(d)) for d in delays_s}
    best = min(tried, key=lambda d: tried[d][0])
    for d in np.arange(best - 0.015, best + 0.0151, 0.005):
        d = float(round(d, 4))
        if d not in tried:
            tried[d] = solve(d)
    best = min(tried, key=lambda d: tried[d][0])
    _, psi, bias, resid, unbiased = tried[best]
    n_axes = source.c0.shape[1]
    return HeadingReference(t, psi, best, knots, bias.reshape(n_axes, -1), resid, source.gyro,
                            unbiased)


def _fit_at_delay(t, head, source: RateSource, knots, delay):
    """(robust cost, reference heading, bias coefficients, residuals, the reference without the
    bias) for one sample delay."""
    u = t - delay
    g = source.heading(u)
    y = np.unwrap(_wrap(head - g))
    basis = source.bias_basis(u, knots)
    steps = source.step_basis(u)
    n, m = len(t), basis.shape[1]
    a = np.concatenate([np.ones((n, 1)), -basis, steps], axis=1)
    # priors: every bias small, its knot-to-knot steps small (a random walk), per axis
    k = len(knots)
    rows = []
    for axis in range(m // k):
        first = np.zeros(m)
        first[axis * k] = 1.0 / BIAS_SIGMA
        rows.append(first)
        for j in range(k - 1):
            step = np.zeros(m)
            step[axis * k + j], step[axis * k + j + 1] = -1.0 / BIAS_STEP_SIGMA, 1.0 / BIAS_STEP_SIGMA
            rows.append(step)
    prior = np.concatenate([np.zeros((len(rows), 1)), np.array(rows),
                            np.zeros((len(rows), steps.shape[1]))], axis=1)
    w = np.ones(n)
    sigma = np.radians(1.0)
    ptp = prior.T @ prior
    for _ in range(3):
        aw = a * (w / sigma ** 2)[:, None]
        # least squares on the normal equations: jumps with no sample between them are one
        coef = np.linalg.lstsq(aw.T @ a + ptp, aw.T @ y, rcond=None)[0]
        resid = y - a @ coef
        sigma = max(1.4826 * float(np.median(np.abs(resid - np.median(resid)))), np.radians(0.01))
        z = np.abs(resid) / (HUBER_K * sigma)
        w = np.where(z <= 1.0, 1.0, 1.0 / np.maximum(z, 1e-12))
    z = np.abs(resid) / sigma
    cost = float(np.sum(np.where(z <= HUBER_K, 0.5 * z ** 2, HUBER_K * z - 0.5 * HUBER_K ** 2)))
    cost *= sigma ** 2          # comparable between delays: in rad², not in units of each σ
    psi = head - resid
    unbiased = psi + basis @ coef[1:1 + m]
    return cost, psi, coef[1:1 + m], resid, unbiased


@dataclass
class HeadingHealth:
    """Heading error of one calibration along a flight: per-sample errors [deg], their rms,
    95th percentile and maximum of |error| [deg], the field residual against the expected
    field [mGauss] (rms of |B − B_expected|, the expected field turned by the reference
    heading) and its magnitude part, and the verdict."""

    t: np.ndarray
    error_deg: np.ndarray
    rms_deg: float
    p95_deg: float
    max_deg: float
    field_rms_mgauss: float
    magnitude_rms_mgauss: float
    verdict: str

    def to_dict(self) -> dict:
        """Summary (no per-sample arrays)."""
        return {"heading_error_rms_deg": self.rms_deg, "heading_error_p95_deg": self.p95_deg,
                "heading_error_max_deg": self.max_deg,
                "field_residual_rms_mgauss": self.field_rms_mgauss,
                "magnitude_residual_rms_mgauss": self.magnitude_rms_mgauss,
                "verdict": self.verdict}


def heading_health(t: np.ndarray, field_body: np.ndarray, roll: np.ndarray, pitch: np.ndarray,
                   reference: HeadingReference, field_ned: np.ndarray,
                   declination: float) -> HeadingHealth:
    """:class:`HeadingHealth` of corrected fields (n, 3) [mGauss, body], with roll and pitch
    [rad] at the instants the samples stand for, against the reference and the expected field
    ``field_ned`` [mGauss, NED]."""
    err = reference.error_deg(compass_heading(field_body, roll, pitch, declination))
    yaw = reference.psi
    cy, sy = np.cos(yaw), np.sin(yaw)
    # expected body field: R_levᵀ · Rz(yaw)ᵀ · B_ned
    level = np.stack([cy * field_ned[0] + sy * field_ned[1],
                      -sy * field_ned[0] + cy * field_ned[1],
                      np.full_like(yaw, field_ned[2])], axis=1)
    expected = np.einsum("nji,nj->ni", levelling(roll, pitch), level)
    resid = np.linalg.norm(field_body - expected, axis=1)
    mag = np.linalg.norm(field_body, axis=1) - np.linalg.norm(field_ned)
    a = np.abs(err)
    p95 = float(np.percentile(a, 95))
    return HeadingHealth(t, err, float(np.sqrt(np.mean(err ** 2))), p95, float(a.max()),
                         float(np.sqrt(np.mean(resid ** 2))), float(np.sqrt(np.mean(mag ** 2))),
                         verdict(p95))


def gyro_heading(gyr_t: np.ndarray, gyr: np.ndarray, att_t: np.ndarray, roll: np.ndarray,
                 pitch: np.ndarray, t_out: np.ndarray) -> np.ndarray:
    """Heading change [rad, unwrapped, 0 at the first gyro sample] integrated from body rates
    (n, 3) [rad/s] at ``gyr_t``, with roll/pitch [rad] interpolated from ``att_t``; sampled at
    ``t_out`` [s]."""
    return RateSource.from_gyro(gyr_t, gyr, att_t, roll, pitch).heading(t_out)
