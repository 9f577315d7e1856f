"""Out-of-sample check of a calibration, as [Chow] §5 validates one: the orientation change
integrated from the calibrated gyro between two still poses against the one the calibrated
accelerometer (+ compass) gives at those poses.

At each still pose the reference attitude is TRIAD's: down = −a/|a| (a: specific force at
rest), east = down × m, north = east × down, so that C = [north east down] holds the NED axes
in the sensor frame; the change from pose i to pose j is C_i·C_jᵀ (sensor frame j → i). The
gyro's is dR = Π Exp(ω_k·Δt_k) (midpoint rate, as in :mod:`apmcal.solvers.joint.residuals`).
The error is the angle of dR_gyroᵀ·dR_ref [deg]. Without a compass only the tilt can be
compared: the angle between a_j and dR_gyroᵀ·a_i.

The gyro bias is re-measured on the checked session's own still poses (what ArduPilot does at
every boot, INS_GYROFFS): a turn-on bias is not part of what a calibration can carry from one
session to the next, and every method gets the same treatment.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.solvers.strapdown import midpoint, so3_exp

BLOCK_S = 1.0     # reference: mean over this much of each pose next to the turn [s]


@dataclass
class PosePair:
    """Two consecutive still poses: reference sample ranges and the centre samples k0, k1.

    Attributes
    ----------
    ref_i, ref_j : int array
        Sample indices of the last ``BLOCK_S`` of pose i and the first of pose j.
    k0, k1 : int
        Centre samples of ``ref_i`` and ``ref_j``: the orientation change is integrated
        between them.
    """

    ref_i: np.ndarray
    ref_j: np.ndarray
    k0: int
    k1: int


def pose_pairs(t: np.ndarray, holds) -> list[PosePair]:
    """Consecutive still poses (StaticSegments in time order) as :class:`PosePair`.

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    holds : list of StaticSegment
        In time order.

    Returns
    -------
    list of PosePair
        One fewer than the holds.
    """
    pairs = []
    for h0, h1 in zip(holds, holds[1:]):
        a, b = h0.kept(), h1.kept()
        ri = a[t[a] >= t[a[-1]] - BLOCK_S]
        rj = b[t[b] <= t[b[0]] + BLOCK_S]
        pairs.append(PosePair(ri, rj, int(ri[ri.size // 2]), int(rj[rj.size // 2])))
    return pairs


def corrected(cal, t, acc, gyr, mag, holds):
    """Calibrated specific force, rate (bias re-measured on ``holds``) and field, or the raw
    samples for a sensor the calibration lacks. The gyro's g-sensitivity, when the calibration
    has one, acts on the calibrated specific force (:class:`SensorCalibration` convention).

    Parameters
    ----------
    cal : Calibration
    t : (n,) array, s
    acc : (n, 3) array, m/s²
    gyr : (n, 3) array, rad/s
    mag : (n, 3) array, mGauss, or None
    holds : list of StaticSegment

    Returns
    -------
    a : (n, 3) array, m/s²
    w : (n, 3) array, rad/s
    m : (n, 3) array, mGauss, or None
    """
    a = cal.apply("acc", acc, t) if "acc" in cal.sensors else np.asarray(acc, float)
    w = cal.sensors["gyr"].apply(gyr, t, force=a) if "gyr" in cal.sensors else np.asarray(gyr, float)
    still = np.concatenate([h.kept() for h in holds])
    w = w - w[still].mean(axis=0)
    m = None
    if mag is not None:
        m = cal.apply("mag", mag, t) if "mag" in cal.sensors else np.asarray(mag, float)
    return a, w, m


def triad(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """C = [north east down] in the sensor frame from specific force a and field m.

    Parameters
    ----------
    a : (3,) array
        Specific force at rest [m/s²].
    m : (3,) array
        Magnetic field [mGauss].

    Returns
    -------
    (3, 3) array
        Columns north, east, down (unit vectors).
    """
    down = -a / np.linalg.norm(a)
    east = np.cross(down, m)
    east /= np.linalg.norm(east)
    return np.column_stack([np.cross(east, down), east, down])


def rotation_angle_deg(r: np.ndarray) -> float:
    """Angle [deg] of a rotation matrix (via the chord, accurate near 0).

    Parameters
    ----------
    r : (3, 3) array

    Returns
    -------
    float
        0..180 deg.
    """
    chord = np.linalg.norm(r - np.eye(3)) / (2 * np.sqrt(2))
    return float(np.degrees(2 * np.arcsin(min(1.0, chord))))


def orientation_errors(cal, t, acc, gyr, mag, holds, pairs=None) -> dict:
    """Per pose pair: the angle turned and the error of the gyro's orientation change [deg].

    Parameters
    ----------
    cal : Calibration
        Sensors acc, gyr, mag as available; identity for "raw".
    t : (n,) array, s
    acc : (n, 3) array, m/s²
    gyr : (n, 3) array, rad/s
    mag : (n, 3) array, mGauss, or None
        Raw samples of the session checked (not the one fitted).
    holds : list of StaticSegment
        Its still periods.
    pairs : list of PosePair, optional
        :func:`pose_pairs` of them by default.

    Returns
    -------
    dict
        "turn_deg" and "error_deg" (arrays over pairs) and "kind" ("attitude" with a
        compass, "tilt" without).
    """
    t = np.asarray(t, float)
    pairs = pose_pairs(t, holds) if pairs is None else pairs
    a, w, m = corrected(cal, t, acc, gyr, mag, holds)
    dt = np.append(np.diff(t), 0.0)
    step = so3_exp(midpoint(w) * dt[:, None])
    turn, err = [], []
    for p in pairs:
        dr = np.eye(3)
        for k in range(p.k0, p.k1):
            dr = dr @ step[k]
        ai, aj = a[p.ref_i].mean(axis=0), a[p.ref_j].mean(axis=0)
        if m is None:
            moved = dr.T @ ai
            cos = moved @ aj / (np.linalg.norm(moved) * np.linalg.norm(aj))
            err.append(float(np.degrees(np.arccos(np.clip(cos, -1, 1)))))
        else:
            ci, cj = triad(ai, m[p.ref_i].mean(axis=0)), triad(aj, m[p.ref_j].mean(axis=0))
            err.append(rotation_angle_deg(dr.T @ (ci @ cj.T)))
        turn.append(rotation_angle_deg(dr))
    return {"turn_deg": np.array(turn), "error_deg": np.array(err),
            "kind": "tilt" if m is None else "attitude"}
