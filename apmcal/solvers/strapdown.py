"""Strap-down integration of a gyro over many windows at once ([Chow] eq. 8 and 11).

Rotations as 3×3 matrices: the rate over step k is the midpoint of samples k and k+1, the step
rotation Exp(ω·Δt) (Rodrigues), and the rotation of a window the product of its steps,
computed for all windows of a batch together (numpy calls scale with log₂ of the window
length, not with it).
"""
from __future__ import annotations

import numpy as np


def so3_exp(v: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors v (..., 3) [rad] (Rodrigues).

    Parameters
    ----------
    v : (..., 3) array
        Rotation vectors [rad].

    Returns
    -------
    (..., 3, 3) array
    """
    th2 = np.sum(v * v, axis=-1)[..., None, None]
    th = np.sqrt(th2)
    small = th2 < 1e-12
    a = np.where(small, 1.0 - th2 / 6, np.sin(th) / np.where(small, 1.0, th))
    b = np.where(small, 0.5 - th2 / 24, (1 - np.cos(th)) / np.where(small, 1.0, th2))
    h = hat(v)
    return np.eye(3) + a * h + b * (h @ h)


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices [v]× (..., 3, 3) with [v]×·u = v × u.

    Parameters
    ----------
    v : (..., 3) array

    Returns
    -------
    (..., 3, 3) array
    """
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], axis=-2)


def prefix_products(e: np.ndarray) -> np.ndarray:
    """Inclusive products S_k = E_0·E_1·…·E_k along axis 1 of (W, K, 3, 3), in log2(K)
    batched steps (Hillis-Steele scan; a loop over K would cost K numpy calls).

    Parameters
    ----------
    e : (W, K, 3, 3) array

    Returns
    -------
    (W, K, 3, 3) array
        S_k in place of E_k (``e`` itself is not changed).
    """
    s = e.copy()
    shift = 1
    while shift < s.shape[1]:
        s[:, shift:] = s[:, :-shift] @ s[:, shift:]
        shift *= 2
    return s


def product(e: np.ndarray) -> np.ndarray:
    """E_0·E_1·…·E_{K−1} of (W, K, 3, 3) by pairwise reduction (K − 1 products per row).

    Parameters
    ----------
    e : (W, K, 3, 3) array

    Returns
    -------
    (W, 3, 3) array
    """
    while e.shape[1] > 1:
        if e.shape[1] % 2:
            e = np.concatenate([e, np.broadcast_to(np.eye(3), (e.shape[0], 1, 3, 3))], axis=1)
        e = e[:, 0::2] @ e[:, 1::2]
    return e[:, 0]


def integrate(step_rot: np.ndarray, idx: np.ndarray, force: np.ndarray | None = None):
    """Strap-down integration ([Chow] eq. 8 and 11) over index rows ``idx`` (W, K+1).

    ``step_rot`` (n+1, 3, 3) holds Exp(ω_k·Δt_k) of every sample and the identity last;
    rows are padded with that last index (n). Returns dR (W, 3, 3) from the frame at
    idx[:, 0] to the one at the end of the row, and, when ``force`` (n+1, 3) = a_k·Δt_k (zero
    last) is given, Σ_k dR(0, k)·force_k (the Δv of eq. 11).

    Parameters
    ----------
    step_rot : (n+1, 3, 3) array
        Exp(ω_k·Δt_k), identity last.
    idx : (W, K+1) int array
        Sample indices of each row, padded with n.
    force : (n+1, 3) array, optional
        a_k·Δt_k [m/s], zero last.

    Returns
    -------
    dR : (W, 3, 3) array
    dv : (W, 3) array or None
        Δv [m/s], None without ``force``.
    """
    if force is None:
        return product(step_rot[idx[:, :-1]]), None
    s = prefix_products(step_rot[idx[:, :-1]])
    f = force[idx[:, :-1]]
    dv = f[:, 0] + np.einsum("wkij,wkj->wi", s[:, :-1], f[:, 1:])
    return s[:, -1], dv


def midpoint(w: np.ndarray) -> np.ndarray:
    """Rate over the step from sample k to k+1, (ω_k + ω_{k+1})/2 (the last sample's own).

    The rectangle rule with ω_k would rotate half a sample early: at 3 rad/s and 100 Hz that
    alone leaves 0.1 m/s in a noise-free ZUPT and several mGauss in the magnetometer windows.

    Parameters
    ----------
    w : (n, 3) array
        Angular rate [rad/s].

    Returns
    -------
    (n, 3) array
        Step rates [rad/s].
    """
    out = np.array(w, dtype=float, copy=True)
    out[:-1] += w[1:]
    out[:-1] *= 0.5
    return out
