"""First design matrix A = ∂f/∂X of [Chow]'s conditions (eq. 15), by hand.

Why by hand: a finite-difference Jacobian re-integrates the gyro of every window once per
parameter (42 times per iteration); here the integration is done once and differentiated.
For dR = E_0·…·E_{K−1}, E_k = Exp(ω_k·Δt_k), a change δω_k turns dR into dR·Exp(δθ) with

    δθ = dRᵀ · Σ_k S_k·δω_k·Δt_k,      S_k = E_0·…·E_k

(first order; the right Jacobian of Exp over one sample step, |ω·Δt| ≲ 0.05 rad, is taken as
the identity — this only slows Gauss-Newton's convergence, never moves its fixed point, since
the misclosures themselves are exact). The per-sample derivatives ∂a/∂X, ∂ω/∂X, ∂m/∂X are
closed-form and linear in a few features of the sample (:func:`coefficients`), so every sum
over samples is taken of the features and multiplied by the coefficients once.

All windows at once (:mod:`apmcal.solvers.joint.trajectory`): with Q_k the frame of sample k in
the first sample's, S_k = Q_sᵀ·Q_{k+1} for a window starting at s, so Σ_{s≤k<e} S_k·δω_k·Δt_k =
Q_sᵀ·ΔΦ with ΔΦ = Σ_{s≤k<e} Q_{k+1}·δω_k·Δt_k, and δθ = Q_eᵀ·ΔΦ. The ZUPT's sum
Σ_k [P_k·f_k]×·Σ_{l<k} S_l·φ_l (P_k = Q_sᵀ·Q_k, f_k the specific force step, φ_l = δω_l·Δt_l)
is rearranged as Q_sᵀ·Σ_l [V_e − V_{l+1}]×·Q_{l+1}·φ_l (V the running velocity sum). Each
window's sums are taken of the features (:func:`window_sums`, one batched matrix product for
all windows of a length), then multiplied by the coefficients.
"""
from __future__ import annotations

import numpy as np

from apmcal.solvers.joint import model as jm
from apmcal.solvers.joint.residuals import window_ends
from apmcal.solvers.joint.trajectory import Trajectory, transposed
from apmcal.solvers.strapdown import hat, midpoint

STEP = 1e-7


def coefficients(x: np.ndarray, mats: dict, free: np.ndarray):
    """The per-sample derivatives ∂a, ∂ω, ∂m as linear maps of a few per-sample features.

    With a = K_a⁻¹(y_a − b_a), ∂a = −K_a⁻¹·(∂b_a + ∂K_a·a); with ω = K_ω⁻¹(y_ω − b_ω − G_ω·a),
    ∂ω = −K_ω⁻¹·(∂b_ω + ∂G_ω·a + G_ω·∂a + ∂K_ω·ω); with m = D⁻¹(y_m − o), ∂m = −D⁻¹·(∂o + ∂D·m).
    Each is linear in the features z_a = [1, a], z_ω = [1, a, ω], z_m = [1, m] of the sample:
    ∂a_k = Σ_f z_a[k, f]·C_a[f] and so on, so that sums of derivatives over samples are sums
    of features (3 + 3·3 + …, not 3 × 42 columns per sample). Only ∂K/∂x of the 3×3 matrices is
    taken by differences (cheap: no samples involved). Each sensor's derivatives are over the
    free parameters it depends on: ∂a over the free accelerometer parameters, ∂ω over the free
    accelerometer then gyro parameters, ∂m over the free magnetometer parameters (the free
    parameters in :data:`~apmcal.solvers.joint.model.NAMES` order are exactly these; every
    other derivative is zero, so it is not computed).

    Parameters
    ----------
    x : (42,) array
        Parameters (:mod:`apmcal.solvers.joint.model`).
    mats : dict
        :func:`apmcal.solvers.joint.model.matrices` of ``x``.
    free : (42,) bool array
        The parameters estimated (p = p_ω + p_m of them).

    Returns
    -------
    tuple
        C_a (4, 3, p_a), C_ω (7, 3, p_ω), C_m (4, 3, p_m) (units of the sensor per parameter,
        the non-constant features' units divided out).
    """
    cols = np.flatnonzero(free)
    pa, pw = _counts(free)
    h = STEP * np.maximum(1.0, np.abs(x[cols]))
    xh = np.repeat(x[None], len(cols), axis=0)
    xh[np.arange(len(cols)), cols] += h
    many = jm.matrices_many(xh)
    dmat = {k: (many[k] - mats[k]) / h.reshape((-1,) + (1,) * np.ndim(mats[k]))
            for k in mats}
    ka_inv, kw_inv = np.linalg.inv(mats["K_a"]), np.linalg.inv(mats["K_w"])
    # C[f] (3, p): f = 0 the constant, then the components of a (and of ω)
    c_a = -ka_inv @ np.concatenate([dmat["b_a"][:pa].T[None],
                                    np.moveaxis(dmat["K_a"][:pa], 0, 2).transpose(1, 0, 2)])
    inner = np.concatenate([dmat["b_w"][:pw].T[None],
                            np.moveaxis(dmat["G_w"][:pw], 0, 2).transpose(1, 0, 2),
                            np.moveaxis(dmat["K_w"][:pw], 0, 2).transpose(1, 0, 2)])
    inner[:4, :, :pa] += mats["G_w"] @ c_a
    c_w = -kw_inv @ inner
    c_m = -np.linalg.inv(mats["D_m"]) @ np.concatenate(
        [dmat["o_m"][pw:].T[None], np.moveaxis(dmat["D_m"][pw:], 0, 2).transpose(1, 0, 2)])
    return c_a, c_w, c_m


def features(v: np.ndarray, *more: np.ndarray) -> np.ndarray:
    """[1, v, more…] per sample: (n, 1 + 3·k).

    Parameters
    ----------
    v, more : (n, 3) arrays

    Returns
    -------
    (n, 1 + 3·(1 + len(more))) array
    """
    out = np.empty((len(v), 4 + 3 * len(more)))
    out[:, 0] = 1.0
    for k, part in enumerate((v,) + more):
        out[:, 1 + 3 * k:4 + 3 * k] = part
    return out


def _apply(z: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Σ_f z[..., f]·c[f]: (..., 3, p) from features (..., F) and coefficients (F, 3, p)."""
    # explicit sizes: with no free parameter of a sensor, c has 0 columns and −1 is ambiguous
    return (z.reshape(-1, z.shape[-1]) @ c.reshape(c.shape[0], c.shape[1] * c.shape[2])).reshape(
        z.shape[:-1] + c.shape[1:])


def _pad(v: np.ndarray) -> np.ndarray:
    """``v`` with a zero row appended: index n, the padding of window rows, adds nothing."""
    return np.concatenate([v, np.zeros((1,) + v.shape[1:])])


def window_sums(rot: np.ndarray, z: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Σ_k rot[k]⊗z[k] over each row of ``steps``: (W, 3, 3·F) with [w, i, j·F + f] =
    Σ_k rot[k, i, j]·z[k, f], the summed features of rot·∂(…) (:func:`_contract` applies the
    coefficients). One batched product (9 × K)·(K × F) per window.

    Parameters
    ----------
    rot : (n+1, 3, 3) array
        Per-sample matrices (row n: padding, any value).
    z : (n+1, F) array
        Per-sample features, row n zero.
    steps : (W, K) int array
        Sample indices of each window, padded with n.

    Returns
    -------
    (W, 3, 3·F) array
    """
    r9 = rot.reshape(len(rot), 9)
    return np.matmul(r9[steps].transpose(0, 2, 1), z[steps]).reshape(len(steps), 3,
                                                                     3 * z.shape[1])


def _contract(y: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Σ_{j,f} y[..., i, j·F + f]·c[f, j, p]: (..., 3, p) from :func:`window_sums`."""
    return y @ c.transpose(1, 0, 2).reshape(c.shape[0] * c.shape[1], c.shape[2])


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
    c_a, c_w, c_m = coefficients(x, tr.mats, free)
    cols = np.flatnonzero(free)
    p = len(cols)
    pa, pw = _counts(free)
    out = {}
    if mc is not None and "mag_datum" in families:
        u = mc / np.linalg.norm(mc, axis=1, keepdims=True)
        # Σ_n u_n·∂m_n / n = Σ_{i,f} (Σ_n u_n[i]·z_m[n, f])·C_m[f, i] / n
        out["mag_datum"] = _widen(np.einsum("if,fip->p", u.T @ features(mc), c_m)[None, None, :]
                                  / len(mc), pw, p)
    if not set(families) - {"mag_datum"}:
        return out
    za, zw = features(a), features(a, tr.w)
    # Ψ_k = Q_{k+1}·δω̄_k·Δt_k (session frame) as features, summed over each window's steps
    zmid = _pad(midpoint(zw) * d.dt[:, None])                         # (n+1, 7)
    q_next = _pad(q[1:])                                              # Q_{k+1}
    bm = d.block_mean
    a_blk = bm @ a
    da_blk = _apply(bm @ za, c_a)                                     # (n_blocks, 3, p_a)
    if "acc_norm" in families:
        u = a_blk / np.linalg.norm(a_blk, axis=1, keepdims=True)
        out["acc_norm"] = _widen(np.einsum("ci,cip->cp", u, da_blk)[:, None, :], 0, p)
    if "zaru" in families:
        out["zaru"] = _widen(_apply(bm @ zw, c_w), 0, p)
    if d.intervals and ("level" in families or "zupt" in families):
        i, j, k0, k1 = d.interval_index.T
        steps = d.steps                                               # (I, K), padded n
        dphi = _contract(window_sums(q_next, zmid, steps), c_w)       # Q_{k0}·Σ S_k·φ_k
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
            # Σ_l [V_e − V_{l+1}]×·Ψ_l = [V_e]×·ΔΦ − Σ_l [V_{l+1}]×·Ψ_l, and Σ_l Q_l·∂f_l
            nxt = np.minimum(steps + 1, len(v) - 1)                   # (padding: z is 0)
            hq = hat(v[nxt]) @ q[nxt]                                 # (I, K, 3, 3)
            cross = np.matmul(hq.reshape(*steps.shape, 9).transpose(0, 2, 1),
                              zmid[steps]).reshape(len(steps), 3, 3 * zmid.shape[1])
            force = window_sums(q, _pad(za * d.dt[:, None]), steps)
            rot = hat(v[k1]) @ dphi - _contract(cross, c_w)
            qt = transposed(q[k0])
            zv = -(qt @ rot)
            zv[..., :pa] += (qt @ _contract(force, c_a)
                             - da_blk[i] * (d.t[k1] - d.t[k0])[:, None, None])
            out["zupt"] = _widen(zv, 0, p)
    if mc is not None and "mag" in families:
        s, e = window_ends(d)
        dr = tr.rotation(s, e)
        rms = np.einsum("wji,wj->wi", dr, mc[s])
        w_cal = mc[e] - rms
        zm = features(mc)
        dmag = tr.mats["D_m"]
        da_m = np.empty((len(s), 3, p))
        # the condition is D_m·w_cal. The inertial parameters act through the rotation:
        # D_m·(−[dRᵀ·m_s]×·δθ), δθ = Q_eᵀ·ΔΦ (3×3 products first, then one per window)
        lead = -(dmag @ hat(rms) @ transposed(q[e]))
        dphi = np.concatenate([window_sums(q_next, zmid, idx[:, :-1]) for idx in d.windows])
        da_m[:, :, :pw] = lead @ _contract(dphi, c_w)
        # the magnetometer's own: D_m·(∂m_e − dRᵀ·∂m_s), plus D_m's own entries (row-major)
        da_m[:, :, pw:] = (_apply(zm[e], dmag @ c_m)
                           - (dmag @ transposed(dr)) @ _apply(zm[s], c_m))
        for c, col in enumerate(cols):
            if col in jm.SLICES_RANGE["D_m"]:
                row, k = divmod(col - jm.SLICES["D_m"].start, 3)
                da_m[:, row, c] += w_cal[:, k]
        out["mag"] = da_m
    return out
