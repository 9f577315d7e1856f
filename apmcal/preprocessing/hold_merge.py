"""Joining still runs that are one hold split by a short knock.

A run is continued by the next one when the mean specific force is unchanged and the gyro turns
less than a small angle across the gap; the gap's samples are then excluded from the hold's
statistics (:func:`apmcal.preprocessing.static.find_static_segments`).
"""
from __future__ import annotations

import numpy as np

MERGE_ANGLE_DEG = 2.0   # runs of one hold: mean specific forces and gap turn within this angle


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle [deg] between the vectors ``a`` and ``b`` (each shape (3,), any common unit)."""
    c = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def same_hold(t, acc, gyr, a, b, *, max_angle_deg, gyr_tol, gyr_unit_rad, max_step):
    """True when runs ``a`` and ``b`` (i0, i1) are one hold interrupted by a disturbance.

    Same orientation before and after: mean specific force within ``max_angle_deg``, mean rates
    within ``gyr_tol`` (the gyro noise threshold), and the bias-corrected gyro integrated over
    the gap turns less than ``max_angle_deg`` — a quarter turn about the vertical ([Oppong] §3.1)
    leaves the accelerometer unchanged and must still split the holds.

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    acc : numpy.ndarray, shape (n, 3)
        Accelerometer, any unit.
    gyr : numpy.ndarray, shape (n, 3), or None
        Gyroscope in units of ``gyr_unit_rad`` rad/s.
    a, b : tuple of int
        Half-open index ranges (i0, i1) of the two runs, ``a`` first.
    max_angle_deg, gyr_tol, gyr_unit_rad, max_step
        See :func:`merge_holds`.

    Returns
    -------
    bool
    """
    if angle_deg(acc[a[0]:a[1]].mean(axis=0), acc[b[0]:b[1]].mean(axis=0)) >= max_angle_deg:
        return False
    if gyr is None:
        return True
    ga, gb = gyr[a[0]:a[1]].mean(axis=0), gyr[b[0]:b[1]].mean(axis=0)
    if np.linalg.norm(ga - gb) > gyr_tol:
        return False
    g0, g1 = a[1] - 1, b[0] + 1            # last still sample .. first still sample
    turn = integrate_rate(t[g0:g1], gyr[g0:g1] - 0.5 * (ga + gb), max_step)
    return float(np.degrees(np.linalg.norm(turn) * gyr_unit_rad)) < max_angle_deg


def integrate_rate(t: np.ndarray, rate: np.ndarray, max_step: float = np.inf) -> np.ndarray:
    """Trapezoidal integral of (n, 3) ``rate`` over ``t`` [rate unit × s], skipping steps longer
    than ``max_step`` [s] (a logging hole: the turn inside it is unknown, not rate × hole).

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    rate : numpy.ndarray, shape (n, 3)
        Angular rate, any unit (e.g. rad/s).
    max_step : float, optional
        Longest step integrated over [s].

    Returns
    -------
    numpy.ndarray, shape (3,)
        Integrated turn [rate unit × s], e.g. rad.
    """
    if t.size < 2:
        return np.zeros(rate.shape[1])
    h = np.diff(t)
    h = np.where(h > max_step, 0.0, h)
    return (0.5 * (rate[1:] + rate[:-1]) * h[:, None]).sum(axis=0)


def merge_holds(t, acc, gyr, runs, *, merge_gap: float, max_angle_deg: float = MERGE_ANGLE_DEG,
                gyr_tol: float = np.inf, gyr_unit_rad: float = 1.0, max_step: float = np.inf):
    """Join consecutive still runs that are one hold split by short disturbances.

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    acc : numpy.ndarray, shape (n, 3)
        Accelerometer, any unit.
    gyr : numpy.ndarray, shape (n, 3), or None
        Gyroscope in units of ``gyr_unit_rad`` rad/s.
    runs : list of (i0, i1)
        Half-open still runs in time order.
    merge_gap : float
        Longest gap [s] (disturbance or logging hole) bridged.
    max_angle_deg, gyr_tol, gyr_unit_rad
        See :func:`find_static_segments`.
    max_step : float
        Sample steps longer than this [s] are logging holes, left out of the gap's turn.

    Returns
    -------
    list of (i0, i1, excluded)
        ``excluded`` are the half-open gap ranges inside [i0, i1) whose samples are left out
        of the segment's statistics.
    """
    out: list[tuple[int, int, list[tuple[int, int]]]] = []
    for r in runs:
        if out:
            i0, i1, exc = out[-1]
            last = (exc[-1][1] if exc else i0, i1)          # the previous run's own samples
            if (t[r[0]] - t[i1 - 1] <= merge_gap
                    and same_hold(t, acc, gyr, last, r, max_angle_deg=max_angle_deg,
                                   gyr_tol=gyr_tol, gyr_unit_rad=gyr_unit_rad,
                                   max_step=max_step)):
                out[-1] = (i0, r[1], exc + ([(i1, r[0])] if r[0] > i1 else []))
                continue
        out.append((r[0], r[1], []))
    return out
