"""The misclosures' covariance B·C_l·Bᵀ ([Chow] eq. 14-15) and the whitening it gives.

Sources of noise, each white with the per-sample σ measured on the still blocks:

* the accelerometer's block means δā_b (σ_a²/n_b per axis): shared by the static norm of the
  block, the levelling and the ZUPT of the intervals that start or end there — these
  correlations are kept (one dense matrix over the inertial conditions), since the same
  block noise would otherwise count up to three times;
* the gyro's block means (ZARU) and the magnetometer samples, independent per condition;
* the gyro samples of an interval, which move both its levelling and its ZUPT: a rate error
  n_k·Δt_k at step k turns the frame by S_k·n_k·Δt_k (S_k the integrated rotation), moving the
  levelling by −Eᵀ·dRᵀ·[û_i]×·S_k·n_k·Δt_k and the ZUPT by −[C_k]×·S_k·n_k·Δt_k, with
  C_k = Σ_{l>k} P_l·a_l·Δt_l the velocity still to come (kept, per interval);
* the accelerometer samples of an interval (ZUPT only): σ_a²·ΣΔt².

Left out: the gyro noise the magnetometer windows share with the levelling and ZUPT (small
next to the magnetometer's own noise there), and the half blocks an interval shares with the
ZARU of its end poses.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular

from apmcal.solvers.joint.model import correct_acc, correct_gyr, correct_mag, matrices
from apmcal.solvers.joint.residuals import DIM
from apmcal.solvers.strapdown import hat, midpoint, prefix_products, product, so3_exp

INERTIAL = ("acc_norm", "zaru", "level", "zupt")
WEIGHT_FLOOR = 1e-8        # a rejected condition (weight 0) gets this weight: its variance ×1e8


def inertial_covariance(x, d, families, rows) -> np.ndarray:
    """Dense covariance of the inertial misclosures, rows laid out family by family in
    :data:`INERTIAL` order, each condition's components together.

    Parameters
    ----------
    x : (42,) array
        Parameters (:mod:`apmcal.solvers.joint.model`).
    d : JointData
        The session's samples and condition layout (:func:`apmcal.solvers.joint.residuals.layout`).
    families : tuple of str
        The condition families in use.
    rows : (I, K+1) int array
        Moving intervals' sample indices (:func:`apmcal.solvers.joint.residuals.interval_rows`).

    Returns
    -------
    (N, N) array
        N = Σ over the inertial families of conditions × dim, in the families' units squared
        ([m/s²]², [rad/s]², [rad]², [m/s]²).
    """
    m = matrices(x)
    a = correct_acc(d.acc, m)
    sa2, sw2 = d.noise["acc"] ** 2, d.noise["gyr"] ** 2
    nb = len(d.blocks)
    var_blk = sa2 / np.array([b.size for b in d.blocks], float)
    a_blk = d.block_mean @ a
    fam = [f for f in INERTIAL if f in families]
    size = {"acc_norm": nb, "zaru": 3 * nb, "level": 2 * len(d.intervals),
            "zupt": 3 * len(d.intervals)}
    start, k = {}, 0
    for f in fam:
        start[f], k = k, k + size[f]
    cov = np.zeros((k, k))
    b_a = np.zeros((k, 3 * nb))                   # ∂w/∂(block means of the accelerometer)
    if "acc_norm" in fam:
        u = a_blk / np.linalg.norm(a_blk, axis=1, keepdims=True)
        for b in range(nb):
            b_a[start["acc_norm"] + b, 3 * b:3 * b + 3] = u[b]
    if "zaru" in fam:
        r = np.arange(start["zaru"], start["zaru"] + 3 * nb)
        cov[r, r] += np.repeat(sw2 * var_blk / sa2, 3)
    if d.intervals and ("level" in fam or "zupt" in fam):
        w = correct_gyr(d.gyr, a, m)
        step = so3_exp(np.vstack([midpoint(w) * d.dt[:, None], np.zeros((1, 3))]))
        s = prefix_products(step[rows[:, :-1]])                        # S_k (I, K, 3, 3)
        dt = np.append(d.dt, 0.0)[rows[:, :-1]]                          # (I, K)
        pk = np.concatenate([np.broadcast_to(np.eye(3), (len(rows), 1, 3, 3)), s[:, :-1]], 1)
        pf = np.einsum("wkij,wkj->wki", pk, np.vstack([a, np.zeros((1, 3))])[rows[:, :-1]]
                       * dt[..., None])
        c = np.cumsum(pf[:, ::-1], axis=1)[:, ::-1] - pf                 # Σ_{l>k} P_l·f_l
        for r, (i, j, k0, k1) in enumerate(d.intervals):
            dr = s[r, -1]
            sdt = s[r] * dt[r][:, None, None]
            blocks = []
            if "level" in fam:
                lv, e = start["level"] + 2 * r, d.level_basis[r]
                ui, uj = (a_blk[k] / np.linalg.norm(a_blk[k]) for k in (i, j))
                pi, pj = ((np.eye(3) - np.outer(u, u)) / np.linalg.norm(a_blk[k])
                          for u, k in ((ui, i), (uj, j)))
                b_a[lv:lv + 2, 3 * j:3 * j + 3] += e.T @ pj
                b_a[lv:lv + 2, 3 * i:3 * i + 3] -= e.T @ dr.T @ pi
                blocks.append((lv, -e.T @ dr.T @ hat(ui) @ sdt))          # (K, 2, 3)
            if "zupt" in fam:
                zv = start["zupt"] + 3 * r
                b_a[zv:zv + 3, 3 * i:3 * i + 3] -= (d.t[k1] - d.t[k0]) * np.eye(3)
                blocks.append((zv, -hat(c[r]) @ sdt))
                cov[zv:zv + 3, zv:zv + 3] += sa2 * float(np.sum(dt[r] ** 2)) * np.eye(3)
            for p, bp in blocks:                   # gyro noise of the interval
                for q, bq in blocks:
                    cov[p:p + bp.shape[1], q:q + bq.shape[1]] += sw2 * np.einsum(
                        "kij,klj->il", bp, bq)
    cov += (b_a * np.repeat(var_blk, 3)) @ b_a.T
    return cov


def mag_covariances(x, d) -> np.ndarray:
    """(W, 3, 3) per magnetometer window of the condition D_m·(m_e − dRᵀ·m_s), in raw units:
    σ_m²·(I + T·Tᵀ) + D_m·σ_ω²·Δt·T·[m]×[m]×ᵀ·D_mᵀ with T = D_m·dRᵀ·D_m⁻¹.

    Parameters
    ----------
    x : (42,) array
        Parameters (:mod:`apmcal.solvers.joint.model`).
    d : JointData
        The session's samples and condition layout (:func:`apmcal.solvers.joint.residuals.layout`).

    Returns
    -------
    (W, 3, 3) array
        One covariance per window, all window lengths in turn [mGauss²].
    """
    sm2, sw2 = d.noise["mag"] ** 2, d.noise["gyr"] ** 2
    step = float(np.median(np.diff(d.t)))
    m = matrices(x)
    a = correct_acc(d.acc, m)
    w = correct_gyr(d.gyr, a, m)
    rot = so3_exp(np.vstack([midpoint(w) * d.dt[:, None], np.zeros((1, 3))]))
    mc = correct_mag(d.mag, m)
    dm = m["D_m"]
    parts = []
    for idx in d.windows:
        tr = dm @ np.swapaxes(product(rot[idx[:, :-1]]), 1, 2) @ np.linalg.inv(dm)
        span = d.t[idx[:, -1]] - d.t[idx[:, 0]]
        hm = dm @ hat(mc[idx[:, 0]])
        parts.append(sm2 * (np.eye(3) + tr @ np.swapaxes(tr, 1, 2))
                     + (sw2 * step * span)[:, None, None] * hm @ np.swapaxes(hm, 1, 2))
    return np.concatenate(parts)


class Whitener:
    """Maps misclosures (family → (n_c, dim)) to the whitened, weighted residual vector of the
    least squares, with per-condition robust weights and per-family variance factors folded
    into the covariance (a weight w divides a condition's variance by w).

    Parameters
    ----------
    x : (42,) array
        Parameters the covariance is evaluated at.
    d : JointData
        The session's samples and condition layout (:func:`apmcal.solvers.joint.residuals.layout`).
    families : tuple of str
        The condition families in use.
    rows : (I, K+1) int array
        Moving intervals' sample indices.
    weights : dict
        family → (n_c,) robust weight of each condition (0..1).
    factor : dict
        family → variance factor (a σ scale, dimensionless).
    """

    def __init__(self, x, d, families, rows, weights: dict, factor: dict):
        self.families = families
        self.inertial = [f for f in INERTIAL if f in families]
        cov = inertial_covariance(x, d, families, rows)
        scale = np.concatenate([np.repeat(factor[f] / np.sqrt(np.maximum(weights[f],
                                                                          WEIGHT_FLOOR)),
                                          DIM[f])
                                for f in self.inertial])
        self.marginal = {}
        k = 0
        for f in self.inertial:
            dim = DIM[f]
            n = len(weights[f])
            blk = cov[k:k + n * dim, k:k + n * dim]
            self.marginal[f] = np.array([blk[c * dim:(c + 1) * dim, c * dim:(c + 1) * dim]
                                         for c in range(n)])
            k += n * dim
        self.chol = np.linalg.cholesky(cov * np.outer(scale, scale))
        self.other = {}
        if "mag" in families:
            self.marginal["mag"] = mag_covariances(x, d)
            self.other["mag"] = (np.linalg.inv(np.linalg.cholesky(self.marginal["mag"]))
                                 * (np.sqrt(weights["mag"]) / factor["mag"])[:, None, None])
        if "mag_datum" in families:
            # a datum, not an observation: far tighter than the data, so it acts as a constraint
            self.other["mag_datum"] = np.array([[[1.0 / (1e-3 * d.noise["mag"])]]])

    def __call__(self, w: dict) -> np.ndarray:
        """The whitened, weighted residual vector of the misclosures ``w``.

        Parameters
        ----------
        w : dict
            family → (n_c, dim) misclosures (:func:`apmcal.solvers.joint.residuals.misclosures`).

        Returns
        -------
        (N,) array
            Dimensionless: inertial families first (Cholesky order), then the others.
        """
        head = np.concatenate([w[f].ravel() for f in self.inertial])
        tail = [np.einsum("cij,cj->ci", self.other[f], w[f]).ravel() for f in self.other]
        return np.concatenate([solve_triangular(self.chol, head, lower=True)] + tail)

    def jacobian(self, a: dict) -> np.ndarray:
        """The design matrix whitened as :meth:`__call__` whitens the misclosures.

        Parameters
        ----------
        a : dict
            family → (n_c, dim, p) ∂w/∂X (:func:`apmcal.solvers.joint.jacobian.jacobian`).

        Returns
        -------
        (N, p) array
        """
        head = np.concatenate([a[f].reshape(-1, a[f].shape[2]) for f in self.inertial])
        tail = [np.einsum("cij,cjp->cip", self.other[f], a[f]).reshape(-1, a[f].shape[2])
                for f in self.other]
        return np.vstack([solve_triangular(self.chol, head, lower=True)] + tail)

    def family_rows(self, w: dict) -> dict[str, slice]:
        """Rows of the whitened vector attributed to each family (Cholesky order: a row is the
        part of its condition not explained by the conditions before it).

        Parameters
        ----------
        w : dict
            family → (n_c, dim) misclosures.

        Returns
        -------
        dict
            family → slice of rows.
        """
        out, k = {}, 0
        for f in self.inertial + list(self.other):
            out[f] = slice(k, k + w[f].size)
            k += w[f].size
        return out

    def standardised(self, w: dict, f: str) -> np.ndarray:
        """Each condition's residual over its own (marginal) σ, RMS over its components.

        Parameters
        ----------
        w : dict
            family → (n_c, dim) misclosures.
        f : str
            The family.

        Returns
        -------
        (n_c,) array
            Dimensionless.
        """
        chol = np.linalg.cholesky(self.marginal[f])
        z = np.linalg.solve(chol, w[f][..., None])[..., 0]
        return np.sqrt(np.mean(z ** 2, axis=1))
