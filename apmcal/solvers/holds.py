"""Methods that work on static holds found beforehand: the one-position method on the longest
level hold ([Oppong] §5) and the accelerometer ellipsoid fit of the hold means ([Niespodziany])."""
from __future__ import annotations

import numpy as np

from apmcal.core.constants import STANDARD_GRAVITY
from apmcal.core.errors import ApmcalError
from apmcal.solvers.report_types import Hold, Holds
from apmcal.solvers.result import Calibration, SensorCalibration

LEVEL_TOLERANCE_DEG = 10.0  # [Oppong] §3.2 levels the platform with a plumb line
MIN_ELLIPSOID_HOLDS = 7     # 9 parameters; the robust fit's prior carries the rest ([Niespodziany])
MIN_ORIENTATIONS = 4        # holds ≥ 30° apart: fewer leave the ellipsoid undetermined


def tilt_from_level_deg(acc_mean: np.ndarray) -> float:
    """Angle [deg] between the mean specific force and a level vehicle's (0, 0, −g).

    Parameters
    ----------
    acc_mean : (3,) array
        Mean specific force, body frame [m/s² or counts].

    Returns
    -------
    float
        The tilt [deg], 0..180.
    """
    up = -np.asarray(acc_mean, dtype=float) / np.linalg.norm(acc_mean)
    return float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))


def longest_level_hold(segments, board_rotation: np.ndarray | None = None):
    """The longest hold within :data:`LEVEL_TOLERANCE_DEG` of level, or a clear error.

    Level is the vehicle's: the hold means (sensor frame) are rotated into the body frame by
    ``board_rotation`` (AHRS_ORIENTATION, sensor → body), so a board mounted upside down on a
    level vehicle counts as level (None: the identity).

    Parameters
    ----------
    segments : list of StaticSegment
        The holds.
    board_rotation : (3, 3) array, optional
        Sensor → body rotation.

    Returns
    -------
    StaticSegment

    Raises
    ------
    ApmcalError
        When no hold is level.
    """
    rotation = np.eye(3) if board_rotation is None else np.asarray(board_rotation, dtype=float)

    def tilt(s):
        return tilt_from_level_deg(rotation @ s.acc_mean)

    level = [s for s in segments if tilt(s) <= LEVEL_TOLERANCE_DEG]
    if not level:
        tilts = ", ".join(f"{tilt(s):.0f}°" for s in segments[:5])
        found = f" (still periods found, tilted {tilts})" if segments else ""
        raise ApmcalError("one-position method: no level still period found; hold the vehicle "
                          f"level (z down, x north) for about a minute{found}")
    return max(level, key=lambda s: s.end - s.start)


def one_position_on_holds(t, acc, gyr, segments, lat_deg, lon_deg,
                          board_rotation: np.ndarray | None = None) -> Calibration:
    """[Oppong]'s one-position method on the longest level hold.

    The paper's platform is level with x north and z down ([Oppong] §3.2): that is the vehicle's
    body frame, so the sensor-frame samples are rotated into it by ``board_rotation``
    (AHRS_ORIENTATION), the recipe runs there, and the result is turned back to the sensor frame
    like every other method's. One pose cannot separate accelerometer bias from tilt (see the
    identifiability lines in the report), so the accelerometer is marked undetermined and its
    offsets are never sent to a vehicle.

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    acc : (n, 3) array
        Specific force, sensor frame [m/s²].
    gyr : (n, 3) array or None
        Angular rate, sensor frame [rad/s].
    segments : list of StaticSegment
        The holds.
    lat_deg, lon_deg : float
        Position [deg].
    board_rotation : (3, 3) array, optional
        AHRS_ORIENTATION, sensor → body (None: the identity).

    Returns
    -------
    Calibration
        Method "static" (:func:`apmcal.solvers.one_position.one_position_calibration`), sensor
        frame, accelerometer marked undetermined.

    Raises
    ------
    ApmcalError
        When no hold is level, or the one-position method refuses the hold (too short for its
        high-pass, the equator).
    """
    from apmcal.solvers.one_position import one_position_calibration

    R = np.eye(3) if board_rotation is None else np.asarray(board_rotation, dtype=float)
    still = longest_level_hold(segments, R)
    part = still.kept()
    cal = one_position_calibration(t[part], acc[part] @ R.T,
                                   None if gyr is None else gyr[part] @ R.T,
                                   lat_deg=lat_deg, lon_deg=lon_deg)
    cal.sensors = {name: body_to_sensor(sc, R) for name, sc in cal.sensors.items()}
    cal.report.holds = Holds(count=len(segments), used={"level": Hold(still.start, still.end,
                                                                      len(part))})
    cal.report.undetermined = {"acc": "one static pose cannot separate accelerometer "
                               "bias from tilt (see the identifiability report)"}
    return cal


def body_to_sensor(cal: SensorCalibration, R: np.ndarray) -> SensorCalibration:
    """A calibration of body-frame samples (R @ m) re-expressed for sensor-frame samples m.

    From R·M_s·(m − o_s) = M_b·(R·m − o_b): o_s = Rᵀ·o_b and M_s = Rᵀ·M_b·R. Sigmas move with
    the squared entries (exact for the axis permutations of ArduPilot's board rotations).

    Parameters
    ----------
    cal : SensorCalibration
        Calibration of body-frame samples.
    R : (3, 3) array
        Sensor → body rotation.

    Returns
    -------
    SensorCalibration
        Offset (3,), matrix (3, 3), drift (3,) and their sigmas for sensor-frame samples.
    """
    R2 = R ** 2
    sigma = {}
    if "offset" in cal.sigma:
        sigma["offset"] = np.sqrt(R2.T @ cal.sigma["offset"] ** 2)
    if "matrix" in cal.sigma:
        sigma["matrix"] = np.sqrt(R2.T @ cal.sigma["matrix"] ** 2 @ R2)
    if "drift" in cal.sigma:
        sigma["drift"] = np.sqrt(R2.T @ cal.sigma["drift"] ** 2)
    return SensorCalibration(offset=R.T @ cal.offset, matrix=R.T @ cal.matrix @ R,
                             drift=R.T @ cal.drift, t_ref=cal.t_ref, sigma=sigma)


def distinct_orientations(segments, min_chord: float = 0.5) -> int:
    """Number of hold orientations whose mean accelerometer vectors are at least ``min_chord``
    field radii apart (0.5 radius ≈ 30°), by greedy clustering.

    The radius is g when the samples are in m/s²; for raw counts (large offsets, unknown scale)
    it is half the largest distance between hold means, provided that distance stands well
    above the holds' own noise.

    Parameters
    ----------
    segments : list of StaticSegment
        The holds (their ``acc_mean`` (3,) and ``acc_std`` (3,)).
    min_chord : float
        Least distance between orientations, in field radii.

    Returns
    -------
    int
    """
    means = np.array([s.acc_mean for s in segments])
    if len(means) == 0:
        return 0
    radius = float(np.median(np.linalg.norm(means, axis=1)))
    if not 0.7 * STANDARD_GRAVITY < radius < 1.3 * STANDARD_GRAVITY:     # not m/s²: counts
        spread = np.linalg.norm(means[:, None] - means[None], axis=2).max() / 2
        noise = float(np.median([np.linalg.norm(s.acc_std) for s in segments]))
        if spread < 10 * noise:
            return 1
        radius = spread
    centres: list[np.ndarray] = []
    for m in means:
        if all(np.linalg.norm(m - c) >= min_chord * radius for c in centres):
            centres.append(m)
    return len(centres)


def ellipsoid_on_holds(gyr, segments, gravity: float) -> Calibration:
    """Robust ellipsoid fit ([Niespodziany]) of the hold means [m/s²]; gyro offset from held samples.

    Parameters
    ----------
    gyr : (n, 3) array or None
        Gyro samples [rad/s].
    segments : list of StaticSegment
        The holds.
    gravity : float
        Local gravity [m/s²], the ellipsoid's radius.

    Returns
    -------
    Calibration
        Method "ellipsoid": "acc" (and "gyr", offset only).

    Raises
    ------
    ApmcalError
        With too few holds or orientations.
    """
    from apmcal.solvers.ellipsoid.fit import ellipsoid_calibration

    n_orient = distinct_orientations(segments)
    if len(segments) < MIN_ELLIPSOID_HOLDS or n_orient < MIN_ORIENTATIONS:
        raise ApmcalError(f"ellipsoid fit needs at least {MIN_ELLIPSOID_HOLDS} static holds in "
                          f"{MIN_ORIENTATIONS} or more orientations; found {len(segments)} holds "
                          f"in {n_orient} orientation(s)")
    samples = {"acc": np.array([s.acc_mean for s in segments])}
    if gyr is not None:
        samples["gyr"] = np.concatenate([gyr[s.kept()] for s in segments])
    cal = ellipsoid_calibration(samples, {"acc": gravity})
    cal.report.holds.count = len(segments)
    return cal
