"""First design matrix A = ∂f/∂X of [Chow]'s conditions (eq. 15), by hand.

Why by hand: a finite-difference Jacobian re-integrates the gyro of every window once per
parameter (42 times per iteration); here the integration is done once and differentiated.
For dR = E_0·…·E_{K−1}, E_k = Exp(ω_k·Δt_k), a change δω_k turns dR into dR·Exp(δθ) with

    δθ = dRᵀ · Σ_k S_k·δω_k·Δt_k,      S_k = E_0·…·E_k

(first order; the right Jacobian of Exp over one sample step, |ω·Δt| ≲ 0.05 rad, is taken as
the identity — this only slows Gauss-Newton's convergence, never moves its fixed point, since
the misclosures themselves are exact). The per-sample derivatives ∂a/∂X, ∂ω/∂X, ∂m/∂X come
from forward differences of the closed-form corrections (cheap: no integration).

All windows at once (:mod:`apmcal.solvers.joint.trajectory`): with Q_k the frame of sample k in
the first sample's, S_k = Q_sᵀ·Q_{k+1} for a window starting at s, so Σ_{s≤k<e} S_k·δω_k·Δt_k =
Q_sᵀ·(Φ_e − Φ_s) with the running sum Φ_k = Σ_{l<k} Q_{l+1}·δω_l·Δt_l over the session, and
δθ = Q_eᵀ·(Φ_e − Φ_s). The ZUPT's sum Σ_k [P_k·f_k]×·Σ_{l<k} S_l·φ_l (P_k = Q_sᵀ·Q_k, f_k the
specific force step, φ_l = δω_l·Δt_l) is rearranged as Q_sᵀ·Σ_l [V_e − V_{l+1}]×·Q_{l+1}·φ_l
(V the running velocity sum), again differences of running sums.
"""
from __future__ import annotations

import numpy as np

from apmcal.solvers.joint import model as jm
from apmcal.solvers.joint.residuals import window_ends
from apmcal.solvers.joint.trajectory import Trajectory, running_sum, transposed
from apmcal.solvers.strapdown import hat, midpoint

STEP = 1e-7


def _each(mats: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, 3, p): mats[p] @ v[n] for (p, 3, 3) matrices and (n, 3) vectors, by one BLAS
    product (einsum loops in C here, ten times slower)."""
    return np.tensordot(v, mats, axes=([1], [2])).transpose(0, 2, 1)


def _left(mat: np.ndarray, arr: np.ndarray) -> np.ndarray:
    """(n, 3, p): mat @ arr[n] for one (3, 3) matrix and (n, 3, p) arrays, by one BLAS product."""
    return np.tensordot(mat, arr, axes=([1], [1])).transpose(1, 0, 2)


def sample_derivatives(x: np.ndarray, tr: Trajectory, free: np.ndarray):
    """∂a, ∂ω, ∂m per sample over the free parameters each depends on: ∂a (n, 3, p_a) over the
    free accelerometer parameters, ∂ω (n, 3, p_ω) over the free accelerometer then gyro
    parameters, ∂m (n, 3, p_m) over the free magnetometer parameters (the free parameters in
    :data:`~apmcal.solvers.joint.model.NAMES` order are exactly these: accelerometer, gyro,
    magnetometer; every other derivative is zero, so it is not computed).

    Closed form through the matrices: with a = K_a⁻¹(y_a − b_a), ∂a = −K_a⁻¹·(∂b_a + ∂K_a·a);
    with ω = K_ω⁻¹(y_ω − b_ω − G_ω·a), ∂ω = −K_ω⁻¹·(∂b_ω + ∂G_ω·a + G_ω·∂a + ∂K_ω·ω);
    with m = D⁻¹(y_m − o), ∂m = −D⁻¹·(∂o + ∂D·m). Only ∂K/∂x of the 3×3 matrices is taken
    by differences (cheap: no samples involved).

    Parameters
    ----------
    x : (42,) array
        Parameters (:mod:`apmcal.solvers.joint.model`).
    tr : Trajectory
        The corrected signals at ``x`` (:class:`~apmcal.solvers.joint.trajectory.Trajectory`).
    free : (42,) bool array
        The parameters estimated (p = p_ω + p_m of them).

    Returns
    -------
    tuple
        ∂a (n, 3, p_a), ∂ω (n, 3, p_ω), ∂m (n, 3, p_m) (None without a magnetometer).
    """
    m0 = tr.mats
    a0, w0, mag0 = tr.a, tr.w, tr.mc
    cols = np.flatnonzero(free)
    pa, pw = _counts(free)
    dmat = {k: [] for k in m0}
    for i in cols:
        h = STEP * max(1.0, abs(x[i]))
        xh = x.copy()
        xh[i] += h
        mh = jm.matrices(xh)
        for k in m0:
            dmat[k].append((mh[k] - m0[k]) / h)
    dmat = {k: np.array(v) for k, v in dmat.items()}             # (p, 3) or (p, 3, 3)
    ka_inv, kw_inv = np.linalg.inv(m0["K_a"]), np.linalg.inv(m0["K_w"])
    da = -_left(ka_inv, dmat["b_a"][:pa].T[None] + _each(dmat["K_a"][:pa], a0))
    inner = (dmat["b_w"][:pw].T[None] + _each(dmat["G_w"][:pw], a0)
             + _each(dmat["K_w"][:pw], w0))
    inner[:, :, :pa] += _left(m0["G_w"], da)
    dw = -_left(kw_inv, inner)
    dm = None
    if mag0 is not None:
        dm = -_left(np.linalg.inv(m0["D_m"]),
                    dmat["o_m"][pw:].T[None] + _each(dmat["D_m"][pw:], mag0))
    return da, dw, dm


def _counts(free: np.ndarray) -> tuple[int, int]:
    """(free accelerometer parameters, free accelerometer and gyro parameters)."""
    return int(free[list(jm.ACC_PARAMS)].sum()), int(free[:jm.MAG_PARAMS.start].sum())


def _widen(arr: np.ndarray, lo: int, p: int) -> np.ndarray:
    """``arr`` (..., k) as the columns lo .. lo+k−1 of a (..., p) array of zeros."""
    out = np.zeros(arr.shape[:-1] + (p,))
    out[..., lo:lo + arr.shape[-1]] = arr
    return out


def unit_derivative(v: np.ndarray, dv: np.ndarray):
    """d(v/|v|) = (I − uuᵀ)·dv/|v| for (c, 3) vectors and their (c, 3, p) derivatives;
    returns (that, u).

    Parameters
    ----------
    v : (c, 3) array
    dv : (c, 3, p) array

    Returns
    -------
    du : (c, 3, p) array
    u : (c, 3) array
        The unit vectors.
    """
    n = np.linalg.norm(v, axis=1, keepdims=True)
    u = v / n
    proj = (np.eye(3) - u[:, :, None] * u[:, None, :]) / n[:, :, None]
    return proj @ dv, u


def jacobian(x: np.ndarray, d, families, free: np.ndarray,
             traj: Trajectory | None = None) -> dict[str, np.ndarray]:
    """∂w/∂X of each family: name → (n_c, dim, p) over the free parameters.

    Parameters
    ----------
    x : (42,) array
        Parameters.
    d : JointData
        The session's samples and condition layout (:func:`apmcal.solvers.joint.residuals.layout`).
    families : tuple of str
        The families to differentiate.
    free : (42,) bool array
        The parameters estimated (p of them).
    traj : Trajectory, optional
        :class:`~apmcal.solvers.joint.trajectory.Trajectory` of ``x`` and ``d``, when the
        caller has it.

    Returns
    -------
    dict
        family → (n_c, dim, p) array.
    """
    tr = Trajectory(x, d) if traj is None else traj
    a, mc, q = tr.a, tr.mc, tr.frame
    da, dw, dm = sample_derivatives(x, tr, free)
    cols = np.flatnonzero(free)
    p = len(cols)
    pa, pw = _counts(free)
    # Ψ_k = Q_{k+1}·δω_k·Δt_k per parameter (session frame), and its running sum Φ
    psi = q[1:] @ (midpoint(dw) * d.dt[:, None, None])           # (n, 3, p_ω)
    phi = running_sum(psi)                                          # (n+1, 3, p_ω)
    out = {}
    bm = d.block_mean
    a_blk = bm @ a
    da_blk = (bm @ da.reshape(len(a), -1)).reshape(-1, 3, pa)
    if "acc_norm" in families:
        u = a_blk / np.linalg.norm(a_blk, axis=1, keepdims=True)
        out["acc_norm"] = _widen(np.einsum("ci,cip->cp", u, da_blk)[:, None, :], 0, p)
    if "zaru" in families:
        out["zaru"] = _widen((bm @ dw.reshape(len(dw), -1)).reshape(-1, 3, pw), 0, p)
    if d.intervals and ("level" in families or "zupt" in families):
        i, j, k0, k1 = d.interval_index.T
        dphi = phi[k1] - phi[k0]                                    # Q_{k0}·Σ S_k·φ_k
        if "level" in families:
            dr = tr.rotation(k0, k1)
            dui, ui = unit_derivative(a_blk[i], da_blk[i])
            duj, _ = unit_derivative(a_blk[j], da_blk[j])
            rui = np.einsum("wji,wj->wi", dr, ui)
            dtheta = transposed(q[k1]) @ dphi
            lv = -hat(rui) @ dtheta
            lv[..., :pa] += duj - transposed(dr) @ dui
            out["level"] = _widen(np.einsum("wia,wip->wap", d.level_basis, lv), 0, p)
        if "zupt" in families:
            v = tr.velocity
            # Σ_l [V_e − V_{l+1}]×·Ψ_l = [V_e]×·ΔΦ − Σ_l [V_{l+1}]×·Ψ_l
            cross = running_sum(hat(v[1:]) @ psi)                    # (n+1, 3, p_ω)
            rot = hat(v[k1]) @ dphi - (cross[k1] - cross[k0])
            force = running_sum(q[:-1] @ (da * d.dt[:, None, None]))  # (n+1, 3, p_a)
            qt = transposed(q[k0])
            zv = -(qt @ rot)
            zv[..., :pa] += (qt @ (force[k1] - force[k0])
                             - da_blk[i] * (d.t[k1] - d.t[k0])[:, None, None])
            out["zupt"] = _widen(zv, 0, p)
    if mc is not None and "mag" in families:
        s, e = window_ends(d)
        dr = tr.rotation(s, e)
        dtheta = transposed(q[e]) @ (phi[e] - phi[s])
        rms = np.einsum("wji,wj->wi", dr, mc[s])
        w_cal = mc[e] - rms
        # columns: the inertial parameters through the rotation, the magnetometer's own
        dw_cal = np.concatenate([-hat(rms) @ dtheta, dm[e] - transposed(dr) @ dm[s]], axis=2)
        # the condition is D_m·w_cal: product rule, D_m's own entries row-major
        da_m = tr.mats["D_m"] @ dw_cal
        for c, col in enumerate(cols):
            if col in jm.SLICES_RANGE["D_m"]:
                row, k = divmod(col - jm.SLICES["D_m"].start, 3)
                da_m[:, row, c] += w_cal[:, k]
        out["mag"] = da_m
        if "mag_datum" in families:
            u = mc / np.linalg.norm(mc, axis=1, keepdims=True)
            out["mag_datum"] = _widen(np.einsum("ni,nip->p", u, dm)[None, None, :] / len(mc),
                                      pw, p)
    return out
