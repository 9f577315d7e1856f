"""The gyro's bias during a Ferraris session: a line in time through the holds, and the
motions integrated against the bias held just before and after each ([Oppong] §4.3-4.4).

Integrating each turn against its neighbouring holds, rather than a global b0 + b1·t, removes
what a global line cannot: the horizontal Earth rate, which changes with every pose, and a
random-walking bias (error on the simulated benchmark 1.6e-3 → 5e-4, benchmarks/accuracy_ferraris.py).
"""
from __future__ import annotations

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.rotations import Rotation, integrate_slice, sample_intervals


def fit_gyro_bias(ts, ys, fs=None, *, drift: bool = True, t_ref: float = 0.0):
    """Least squares per axis of ``y = b0 + b1 (t − t_ref) + K_ga f`` ([Oppong] eq. 5 + g-sensitivity).

    Returns b0 (3,), b1 (3,), K_ga (3, 3) or None, the one-sigma of b0 and b1 (residual-scaled
    covariance; white-noise assumption, optimistic for correlated noise) and that of K_ga
    (3, 3) or None.

    Parameters
    ----------
    ts : (n,) array
        Sample times [s].
    ys : (n, 3) array
        Still gyro samples [rad/s].
    fs : (n, 3) array, optional
        Calibrated specific force at each sample [m/s²]; None fits no g-sensitivity.
    drift : bool
        Fit the drift b1 (else zeros).
    t_ref : float
        Reference time of the drift [s].

    Returns
    -------
    b0 : (3,) array
        Bias at ``t_ref`` [rad/s].
    b1 : (3,) array
        Drift [rad/s²].
    kga : (3, 3) array or None
        g-sensitivity K_ga [rad/s per m/s²].
    sb0, sb1 : (3,) array
        One-sigma of b0 [rad/s] and b1 [rad/s²].
    skga : (3, 3) array or None
        One-sigma of K_ga [rad/s per m/s²].

    Raises
    ------
    ApmcalError
        When the design is rank deficient (bias not identifiable).
    """
    cols = [np.ones_like(ts)] + ([ts - t_ref] if drift else [])
    a = np.column_stack(cols + ([fs] if fs is not None else []))
    if np.linalg.matrix_rank(a) < a.shape[1]:
        raise ApmcalError("gyro bias not identifiable from these static holds (need holds spread "
                          "over time for the drift and opposite poses for the g-sensitivity)")
    coef, *_ = np.linalg.lstsq(a, ys, rcond=None)
    res = ys - a @ coef
    dof = max(1, a.shape[0] - a.shape[1])
    cov = np.linalg.inv(a.T @ a)
    s2 = (res ** 2).sum(axis=0) / dof
    sig = np.sqrt(np.outer(np.diag(cov), s2))
    b0, sb0 = coef[0], sig[0]
    b1, sb1 = (coef[1], sig[1]) if drift else (np.zeros(3), np.zeros(3))
    kga, skga = (coef[-3:].T, sig[-3:].T) if fs is not None else (None, None)
    return b0, b1, kga, sb0, sb1, skga


def motions_between_holds(rotation: Rotation, segments) -> list[tuple]:
    """(hold before, hold after) pairs around each motion of ``rotation``, in time order.

    The holds are the static segment ending where the rotation starts, those inside it and the
    one starting where it ends; an empty list when they cannot all be found.

    Parameters
    ----------
    rotation : Rotation
        The turn (sample indices ``i0``, ``i1``).
    segments : list of StaticSegment
        The holds.

    Returns
    -------
    list of (StaticSegment, StaticSegment)
    """
    holds = [s for s in segments if s.i1 <= rotation.i1 + 1 and s.i0 >= rotation.i0 - 1
             or s.i1 == rotation.i0 or s.i0 == rotation.i1]
    holds = sorted({(s.i0, s.i1): s for s in holds}.values(), key=lambda s: s.i0)
    if len(holds) < 2 or holds[0].i1 > rotation.i0 or holds[-1].i0 < rotation.i1:
        return []
    return list(zip(holds[:-1], holds[1:]))


HOLD_EDGE_S = 0.5     # the static detector's window: a hold's edge may still hold motion tails


def _trimmed_hold(t, gyr, seg, keep_start: bool) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """The hold's kept samples without the edge next to the motion: (indices, mean time, mean,
    std error). Samples the segmentation excluded (bumps inside a hold) stay out."""
    idx = seg.kept()
    n_edge = int(np.searchsorted(t[idx], t[idx[0]] + HOLD_EDGE_S))
    n_edge = min(n_edge, len(idx) // 4)
    idx = idx[:len(idx) - n_edge] if keep_start else idx[n_edge:]
    g = gyr[idx]
    return idx, float(t[idx].mean()), g.mean(axis=0), g.std(axis=0, ddof=1) / np.sqrt(len(g))


def integrate_motions(t, gyr, moves, step: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Σ over motions of ∫ (gyr − local bias) dt [rad] and its one-sigma [rad].

    ``step`` [rad/s]: with too little noise to dither it, quantisation errs by the same fraction
    of a step on every sample of a steady turn, so its error is taken as uniform over one step,
    times the motion time, and the same in every motion (added linearly: step·ΣT/√12).

    Each motion is integrated from the trimmed end of the hold before it to the trimmed start
    of the hold after it (:data:`HOLD_EDGE_S` given back to the motion, so slow tails are not
    lost), against a bias linear in time between the two trimmed holds' means.

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    gyr : (n, 3) array
        Gyro samples [rad/s].
    moves : list of (StaticSegment, StaticSegment)
        From :func:`motions_between_holds`.
    step : float
        Quantisation step of the gyro samples [rad/s].

    Returns
    -------
    total : (3,) array
        The integral [rad].
    sigma : (3,) array
        Its one-sigma [rad].
    """
    total, var, moving_s = np.zeros(3), np.zeros(3), 0.0
    for before, after in moves:
        sa, ta, ba, ea = _trimmed_hold(t, gyr, before, keep_start=True)
        sb, tb, bb, eb = _trimmed_hold(t, gyr, after, keep_start=False)
        sl = slice(sa[-1] + 1, sb[0])
        ts = t[sl]
        if ts.size == 0:
            continue
        frac = ((ts - ta) / (tb - ta))[:, None]
        dt = sample_intervals(ts)
        total += integrate_slice(ts, gyr[sl] - ((1 - frac) * ba + frac * bb))
        noise = 0.5 * (before.gyr_std + after.gyr_std)
        var += (0.5 * np.hypot(ea, eb) * dt.sum()) ** 2 + noise ** 2 * (dt ** 2).sum()
        moving_s += dt.sum()
    return total, np.sqrt(var + (step * moving_s / np.sqrt(12.0)) ** 2)
