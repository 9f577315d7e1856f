"""How many degrees of heading a compass calibration costs along a flight.

The heading a compass gives is that of its tilt-compensated horizontal field: with
v = Ry(pitch)·Rx(roll)·B (body field into the level frame that keeps the body's heading),
heading = atan2(−v_y, v_x) + declination. A field error e therefore turns the heading by about
e_⊥ / B_horizontal (e_⊥ the part of the levelled error across the horizontal field), which is
why the same error in mGauss costs more degrees where the inclination is steep.

The true heading is not in the log (the EKF's yaw used the compass under test). The reference
is the gyro's: the heading change between instants integrated from the body rates (ψ̇ =
(q·sinφ + r·cosφ)/cosθ), anchored in each ``window_s`` window to the circular mean of a chosen
calibration's compass heading (the proposed one). Over a window a gyro calibrated at boot
drifts a fraction of a degree; a heading-dependent compass error does not average away, so it
shows as the spread of the error. A constant heading offset common to every calibration (a
compass twisted on its mount by a few degrees) cannot be seen this way.

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

from dataclasses import dataclass

import numpy as np

from apmcal.solvers.compass_flight import levelling

GOOD_DEG = 2.0
USABLE_DEG = 5.0


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


def gyro_heading(gyr_t: np.ndarray, gyr: np.ndarray, att_t: np.ndarray, roll: np.ndarray,
                 pitch: np.ndarray, t_out: np.ndarray) -> np.ndarray:
    """Heading change [rad, unwrapped, 0 at the first gyro sample] integrated from body rates
    (n, 3) [rad/s] at ``gyr_t``, with roll/pitch [rad] interpolated from ``att_t``; sampled at
    ``t_out`` [s]."""
    phi = np.interp(gyr_t, att_t, roll)
    th = np.interp(gyr_t, att_t, pitch)
    rate = (gyr[:, 1] * np.sin(phi) + gyr[:, 2] * np.cos(phi)) / np.cos(th)
    dt = np.diff(gyr_t)
    dt = np.where((dt > 0) & (dt < 1.0), dt, 0.0)      # gaps: no heading change assumed
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt)])
    return np.interp(t_out, gyr_t, psi)


def wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles [deg] into [−180, 180)."""
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def anchored_reference(t: np.ndarray, psi_rel: np.ndarray, anchor: np.ndarray,
                       window_s: float = 60.0) -> np.ndarray:
    """Reference heading [rad]: ``psi_rel`` plus, per ``window_s`` window of ``t``, the
    circular mean of ``anchor − psi_rel``."""
    out = np.empty_like(psi_rel)
    edges = np.arange(t[0], t[-1] + window_s, window_s)
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, None)
    for k in np.unique(idx):
        s = idx == k
        d = anchor[s] - psi_rel[s]
        out[s] = psi_rel[s] + np.arctan2(np.mean(np.sin(d)), np.mean(np.cos(d)))
    return out


@dataclass
class HeadingHealth:
    """Heading error of one calibration along a flight: per-sample errors [deg], their rms,
    95th percentile and maximum of |error| [deg], the field residual against the WMM [mGauss]
    (rms of |B − B_expected|, the expected field turned by the reference heading) and its
    magnitude part, and the verdict."""

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
                   reference: np.ndarray, field_ned: np.ndarray,
                   declination: float) -> HeadingHealth:
    """:class:`HeadingHealth` of corrected fields (n, 3) [mGauss, body] against the reference
    heading [rad] and the WMM field ``field_ned`` [mGauss, NED]."""
    err = wrap_deg(np.degrees(compass_heading(field_body, roll, pitch, declination) - reference))
    yaw = reference
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
