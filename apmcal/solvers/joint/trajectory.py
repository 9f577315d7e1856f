"""The calibrated signals and the session's strap-down attitude, integrated once ([Chow] eq. 8, 11).

Every condition of :mod:`apmcal.solvers.joint.residuals` compares the sensor frames at two
samples s < e (a magnetometer window's ends, a moving interval's ends) through the rotation
dR(s, e) = E_s·E_{s+1}·…·E_{e−1}, E_k = Exp(ω̄_k·Δt_k) the step from sample k to k+1 (ω̄ the
midpoint rate, :func:`apmcal.solvers.strapdown.midpoint`). Multiplying the steps of every
window and interval separately handles each sample four times (three magnetometer window
lengths and the intervals) with log₂(window) batched products each; instead the frame of every
sample relative to the first one is integrated once,

    Q_0 = I,   Q_{k+1} = Q_k·E_k,        so that  dR(s, e) = Q_sᵀ·Q_e,

and the velocity change of eq. 11 a difference of running sums of quantities taken into the
first sample's frame: Σ_{s≤k<e} dR(s, k)·a_k·Δt_k = Q_sᵀ·(V_e − V_s) with
V_k = Σ_{l<k} Q_l·a_l·Δt_l. The same frames give the design matrix
(:mod:`apmcal.solvers.joint.jacobian`, which sums each window's features directly) and the
condition covariance (:mod:`apmcal.solvers.joint.covariance`) without a loop over windows.

Rounding: the products are formed as unit quaternions (Hamilton convention), each held as the
pair of complex numbers q = (w + x·i) + (y + z·i)·j (Cayley-Dickson: four complex products per
composition, a few numpy calls where the 16 real products take 28), in a chunked
Hillis-Steele scan (log₂ of the chunk length batched steps over all samples, then the chunk
totals). Q_sᵀ·Q_e agrees with the product of the window's own step matrices to 1e-12 and
better (tests/test_joint_trajectory.py, 3 000 steps of up to 0.1 rad); the running velocity
sum's cancellation costs ~1e-16 of its largest value (a few thousand m/s over a 250 s
session), far below any sensor noise.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np

from apmcal.solvers.joint.model import correct_acc, correct_gyr, correct_mag, matrices
from apmcal.solvers.strapdown import midpoint

SCAN_CHUNK = 32          # samples per chunk of the running product (any power of two works)


def quat_exp(v: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors ``v`` (n, 3) [rad], as complex pairs (2, n).

    Parameters
    ----------
    v : (n, 3) array
        Rotation vectors [rad].

    Returns
    -------
    (2, n) complex array
        (w + x·i, y + z·i) with w = cos(|v|/2), (x, y, z) = v·sin(|v|/2)/|v| (the series
        1/2 − |v|²/48 below 1e-6 rad).
    """
    th = np.sqrt(np.einsum("ni,ni->n", v, v))
    small = th < 1e-6
    s = np.where(small, 0.5 - th ** 2 / 48, np.sin(th / 2) / np.where(small, 1.0, th))
    out = np.empty((2, len(v)), complex)
    out[0].real = np.cos(th / 2)
    out[0].imag = v[:, 0] * s
    out[1].real = v[:, 1] * s
    out[1].imag = v[:, 2] * s
    return out


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton products p⊗q (R(p⊗q) = R(p)·R(q)) of quaternions held as complex pairs (2, ...).

    With p = a + b·j and q = c + d·j (a, b, c, d complex, j·c = c̄·j):
    p⊗q = (a·c − b·d̄) + (a·d + b·c̄)·j.

    Parameters
    ----------
    p, q : (2, ...) complex arrays
        Broadcastable.

    Returns
    -------
    (2, ...) complex array
    """
    a, b = p
    c, d = q
    out = np.empty(np.broadcast_shapes(p.shape, q.shape), complex)
    np.multiply(a, c, out=out[0])
    out[0] -= b * np.conj(d)
    np.multiply(a, d, out=out[1])
    out[1] += b * np.conj(c)
    return out


def _scan(s: np.ndarray) -> None:
    """Inclusive running products along axis 1 of (2, c, ...), in place (Hillis-Steele)."""
    shift = 1
    while shift < s.shape[1]:
        s[:, shift:] = quat_mul(s[:, :-shift], s[:, shift:])
        shift *= 2


def running_product(q: np.ndarray) -> np.ndarray:
    """Inclusive running products q_0⊗q_1⊗…⊗q_k of (2, n) quaternions (complex pairs).

    Chunks of :data:`SCAN_CHUNK` are scanned side by side (laid out position-major, so that
    each step works on contiguous memory), then the running product of the chunk totals is
    scanned and applied in front of each chunk (about 6 products per sample instead of
    log₂ n).

    Parameters
    ----------
    q : (2, n) complex array

    Returns
    -------
    (2, n) complex array
    """
    n = q.shape[1]
    m = -(-n // SCAN_CHUNK)
    flat = np.zeros((2, m * SCAN_CHUNK), complex)
    flat[0] = 1.0
    flat[:, :n] = q
    s = np.ascontiguousarray(flat.reshape(2, m, SCAN_CHUNK).transpose(0, 2, 1))   # (2, c, m)
    _scan(s)
    totals = s[:, -1:, :].transpose(0, 2, 1).copy()                                # (2, m, 1)
    _scan(totals)
    s[:, :, 1:] = quat_mul(totals[:, None, :-1, 0], s[:, :, 1:])
    return s.transpose(0, 2, 1).reshape(2, -1)[:, :n]


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of unit quaternions held as complex pairs (2, n).

    Parameters
    ----------
    q : (2, n) complex array

    Returns
    -------
    (n, 3, 3) array
    """
    w, x, y, z = q[0].real, q[0].imag, q[1].real, q[1].imag
    xx, yy, zz = 2 * x * x, 2 * y * y, 2 * z * z
    xy, xz, yz = 2 * x * y, 2 * x * z, 2 * y * z
    wx, wy, wz = 2 * w * x, 2 * w * y, 2 * w * z
    out = np.empty((q.shape[1], 3, 3))
    out[:, 0, 0] = 1 - (yy + zz)
    out[:, 0, 1] = xy - wz
    out[:, 0, 2] = xz + wy
    out[:, 1, 0] = xy + wz
    out[:, 1, 1] = 1 - (xx + zz)
    out[:, 1, 2] = yz - wx
    out[:, 2, 0] = xz - wy
    out[:, 2, 1] = yz + wx
    out[:, 2, 2] = 1 - (xx + yy)
    return out


def frames(theta: np.ndarray) -> np.ndarray:
    """Q_k (n+1, 3, 3): the frame of sample k in the first sample's, from the step rotation
    vectors θ_k = ω̄_k·Δt_k [rad] (n, 3); Q_0 = I, Q_{k+1} = Q_k·Exp(θ_k).

    Parameters
    ----------
    theta : (n, 3) array
        Step rotation vectors [rad].

    Returns
    -------
    (n+1, 3, 3) array
    """
    q = np.empty((2, len(theta) + 1), complex)
    q[:, 0] = (1.0, 0.0)
    q[:, 1:] = running_product(quat_exp(theta))
    return quat_matrix(q)


def transposed(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) → the transposed matrices (a view)."""
    return np.swapaxes(r, -1, -2)


def running_sum(v: np.ndarray) -> np.ndarray:
    """Exclusive running sum along axis 0: out[k] = Σ_{l<k} v[l], one row longer than ``v``.

    Parameters
    ----------
    v : (n, ...) array

    Returns
    -------
    (n+1, ...) array
    """
    out = np.zeros((v.shape[0] + 1,) + v.shape[1:])
    np.cumsum(v, axis=0, out=out[1:])
    return out


class Trajectory:
    """The corrected signals and the session's attitude at one parameter vector.

    Parameters
    ----------
    x : (42,) array
        Parameters (:mod:`apmcal.solvers.joint.model`).
    d : JointData
        The session (:func:`apmcal.solvers.joint.residuals.layout`).

    Attributes
    ----------
    mats : dict
        :func:`apmcal.solvers.joint.model.matrices` of ``x``.
    a : (n, 3) array
        True specific force [m/s²], accelerometer frame.
    w : (n, 3) array
        True angular rate [rad/s].
    mc : (n, 3) array or None
        True field [mGauss].
    frame : (n+1, 3, 3) array
        Q_k, sample k's frame in the first sample's (:func:`frames`; the last two equal, the
        last sample's step being zero).
    """

    def __init__(self, x: np.ndarray, d):
        self.mats = matrices(x)
        self.a = correct_acc(d.acc, self.mats)
        self.w = correct_gyr(d.gyr, self.a, self.mats)
        self.mc = correct_mag(d.mag, self.mats) if d.mag is not None else None
        self.frame = frames(midpoint(self.w) * d.dt[:, None])
        self._dt = d.dt

    def rotation(self, s: np.ndarray, e: np.ndarray) -> np.ndarray:
        """dR(s, e) = Q_sᵀ·Q_e (W, 3, 3): the frame at sample e in the frame at sample s.

        Parameters
        ----------
        s, e : (W,) int arrays
            Sample indices.

        Returns
        -------
        (W, 3, 3) array
        """
        return transposed(self.frame[s]) @ self.frame[e]

    @cached_property
    def velocity(self) -> np.ndarray:
        """V (n+1, 3): V_k = Σ_{l<k} Q_l·a_l·Δt_l [m/s], in the first sample's frame."""
        return running_sum(np.einsum("nij,nj->ni", self.frame[:-1], self.a * self._dt[:, None]))

    def delta_v(self, s: np.ndarray, e: np.ndarray) -> np.ndarray:
        """Σ_{s≤k<e} dR(s, k)·a_k·Δt_k [m/s] (W, 3), in the frame at s ([Chow] eq. 11).

        Parameters
        ----------
        s, e : (W,) int arrays
            Sample indices.

        Returns
        -------
        (W, 3) array
        """
        v = self.velocity
        return np.einsum("wji,wj->wi", self.frame[s], v[e] - v[s])
