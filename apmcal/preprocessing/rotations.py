"""Rotations about one sensor axis between still periods (Ferraris 1995; [Oppong] §3.1, §4.4).

Between two consecutive static segments the bias-corrected gyroscope is integrated. When the
sensor turns about a fixed axis the integral is the rotation vector, so a motion whose integral
points along one sensor axis (within ``max_off_axis_deg``) is a "step" about that axis. [Oppong]
turns each axis through 360° in four 90° steps with a pause after each; consecutive steps about
the same axis with the same sign are grouped until they add up to a full turn. A continuous
360° turn (imucal's example session) is a single step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.static import StaticSegment

MIN_STEP_DEG = 45.0        # smaller motions between holds are not counted as rotation steps
MAX_OFF_AXIS_DEG = 25.0    # angle between the integrated rotation vector and the sensor axis
FULL_TURN_TOL_DEG = 45.0   # a group closes once within this of a full turn


@dataclass
class Rotation:
    """A rotation about one sensor axis.

    Attributes
    ----------
    axis : int
        0, 1, 2 for x, y, z (sensor frame).
    angle_deg : float
        Integrated angle about ``axis`` [deg], signed (right-hand rule about the sensor axis).
    integrated : (3,) array
        Integrated bias-corrected gyro vector [input gyro unit × s] over ``i0 .. i1-1``.
    start, end : float
        Times [s] of the first and last integrated sample.
    i0, i1 : int
        Half-open sample range integrated (from the end of the hold before the first step to the
        start of the hold after the last step; holds between steps included).
    n_steps : int
        Number of motions grouped into this rotation.
    pose : str or None
        Pose of the hold before the rotation (Ferraris name).
    """

    axis: int
    angle_deg: float
    integrated: np.ndarray
    start: float
    end: float
    i0: int
    i1: int
    n_steps: int
    pose: str | None

    @property
    def axis_name(self) -> str:
        """"x", "y" or "z"."""
        return "xyz"[self.axis]

    def is_full_turn(self, full_turn_deg: float = 360.0, tol_deg: float = FULL_TURN_TOL_DEG) -> bool:
        """True when |angle| is within ``tol_deg`` of a full turn."""
        return abs(abs(self.angle_deg) - full_turn_deg) < tol_deg

    @property
    def off_axis_deg(self) -> float:
        """Angle [deg] between the integrated vector and the rotation axis."""
        v = self.integrated
        return float(np.degrees(np.arccos(min(1.0, abs(v[self.axis]) / np.linalg.norm(v)))))


def sample_intervals(t: np.ndarray) -> np.ndarray:
    """Forward time steps Δ_i = t[i+1] − t[i], the last one repeated, so Σ x_i Δ_i = Σ x_i / fs.

    This rectangle rule is imucal's (sum / sampling rate) on regular data and still right on
    irregular telemetry.

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].

    Returns
    -------
    numpy.ndarray, shape (n,)
        Δ_i [s].
    """
    d = np.diff(t)
    return np.append(d, d[-1] if d.size else 0.0)


def integrate(t: np.ndarray, x: np.ndarray, i0: int, i1: int) -> np.ndarray:
    """Rectangle-rule integral of (n, 3) ``x`` over samples ``i0 .. i1-1`` [x unit × s].

    The intervals are taken inside the range, so ranges cut out of a longer recording (imucal's
    annotated sections) integrate the same as contiguous data.

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    x : numpy.ndarray, shape (n, 3)
        Samples, e.g. rate [rad/s].
    i0, i1 : int
        Half-open sample range.

    Returns
    -------
    numpy.ndarray, shape (3,)
        The integral [x unit × s], e.g. rad.
    """
    return integrate_slice(t[i0:i1], x[i0:i1])


def integrate_slice(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Rectangle-rule integral of (m, 3) ``x`` sampled at ``t`` (already sliced) [x unit × s].

    Parameters
    ----------
    t : numpy.ndarray, shape (m,)
        Sample times [s].
    x : numpy.ndarray, shape (m, 3)
        Samples, e.g. rate [rad/s].

    Returns
    -------
    numpy.ndarray, shape (3,)
    """
    return (x * sample_intervals(t)[:, None]).sum(axis=0)


def _bias_between(a: StaticSegment, b: StaticSegment) -> np.ndarray:
    """Gyro bias during a motion, taken as constant: the average of the two holds' means.

    (:func:`apmcal.solvers.ferraris.integrate_motions` refines this with a bias linear in time.)
    """
    return 0.5 * (a.gyr_mean + b.gyr_mean)


def find_steps(t, gyr, segments: list[StaticSegment], *, bias=None,
               min_step_deg: float = MIN_STEP_DEG,
               max_off_axis_deg: float = MAX_OFF_AXIS_DEG) -> list[Rotation]:
    """Single-axis motions between consecutive static segments (one Rotation each, n_steps=1).

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    gyr : (n, 3) array
        Gyroscope [rad/s] (the angle test uses radians).
    segments : list of StaticSegment
        Static segments with ``gyr_mean`` (from :func:`find_static_segments` with gyr).
    bias : callable t -> (m, 3) bias, optional
        Gyro bias model [rad/s]; default: mean of the two holds around each motion.
    min_step_deg : float, optional
        Smaller motions [deg] are not steps.
    max_off_axis_deg : float, optional
        Largest angle [deg] between the integrated rotation vector and the nearest sensor axis.

    Returns
    -------
    list of Rotation
        In time order, ``n_steps`` 1 each.

    Raises
    ------
    ApmcalError
        Segments computed without the gyroscope.
    """
    t = np.asarray(t, dtype=float)
    gyr = np.asarray(gyr, dtype=float)
    steps = []
    for a, b in zip(segments[:-1], segments[1:]):
        if a.gyr_mean is None or b.gyr_mean is None:
            raise ApmcalError("rotation detection needs static segments computed with the gyroscope")
        i0, i1 = a.i1, b.i0
        if i1 <= i0:
            continue
        bb = _bias_between(a, b) if bias is None else bias(t[i0:i1])
        v = integrate_slice(t[i0:i1], gyr[i0:i1] - bb)
        norm = np.linalg.norm(v)
        if np.degrees(norm) < min_step_deg:
            continue
        axis = int(np.argmax(np.abs(v)))
        off = np.degrees(np.arccos(min(1.0, abs(v[axis]) / norm)))
        if off > max_off_axis_deg:
            continue
        steps.append(Rotation(axis=axis, angle_deg=float(np.degrees(v[axis])), integrated=v,
                              start=float(t[i0]), end=float(t[i1 - 1]), i0=int(i0), i1=int(i1),
                              n_steps=1, pose=a.pose))
    return steps


def _merge(group: list[Rotation], t, gyr, segments, bias) -> Rotation:
    """One Rotation spanning a group of adjacent steps, holds between them included."""
    first, last = group[0], group[-1]
    v = sum(s.integrated for s in group)
    # the holds between steps contribute their bias-corrected integral too (≈ 0, but exact)
    for seg in segments:
        if first.i1 <= seg.i0 and seg.i1 <= last.i0:
            bb = seg.gyr_mean if bias is None else bias(t[seg.i0:seg.i1])
            v = v + integrate_slice(t[seg.i0:seg.i1], gyr[seg.i0:seg.i1] - bb)
    return Rotation(axis=first.axis, angle_deg=float(np.degrees(v[first.axis])), integrated=v,
                    start=first.start, end=last.end, i0=first.i0, i1=last.i1,
                    n_steps=len(group), pose=first.pose)


def find_rotations(t, gyr, segments: list[StaticSegment], *, bias=None,
                   full_turn_deg: float = 360.0,
                   min_step_deg: float = MIN_STEP_DEG,
                   max_off_axis_deg: float = MAX_OFF_AXIS_DEG) -> list[Rotation]:
    """Rotations about single sensor axes, consecutive steps grouped into full turns.

    Steps about the same axis with the same sign that follow each other (only holds between them)
    are added up; the group closes as soon as its angle is within 45° of ``full_turn_deg``, or
    before a step that would overshoot it (reorientations such as 180° + 90° + 180°). Groups
    that never reach a full turn are returned as well (their ``angle_deg`` tells); the caller
    decides what to use.

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    gyr : (n, 3) array
        Gyroscope [rad/s].
    segments : list of StaticSegment
        In time order, computed with the gyroscope.
    bias : callable t -> (m, 3) gyro bias, optional
        Gyro bias model [rad/s] (default: mean of the neighbouring holds).
    full_turn_deg : float, optional
        The turn [deg] a group closes at.
    min_step_deg, max_off_axis_deg : float, optional
        As for :func:`find_steps`.

    Returns
    -------
    list of Rotation
        In time order.

    Raises
    ------
    ApmcalError
        Segments computed without the gyroscope.
    """
    t = np.asarray(t, dtype=float)
    gyr = np.asarray(gyr, dtype=float)
    steps = find_steps(t, gyr, segments, bias=bias, min_step_deg=min_step_deg,
                       max_off_axis_deg=max_off_axis_deg)
    next_seg = {seg.i1: k for k, seg in enumerate(segments)}
    out: list[Rotation] = []
    group: list[Rotation] = []

    def close():
        if group:
            out.append(_merge(group, t, gyr, segments, bias))
            group.clear()

    for s in steps:
        if group:
            prev = group[-1]
            k = next_seg.get(prev.i0)
            adjacent = k is not None and k + 1 < len(segments) and segments[k + 1].i1 == s.i0
            same = s.axis == prev.axis and np.sign(s.angle_deg) == np.sign(prev.angle_deg)
            total = abs(sum(g.angle_deg for g in group) + s.angle_deg)
            if not (adjacent and same) or total > full_turn_deg + FULL_TURN_TOL_DEG:
                close()
        group.append(s)
        total = sum(g.angle_deg for g in group)
        if abs(abs(total) - full_turn_deg) < FULL_TURN_TOL_DEG:
            close()
    close()
    return out
