"""Methods that work on static holds found beforehand: the one-position method on the longest
level hold (seed 002 §5) and the accelerometer ellipsoid fit of the hold means (seed 000)."""
from __future__ import annotations

import numpy as np

from apmcal.constants import STANDARD_GRAVITY
from apmcal.errors import ApmcalError
from apmcal.solvers.result import Calibration

LEVEL_TOLERANCE_DEG = 10.0  # seed 002 §3.2 levels the platform with a plumb line
MIN_ELLIPSOID_HOLDS = 7     # 9 parameters; the robust fit's prior carries the rest (seed 000)
MIN_ORIENTATIONS = 4        # holds ≥ 30° apart: fewer leave the ellipsoid undetermined


def tilt_from_level_deg(acc_mean: np.ndarray) -> float:
    """Angle [deg] between the mean specific force and a level vehicle's (0, 0, −g)."""
    up = -np.asarray(acc_mean, dtype=float) / np.linalg.norm(acc_mean)
    return float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))


def longest_level_hold(segments):
    """The longest hold within :data:`LEVEL_TOLERANCE_DEG` of level, or a clear error."""
    level = [s for s in segments if tilt_from_level_deg(s.acc_mean) <= LEVEL_TOLERANCE_DEG]
    if not level:
        tilts = ", ".join(f"{tilt_from_level_deg(s.acc_mean):.0f}°" for s in segments[:5])
        found = f" (still periods found, tilted {tilts})" if segments else ""
        raise ApmcalError("one-position method: no level still period found; hold the vehicle "
                          f"level (z down, x north) for about a minute{found}")
    return max(level, key=lambda s: s.end - s.start)


def one_position_on_holds(t, acc, gyr, segments, lat_deg, lon_deg) -> Calibration:
    """Seed 002's one-position method on the longest level hold.

    The paper's recipe runs, but one pose cannot separate accelerometer bias from tilt (see the
    identifiability lines in the report), so the accelerometer is marked undetermined and its
    offsets are never sent to a vehicle.
    """
    from apmcal.solvers.one_position import one_position_calibration

    still = longest_level_hold(segments)
    part = still.kept()
    cal = one_position_calibration(t[part], acc[part], None if gyr is None else gyr[part],
                                   lat_deg=lat_deg, lon_deg=lon_deg)
    cal.report["static_segment_s"] = [still.start, still.end]
    cal.report["undetermined"] = {"acc": "one static pose cannot separate accelerometer "
                                  "bias from tilt (see the identifiability report)"}
    return cal


def distinct_orientations(segments, min_chord: float = 0.5) -> int:
    """Number of hold orientations whose mean accelerometer vectors are at least ``min_chord``
    field radii apart (0.5 radius ≈ 30°), by greedy clustering.

    The radius is g when the samples are in m/s²; for raw counts (large offsets, unknown scale)
    it is half the largest distance between hold means, provided that distance stands well
    above the holds' own noise.
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
    """Robust ellipsoid fit (seed 000) of the hold means [m/s²]; gyro offset from held samples."""
    from apmcal.solvers.ellipsoid import ellipsoid_calibration

    n_orient = distinct_orientations(segments)
    if len(segments) < MIN_ELLIPSOID_HOLDS or n_orient < MIN_ORIENTATIONS:
        raise ApmcalError(f"ellipsoid fit needs at least {MIN_ELLIPSOID_HOLDS} static holds in "
                          f"{MIN_ORIENTATIONS} or more orientations; found {len(segments)} holds "
                          f"in {n_orient} orientation(s)")
    samples = {"acc": np.array([s.acc_mean for s in segments])}
    if gyr is not None:
        samples["gyr"] = np.concatenate([gyr[s.kept()] for s in segments])
    cal = ellipsoid_calibration(samples, {"acc": gravity})
    cal.report["static_segments"] = len(segments)
    return cal
