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
ZARU of its end poses. The ZARU is therefore independent of every other condition: its
variances are kept as a vector, and the Cholesky factor is taken of the static norm, levelling
and ZUPT alone (the same factor as of the whole matrix, without the ZARU's rows).

The gyro noise of an interval in closed form: S_k is a rotation, so the products S_k·S_kᵀ in
Σ_k B_k·B_kᵀ are the identity and the sums over the interval's samples reduce to
ΣΔt_k²·L·Lᵀ (levelling, L = Eᵀ·dRᵀ·[û_i]×), −L·[ΣΔt_k²·C_k]× (levelling with ZUPT) and
ΣΔt_k²·(|C_k|²·I − C_k·C_kᵀ) (ZUPT), for all intervals at once.
"""
from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.linalg import solve_triangular

from apmcal.solvers.joint.residuals import DIM, window_ends
from apmcal.solvers.joint.trajectory import Trajectory, transposed
from apmcal.solvers.strapdown import hat

INERTIAL = ("acc_norm", "zaru", "level", "zupt")
CORRELATED = ("acc_norm", "level", "zupt")    # the inertial families that share noise
WEIGHT_FLOOR = 1e-8        # a rejected condition (weight 0) gets this weight: its variance ×1e8
DATUM_SIGMA = 1e-3         # the compass datum's σ, in units of the compass's white noise


def _projector(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u = v/|v| (c, 3), (I − u·uᵀ)/|v| (c, 3, 3)): the unit vectors and their derivative."""
    n = np.linalg.norm(v, axis=1)
    u = v / n[:, None]
    return u, (np.eye(3) - u[:, :, None] * u[:, None, :]) / n[:, None, None]


def inertial_covariance(tr: Trajectory, d, families) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the inertial misclosures: dense over the static norm, levelling and ZUPT
    (rows laid out family by family in :data:`CORRELATED` order, each condition's components
    together), and the ZARU's variances (independent of the rest).

    Parameters
    ----------
    tr : Trajectory
        The corrected signals and attitude at the parameters
        (:class:`~apmcal.solvers.joint.trajectory.Trajectory`).
    d : JointData
        The session's samples and condition layout (:func:`apmcal.solvers.joint.residuals.layout`).
    families : tuple of str
        The condition families in use.

    Returns
    -------
    (N, N) array
        N = Σ over the correlated families in use of conditions × dim, in the families' units
        squared ([m/s²]², [rad]², [m/s]²).
    (3·n_blocks,) array
        The ZARU's variances [rad/s]² (empty without it).
    """
    sa2, sw2 = d.noise["acc"] ** 2, d.noise["gyr"] ** 2
    nb, ni = len(d.blocks), len(d.intervals)
    var_blk = sa2 / np.array([b.size for b in d.blocks], float)
    zaru = np.repeat(sw2 * var_blk / sa2, 3) if "zaru" in families else np.zeros(0)
    a_blk = d.block_mean @ tr.a
    fam = [f for f in CORRELATED if f in families and (f == "acc_norm" or ni)]
    size = {"acc_norm": nb, "level": 2 * ni, "zupt": 3 * ni}
    start, k = {}, 0
    for f in fam:
        start[f], k = k, k + size[f]
    # ∂w/∂(block means of the accelerometer), sparse: a row touches one or two blocks
    rows, cols, vals = [], [], []

    def put(r0, b, block):           # block (c, h, 3) at rows r0[c] + 0..h−1, block b[c]
        c, h, _ = block.shape
        rows.append(np.repeat(r0[:, None] + np.arange(h), 3, axis=1).ravel())
        cols.append(np.tile(3 * b[:, None] + np.arange(3), (1, h)).ravel())
        vals.append(block.ravel())

    if "acc_norm" in fam:
        u, _ = _projector(a_blk)
        put(start["acc_norm"] + np.arange(nb), np.arange(nb), u[:, None, :])
    cov = np.zeros((k, k))
    if "level" in fam or "zupt" in fam:
        bi, bj, k0, k1 = d.interval_index.T
        dr = tr.rotation(k0, k1)
        # C_k = Σ_{l>k} P_l·a_l·Δt_l, the velocity still to come, in the session's frame
        steps = d.steps                                                   # (I, K), padded n
        dt = np.append(d.dt, 0.0)[steps]                                  # (I, K), 0 padded
        v = tr.velocity
        c = v[k1][:, None, :] - v[np.minimum(steps + 1, len(v) - 1)]      # (I, K, 3)
        dt2 = dt ** 2
        t2 = dt2.sum(axis=1)                                              # (I,)
        qt = transposed(tr.frame[k0])
        csum = qt @ np.einsum("wk,wki->wi", dt2, c)[..., None]           # (I, 3, 1)
        cc = (np.einsum("wk,wki,wki->w", dt2, c, c)[:, None, None] * np.eye(3)
              - np.einsum("wk,wki,wkj->wij", dt2, c, c))
        blocks = {}
        if "level" in fam:
            ui, pi = _projector(a_blk[bi])
            _, pj = _projector(a_blk[bj])
            et = transposed(d.level_basis)                                # (I, 2, 3)
            rl = start["level"] + 2 * np.arange(ni)
            put(rl, bj, et @ pj)
            put(rl, bi, -(et @ transposed(dr) @ pi))
            lm = et @ transposed(dr) @ hat(ui)                            # L (I, 2, 3)
            blocks["level", "level"] = sw2 * t2[:, None, None] * (lm @ transposed(lm))
        if "zupt" in fam:
            rz = start["zupt"] + 3 * np.arange(ni)
            span = d.t[k1] - d.t[k0]
            put(rz, bi, -span[:, None, None] * np.eye(3))
            blocks["zupt", "zupt"] = (sw2 * (qt @ cc @ transposed(qt))
                                      + sa2 * t2[:, None, None] * np.eye(3))
        if "level" in fam and "zupt" in fam:
            blocks["level", "zupt"] = -sw2 * (lm @ hat(csum[..., 0]))
            blocks["zupt", "level"] = transposed(blocks["level", "zupt"])
        for (f, g), blk in blocks.items():   # per interval: block (I, DIM[f], DIM[g])
            rf = start[f] + DIM[f] * np.arange(ni)[:, None, None] + np.arange(DIM[f])[:, None]
            rg = start[g] + DIM[g] * np.arange(ni)[:, None, None] + np.arange(DIM[g])
            cov[rf, rg] += blk
    if rows:
        b_a = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                        np.concatenate(cols))),
                                shape=(k, 3 * nb))
        cov += (b_a.multiply(np.repeat(var_blk, 3)[None, :]) @ b_a.T).toarray()
    return cov, zaru


def mag_covariances(tr: Trajectory, d) -> np.ndarray:
    """(W, 3, 3) per magnetometer window of the condition D_m·(m_e − dRᵀ·m_s), in raw units:
    σ_m²·(I + T·Tᵀ) + D_m·σ_ω²·Δt·T·[m]×[m]×ᵀ·D_mᵀ with T = D_m·dRᵀ·D_m⁻¹.

    Parameters
    ----------
    tr : Trajectory
        The corrected signals and attitude at the parameters
        (:class:`~apmcal.solvers.joint.trajectory.Trajectory`).
    d : JointData
        The session's samples and condition layout (:func:`apmcal.solvers.joint.residuals.layout`).

    Returns
    -------
    (W, 3, 3) array
        One covariance per window, all window lengths in turn [mGauss²].
    """
    sm2, sw2 = d.noise["mag"] ** 2, d.noise["gyr"] ** 2
    step = float(np.median(np.diff(d.t)))
    dm = tr.mats["D_m"]
    s, e = window_ends(d)
    t = dm @ transposed(tr.rotation(s, e)) @ np.linalg.inv(dm)
    span = d.t[e] - d.t[s]
    hm = dm @ hat(tr.mc[s])
    return (sm2 * (np.eye(3) + t @ transposed(t))
            + (sw2 * step * span)[:, None, None] * hm @ transposed(hm))


def inverse_cholesky(a: np.ndarray) -> np.ndarray:
    """L⁻¹ (c, k, k) of the Cholesky factors L·Lᵀ = a of many small SPD matrices (k ≤ 3).

    The textbook recurrences written out over the batch: for thousands of 3×3 matrices the
    batched LAPACK calls (``np.linalg.cholesky`` then ``inv``) cost a hundred times more in
    per-matrix overhead than the arithmetic; the numbers are the same to rounding.

    Parameters
    ----------
    a : (c, k, k) array
        Symmetric positive definite, k of 1, 2 or 3.

    Returns
    -------
    (c, k, k) array
        Lower triangular.

    Raises
    ------
    numpy.linalg.LinAlgError
        When one of the matrices is not positive definite.
    """
    k = a.shape[-1]
    if k > 3:
        return np.linalg.inv(np.linalg.cholesky(a))
    low = np.zeros_like(a)
    for i in range(k):
        for j in range(i + 1):
            acc = a[:, i, j] - np.sum(low[:, i, :j] * low[:, j, :j], axis=1)
            if i == j and not np.all(acc > 0):      # as np.linalg.cholesky would
                raise np.linalg.LinAlgError("Matrix is not positive definite")
            low[:, i, j] = np.sqrt(acc) if i == j else acc / low[:, j, j]
    out = np.zeros_like(a)
    for i in range(k):
        out[:, i, i] = 1.0 / low[:, i, i]
        for j in range(i):
            out[:, i, j] = -np.sum(low[:, i, j:i] * out[:, j:i, j], axis=1) / low[:, i, i]
    return out


def cholesky_diagonal_head(a: np.ndarray, k: int) -> np.ndarray:
    """Cholesky factor L (L·Lᵀ = a) of a symmetric positive definite matrix whose leading k×k
    block is diagonal (the static norms: each its own block's noise), by the Schur complement:
    L₁₁ = diag(√a₁₁), L₂₁ = a₂₁·L₁₁⁻¹, L₂₂ = chol(a₂₂ − L₂₁·L₂₁ᵀ) — the factor LAPACK would give,
    for a third of the work when k is a third of the rows. Any other ``a`` is factored whole.

    Parameters
    ----------
    a : (N, N) array
    k : int
        Rows of the diagonal head.

    Returns
    -------
    (N, N) array
        Lower triangular.

    Raises
    ------
    numpy.linalg.LinAlgError
        When ``a`` is not positive definite.
    """
    head = a[:k, :k]
    if k == 0 or np.count_nonzero(head - np.diag(np.diag(head))):
        return np.linalg.cholesky(a)
    diag = np.diag(head)
    if not np.all(diag > 0):
        raise np.linalg.LinAlgError("Matrix is not positive definite")
    root = np.sqrt(diag)
    out = np.zeros_like(a)
    out[np.arange(k), np.arange(k)] = root
    low = a[k:, :k] / root
    out[k:, :k] = low
    out[k:, k:] = np.linalg.cholesky(a[k:, k:] - low @ low.T)
    return out


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
    weights : dict
        family → (n_c,) robust weight of each condition (0..1).
    factor : dict
        family → variance factor (a σ scale, dimensionless).
    traj : Trajectory, optional
        :class:`~apmcal.solvers.joint.trajectory.Trajectory` of ``x`` and ``d``, when the
        caller has it.
    """

    def __init__(self, x, d, families, weights: dict, factor: dict,
                 traj: Trajectory | None = None):
        tr = Trajectory(x, d) if traj is None else traj
        self.families = families
        self.inertial = [f for f in INERTIAL if f in families]
        self.correlated = [f for f in CORRELATED if f in families]
        cov, zaru = inertial_covariance(tr, d, families)

        def scale(f):
            return np.repeat(factor[f] / np.sqrt(np.maximum(weights[f], WEIGHT_FLOOR)), DIM[f])

        self.marginal = {}
        k = 0
        for f in self.correlated:
            dim, n = DIM[f], len(weights[f])
            r = k + dim * np.arange(n)[:, None, None] + np.arange(dim)
            self.marginal[f] = cov[r, np.swapaxes(r, 1, 2)]
            k += n * dim
        sc = (np.concatenate([scale(f) for f in self.correlated]) if self.correlated
              else np.zeros(0))
        self.chol = cholesky_diagonal_head(cov * np.outer(sc, sc),
                                           len(weights["acc_norm"]) if "acc_norm" in families
                                           else 0)
        if "zaru" in self.inertial:
            self.marginal["zaru"] = zaru.reshape(-1, 3)[:, :, None] * np.eye(3)
            self.zaru_scale = 1.0 / (np.sqrt(zaru) * scale("zaru"))
        self.other = {}
        self._unit = {}            # family → L⁻¹ of each condition's marginal covariance
        if "mag" in families:
            self.marginal["mag"] = mag_covariances(tr, d)
            self._unit["mag"] = inverse_cholesky(self.marginal["mag"])
            self.other["mag"] = (self._unit["mag"]
                                 * (np.sqrt(weights["mag"]) / factor["mag"])[:, None, None])
        if "mag_datum" in families:
            # a datum, not an observation: far tighter than the data, so it acts as a constraint
            self.other["mag_datum"] = np.array([[[1.0 / (DATUM_SIGMA * d.noise["mag"])]]])

    def _inertial(self, parts: dict) -> list:
        """The inertial families' whitened rows (family → (rows, ...)), in :data:`INERTIAL`
        order: the correlated ones through the Cholesky factor, the ZARU by its σ."""
        out = {}
        if self.correlated:
            head = np.concatenate([parts[f] for f in self.correlated])
            white = solve_triangular(self.chol, head, lower=True)
            k = 0
            for f in self.correlated:
                out[f] = white[k:k + len(parts[f])]
                k += len(parts[f])
        if "zaru" in self.inertial:
            z = parts["zaru"]
            out["zaru"] = z * self.zaru_scale.reshape((-1,) + (1,) * (z.ndim - 1))
        return [out[f] for f in self.inertial]

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
        head = self._inertial({f: w[f].ravel() for f in self.inertial})
        tail = [np.einsum("cij,cj->ci", self.other[f], w[f]).ravel() for f in self.other]
        return np.concatenate(head + tail)

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
        head = self._inertial({f: a[f].reshape(-1, a[f].shape[2]) for f in self.inertial})
        tail = [(self.other[f] @ a[f]).reshape(-1, a[f].shape[2]) for f in self.other]
        return np.vstack(head + tail)

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

    def unit(self, f: str) -> np.ndarray:
        """M_i⁻¹ of each condition of family ``f``: the inverse Cholesky factor of its own
        white-noise covariance M_i·M_iᵀ (weight and noise scale 1), (n_c, dim, dim).

        Parameters
        ----------
        f : str
            The family.

        Returns
        -------
        (n_c, dim, dim) array
            In the inverse of the family's units.
        """
        if f not in self._unit:
            self._unit[f] = inverse_cholesky(self.marginal[f])
        return self._unit[f]

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
        z = (self.unit(f) @ w[f][..., None])[..., 0]
        return np.sqrt(np.mean(z ** 2, axis=1))
