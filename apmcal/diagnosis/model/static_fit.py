"""Fits of the still (hold) data: the geometric sensors (accelerometer, magnetometer) and the gyro.

Accelerometer and magnetometer, block means ȳ_j of hold group k (one orientation u_k)::

    ȳ_j = F·(r·u_k) + k2 ⊙ (F·r·u_k)² + b + X_j·θ + e_j

with ``r`` the field magnitude (gravity [m/s²] or the Earth field [mGauss]), ``F`` the forward
matrix of sitl's model (:meth:`apmcal.sensor_model.truth.Truth.acc_forward`: diag(scale)·T_a⁻¹ with [Oppong]'s
non-orthogonality T_a when ``cross_axis`` is fitted; a symmetric soft-iron matrix for the
magnetometer), ``b`` the offset, ``k2`` the quadratic scale term and ``X_j`` the slow regressors
(temperature, time, current) of :mod:`apmcal.diagnosis.model.regressors`. The orientation of each group
is profiled out in closed form, u_k = F⁻¹m_k / |F⁻¹m_k| with m_k the group's mean of ȳ − b − Xθ
(exact for an orthogonal F, second order otherwise; real and twin share the approximation).
With too few distinct orientations for the geometry, each group keeps a free mean and only θ is
fitted (fixed-effects regression).

Gyroscope, block means during holds, linear::  ȳ_j = b + X_j·θ + Σ a_v·V_j,v + e_j
(per-axis columns such as time, temperature and specific force; whole-vector regressors with one
coefficient such as the Earth rate's vertical and horizontal parts).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from apmcal.diagnosis.compute.memo import ContentMemo, digest
from apmcal.diagnosis.model.blocks import Blocks
from apmcal.solvers.uncertainty import covariance_from_jacobian

MIN_ORIENTATIONS = 6        # distinct group directions for an offset + scale geometry
MIN_CHORD = 0.5             # two directions are distinct when their unit vectors are this apart
# prior one-sigma of the effect terms (MAP fit): wide against real sensors ([Oppong] reports
# non-orthogonality of a few mrad; k2 = 1e-3 /(m/s²) is 0.1 m/s² at 1 g, five times sitl's
# default), so they only hold still the combinations six axis-aligned faces cannot see
PRIOR_SIGMA = {"alpha": 0.05, "k2": 1e-3}
# geometric fits by the content of their inputs: most models of a session leave one sensor's
# hold data (real, and then its twin's) as the nominal model has it, so most fits repeat one
# made before
_GEOMETRY_FITS = ContentMemo("geometry_fits", 512)


def non_orthogonality(alpha) -> np.ndarray:
    """[Oppong] §2.1 T_a for (α_yz, α_zy, α_zx) [rad], as sitl's acc_forward builds it.

    Parameters
    ----------
    alpha : (3,) array
        (α_yz, α_zy, α_zx) [rad].

    Returns
    -------
    (3, 3) array
        Upper-triangular T_a.
    """
    a_yz, a_zy, a_zx = alpha
    return np.array([[1.0, -a_yz, a_zy], [0.0, 1.0, -a_zx], [0.0, 0.0, 1.0]])


def symmetric(p) -> np.ndarray:
    """Symmetric 3×3 matrix from (xx, yy, zz, xy, xz, yz).

    Parameters
    ----------
    p : (6,) array

    Returns
    -------
    (3, 3) array
    """
    xx, yy, zz, xy, xz, yz = p
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def distinct_directions(vectors: np.ndarray, min_chord: float = MIN_CHORD) -> int:
    """Number of directions at least ``min_chord`` apart (greedy clustering of unit vectors).

    Parameters
    ----------
    vectors : (k, 3) array
        Vectors of any length and unit.
    min_chord : float
        Chord between two unit vectors that makes them distinct (0.5: about 29°).

    Returns
    -------
    int
    """
    units = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    apart = _apart(units, min_chord)
    centres: list[int] = []
    for i in range(len(units)):
        if all(apart[i, j] for j in centres):
            centres.append(i)
    return len(centres)


def _apart(units: np.ndarray, min_chord: float) -> np.ndarray:
    """(k, k) bool: ``np.linalg.norm(units[i] - units[j]) >= min_chord``, every pair at once
    (a norm per pair in Python made the clustering a few per cent of every fit); a distance
    within 1e-9 of the chord — where the two ways of summing the squares, a few units in the
    last place apart, could disagree — is decided by np.linalg.norm itself."""
    diff = units[:, None, :] - units[None, :, :]
    dist = np.sqrt(np.sum(diff * diff, axis=-1))
    apart = dist >= min_chord
    for i, j in zip(*np.nonzero(np.abs(dist - min_chord) < 1e-9)):
        apart[i, j] = np.linalg.norm(units[i] - units[j]) >= min_chord
    return apart


def count_orientations(blocks: Blocks, kind: str) -> int:
    """Distinct orientations among the hold groups (the magnetometer's about its hard-iron
    centre, estimated by a sphere through the group means).

    Parameters
    ----------
    blocks : Blocks
        The sensor's hold blocks.
    kind : str
        "acc" or "mag".

    Returns
    -------
    int
    """
    means = blocks.group_means(blocks.values)
    if kind == "mag":
        if len(means) < 4:
            return len(means)
        from apmcal.core.errors import ApmcalError
        from apmcal.solvers.ellipsoid.fit import sphere_fit
        try:
            means = means - sphere_fit(means)[0]
        except ApmcalError:
            return 1
    return distinct_directions(means)


@dataclass
class GeometryFit:
    """A fitted geometric sensor model (see the module docstring); arrays in sensor units.

    Attributes
    ----------
    offset : (3,) array
        Offset b.
    forward : (3, 3) array
        Forward matrix F.
    radius : float
        Field magnitude r (gravity [m/s²] or Earth field [mGauss]).
    k2 : (3,) array
        Quadratic term per axis [1/sensor unit].
    theta : (k, 3) array
        Slow-regressor coefficients.
    geometry : bool
        False: free group means (too few orientations).
    params : dict
        Name → value (for the report).
    sigma : dict
        Name → one-sigma.
    vector : array or None
        The fitted parameter vector.
    """

    offset: np.ndarray
    forward: np.ndarray             # F
    radius: float
    k2: np.ndarray                  # quadratic term per axis
    theta: np.ndarray               # (k, 3) slow-regressor coefficients
    geometry: bool                  # False: free group means (too few orientations)
    params: dict = field(default_factory=dict)     # name -> value (for the report)
    sigma: dict = field(default_factory=dict)      # name -> one-sigma
    vector: np.ndarray | None = None               # the fitted parameter vector

    def directions(self, blocks: Blocks, columns: np.ndarray) -> np.ndarray:
        """Orientation u_k of each group [unit vectors in the calibrated frame] (or, without
        geometry, the group means of ȳ − b − Xθ, which are then the full prediction).

        Parameters
        ----------
        blocks : Blocks
            The sensor's blocks (every group).
        columns : (b, k) array
            Slow regressors at each block.

        Returns
        -------
        (n_groups, 3) array
            NaN rows for groups without blocks.
        """
        z = blocks.values - self.offset - columns @ self.theta
        m = blocks.group_means(z)
        if not self.geometry:
            return m
        return self.orientation(m)

    def orientation(self, z: np.ndarray) -> np.ndarray:
        """The unit vector(s) u whose reading F·r·u + k2 ⊙ (F·r·u)² is closest to z (rows,
        offset and θ removed): the quadratic term is taken off z first — otherwise its part
        across the field would tilt u and be lost from the fit — by the fixed point
        s = z − k2 ⊙ s² (|k2·s| ≪ 1: two steps leave an error of order (k2·s)³).

        Parameters
        ----------
        z : (g, 3) array
            Readings, offset and θ removed [sensor unit].

        Returns
        -------
        (g, 3) array
            Unit vectors.
        """
        s = z
        if np.any(self.k2):
            for _ in range(2):
                s = z - self.k2 * s ** 2
        u = np.linalg.solve(self.forward, s.T).T
        return u / np.linalg.norm(u, axis=1, keepdims=True)

    def truth_of(self, u: np.ndarray) -> np.ndarray:
        """F·r·u + k2 ⊙ (F·r·u)²: the sensor reading of orientation(s) u, before offset and θ.

        Parameters
        ----------
        u : (g, 3) array
            Unit vectors (without geometry: the group means, returned as they are).

        Returns
        -------
        (g, 3) array
            [sensor unit].
        """
        if not self.geometry:
            return u
        s = (self.radius * u) @ self.forward.T
        return s + self.k2 * s ** 2

    def predict(self, u_rows: np.ndarray, columns: np.ndarray, group: np.ndarray | None = None
                ) -> np.ndarray:
        """Predicted samples given each sample's orientation row and regressor columns; with
        ``group`` (one index per sample) ``u_rows`` holds one orientation per group, mapped
        through the sensor model once per group rather than once per sample.

        Parameters
        ----------
        u_rows : (n, 3) or (g, 3) array
            Orientation of each sample, or of each group with ``group``.
        columns : (n, k) array
            Slow regressors at each sample.
        group : (n,) int array, optional
            Row of ``u_rows`` of each sample.

        Returns
        -------
        (n, 3) array
            [sensor unit].
        """
        # the offset added once per group before the rows are gathered, and no product of an
        # empty column set (zeros): the same values, 2 fewer passes over the samples
        out = self.truth_of(u_rows) + self.offset
        if group is not None:
            out = np.take(out, group, axis=0)         # faster than out[group]
        return out + columns @ self.theta if columns.shape[1] else out


class _Layout:
    """Named slices of a parameter vector (and fixed values of parameters not fitted)."""

    def __init__(self, sizes: dict[str, int], fixed: dict | None = None):
        self.fixed = fixed or {}
        self.slices, start = {}, 0
        for name, n in sizes.items():
            self.slices[name] = slice(start, start + n)
            start += n
        self.size = start

    def get(self, p, name, default=None):
        if name in self.slices:
            return p[self.slices[name]]
        return self.fixed.get(name, default)


def _forward(layout: _Layout, p, kind: str) -> np.ndarray:
    if kind == "mag":
        return symmetric(layout.get(p, "soft"))
    f = np.diag(np.exp(layout.get(p, "log_scale")))
    alpha = layout.get(p, "alpha")
    return f if alpha is None else f @ np.linalg.inv(non_orthogonality(alpha))


def fit_geometry(blocks: Blocks, columns: np.ndarray, radius: float, *, kind: str = "acc",
                 cross_axis: bool = False, quadratic: bool = False,
                 start: GeometryFit | None = None, with_sigma: bool = True,
                 fixed: dict | None = None) -> GeometryFit:
    """Fit offset, forward matrix (and the optional terms) to the hold block means.

    Parameters
    ----------
    blocks : Blocks
        Blocks of one sensor (holds of the training fold).
    columns : (b, k) array
        Slow regressors at each block (k may be 0).
    radius : float
        Field magnitude (gravity [m/s²] or Earth field [mGauss]).
    kind : {"acc", "mag"}
        "acc" (diagonal scale, optional non-orthogonality) or "mag" (symmetric soft iron).
    cross_axis : bool
        Fit the accelerometer's non-orthogonality α [rad].
    quadratic : bool
        Fit the quadratic term k2.
    start : GeometryFit, optional
        A fit to start from.
    with_sigma : bool
        Compute the parameters' one-sigma.
    fixed : dict, optional
        Terms held at known values instead of fitted ("alpha", "k2"; found on the moves).

    Returns
    -------
    GeometryFit
        With free group means instead (``geometry`` False) when the blocks hold fewer than
        ``MIN_ORIENTATIONS`` distinct orientations.
    """
    key = digest(blocks.values, blocks.count, blocks.group, blocks.n_groups, columns,
                 float(radius), kind, cross_axis, quadratic, with_sigma, fixed,
                 None if start is None else (start.vector, start.geometry, start.offset,
                                             start.forward))
    fit = _GEOMETRY_FITS.get(key)
    if fit is None:
        fit = _fit_geometry(blocks, columns, radius, kind, cross_axis, quadratic, start,
                            with_sigma, fixed)
        _GEOMETRY_FITS.put(key, fit)
    return fit


def _fit_geometry(blocks: Blocks, columns: np.ndarray, radius: float, kind: str,
                  cross_axis: bool, quadratic: bool, start: GeometryFit | None,
                  with_sigma: bool, fixed: dict | None) -> GeometryFit:
    k = columns.shape[1]
    if count_orientations(blocks, kind) < MIN_ORIENTATIONS:
        return _fit_free_means(blocks, columns, radius)
    sizes = {"offset": 3}
    sizes.update({"soft": 6} if kind == "mag" else {"log_scale": 3})
    if cross_axis and kind == "acc":
        sizes["alpha"] = 3
    if quadratic:
        sizes["k2"] = 3
    sizes["theta"] = 3 * k
    layout = _Layout(sizes, {k: np.asarray(v, float) for k, v in (fixed or {}).items()})
    p0 = _start_vector(layout, blocks, radius, kind, start, k)
    residuals = _with_priors(_split_residuals(blocks, columns, layout, kind, radius), layout,
                             _noise_level(blocks))
    sol = least_squares(residuals, p0, method="lm", x_scale="jac")
    fit = _unpack(layout, sol.x, kind, radius, k)
    fit.vector = sol.x
    sigma = np.full(layout.size, np.nan)
    if with_sigma:
        cov, _ = covariance_from_jacobian(sol.jac, sol.fun, layout.size)
        sigma = np.sqrt(np.clip(np.diag(cov), 0, None))
    _name_params(fit, layout, sol.x, sigma)
    return fit


def _split_residuals(blocks: Blocks, columns: np.ndarray, layout, kind, radius):
    """The weighted block residuals as two parts with the same sum of squares (fast):
    each group's mean — which alone sees the geometry — weighted by its sample count, and
    the blocks' deviations from their group mean, which see only the slow columns θ."""
    k = columns.shape[1]
    w = blocks.count.astype(float)
    counts = np.bincount(blocks.group, w, minlength=blocks.n_groups)
    present = counts > 0
    y_mean = blocks.group_means(blocks.values)[present]
    x_mean = blocks.group_means(columns)[present] if k else np.zeros((present.sum(), 0))
    sw_group = np.sqrt(counts[present])[:, None]
    sw_block = np.sqrt(w)[:, None]
    y_dev = (blocks.values - blocks.group_means(blocks.values)[blocks.group]) * sw_block
    x_dev = (columns - blocks.group_means(columns)[blocks.group]) * sw_block if k else None

    def residuals(p):
        fit = _unpack(layout, p, kind, radius, k)
        z = y_mean - fit.offset - x_mean @ fit.theta
        parts = [((z - fit.truth_of(fit.orientation(z))) * sw_group).ravel()]
        if k:
            parts.append((y_dev - x_dev @ fit.theta).ravel())
        return np.concatenate(parts)

    return residuals


def _noise_level(blocks: Blocks) -> float:
    """Per-sample noise seen in the blocks: the count-weighted RMS of their deviation from
    their group's mean (slow effects included: a conservative scale for the priors)."""
    dev = blocks.values - blocks.group_means(blocks.values)[blocks.group]
    w = blocks.count.astype(float)[:, None]
    return float(np.sqrt(np.sum(w * dev ** 2) / max(np.sum(w) * 3, 1.0))) or 1.0


def _with_priors(residuals, layout: _Layout, noise: float):
    """Append Gaussian prior residuals noise·p/σ_prior for the effect terms (MAP estimate)."""
    priors = [(layout.slices[name], sigma) for name, sigma in PRIOR_SIGMA.items()
              if name in layout.slices]
    if not priors:
        return residuals

    def with_priors(p):
        return np.concatenate([residuals(p)] + [noise * p[sl] / sigma for sl, sigma in priors])

    return with_priors


def _unpack(layout, p, kind, radius, k) -> GeometryFit:
    theta = layout.get(p, "theta", np.zeros(0)).reshape(k, 3)
    fit = GeometryFit(offset=layout.get(p, "offset"), forward=_forward(layout, p, kind),
                      radius=radius, k2=layout.get(p, "k2", np.zeros(3)), theta=theta,
                      geometry=True)
    for name, value in layout.fixed.items():
        fit.params[name] = value.tolist()
    return fit


def _start_vector(layout, blocks, radius, kind, start, k) -> np.ndarray:
    if start is not None and start.vector is not None and len(start.vector) == layout.size:
        return np.array(start.vector)           # the same model fitted before (a twin's start)
    p0 = np.zeros(layout.size)
    if start is not None and start.geometry:
        p0[layout.slices["offset"]] = start.offset
    if kind == "mag":
        centre, soft = _mag_start(blocks, radius) if start is None or not start.geometry else \
            (start.offset, start.forward)
        p0[layout.slices["offset"]] = centre
        p0[layout.slices["soft"]] = [soft[0, 0], soft[1, 1], soft[2, 2], soft[0, 1], soft[0, 2],
                                     soft[1, 2]]
    return p0


def _mag_start(blocks: Blocks, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Sphere through the group means (centre, radius ratio) as the soft-iron starting point."""
    from apmcal.solvers.ellipsoid.fit import sphere_fit

    means = blocks.group_means(blocks.values)
    centre, r = sphere_fit(means)
    return centre, np.eye(3) * (r / radius)


def _name_params(fit: GeometryFit, layout, p, sigma) -> None:
    for name, sl in layout.slices.items():
        fit.params[name] = np.asarray(p[sl]).tolist()
        fit.sigma[name] = np.asarray(sigma[sl]).tolist()


def _fit_free_means(blocks: Blocks, columns: np.ndarray, radius: float) -> GeometryFit:
    """Without geometry: θ by a fixed-effects regression (each group its own mean)."""
    k = columns.shape[1]
    theta = np.zeros((k, 3))
    sigma = np.zeros((k, 3))
    if k:
        w = blocks.count.astype(float)
        xc = columns - blocks.group_means(columns)[blocks.group] if k else columns
        yc = blocks.values - blocks.group_means(blocks.values)[blocks.group]
        theta, sigma = weighted_lstsq(xc, yc, w)
    fit = GeometryFit(offset=np.zeros(3), forward=np.eye(3), radius=radius, k2=np.zeros(3),
                      theta=theta, geometry=False)
    fit.params["theta"], fit.sigma["theta"] = theta.ravel().tolist(), sigma.ravel().tolist()
    return fit


def weighted_lstsq(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares of each column of (b, c) ``y`` on (b, k) ``x`` → coefficients
    (k, c) and their one-sigma (k, c) from the residual variance.

    Normal equations on RMS-scaled columns (k is small, b is thousands: far cheaper than an SVD
    of the whole design, and the scaling keeps columns as different as 1e-5 rad/s Earth-rate
    vectors and 300 s time offsets well conditioned); a pseudo-inverse for rank deficiency.

    Parameters
    ----------
    x : (b, k) array
        Design.
    y : (b, c) array
        Observations.
    w : (b,) array
        Weights.

    Returns
    -------
    coef, sigma : (k, c) arrays
    """
    scale = np.sqrt(np.mean(x ** 2, axis=0))
    scale[scale == 0] = 1.0
    xs = x / scale
    xw = xs * w[:, None]
    normal_inv = np.linalg.pinv(xs.T @ xw, hermitian=True)
    coef = normal_inv @ (xw.T @ y)
    resid = y - xs @ coef
    dof = max(len(y) - x.shape[1], 1)
    s2 = (w[:, None] * resid ** 2).sum(axis=0) / dof
    sigma = np.sqrt(np.outer(np.clip(np.diag(normal_inv), 0, None), s2))
    return coef / scale[:, None], sigma / scale[:, None]


@dataclass
class GyroFit:
    """Gyro hold model: offset [rad/s], per-axis column coefficients θ (k, 3) and whole-vector
    coefficients (v,), with one-sigma uncertainties.

    Attributes
    ----------
    offset : (3,) array
        [rad/s].
    theta : (k, 3) array
        Per-axis column coefficients [rad/s per column unit].
    vector_coef : (v,) array
        Whole-vector coefficients.
    sigma : dict
        One-sigma of each: "offset" (3,), "theta" (k, 3), "vector_coef" (v,).
    """

    offset: np.ndarray
    theta: np.ndarray
    vector_coef: np.ndarray
    sigma: dict = field(default_factory=dict)

    def predict(self, columns: np.ndarray, vectors: np.ndarray) -> np.ndarray:
        """Predicted rate (n, 3) from columns (n, k) and vector regressors (n, v, 3).

        Returns
        -------
        (n, 3) array
            [rad/s].
        """
        out = self.offset + columns @ self.theta
        if vectors.shape[1]:
            out = out + np.einsum("nvc,v->nc", vectors, self.vector_coef)
        return out


def fit_gyro(blocks: Blocks, columns: np.ndarray, vectors: np.ndarray) -> GyroFit:
    """Weighted least squares of the gyro hold block means (module docstring).

    Parameters
    ----------
    blocks : Blocks
        Gyro Blocks of the training holds.
    columns : (b, k) array
        Per-axis regressors.
    vectors : (b, v, 3) array
        Whole-vector regressors (e.g. Earth rate parts), v may be 0.

    Returns
    -------
    GyroFit
    """
    nb, k, nv = len(blocks.t), columns.shape[1], vectors.shape[1]
    design = np.zeros((nb, 3, 3 + 3 * k + nv))
    for axis in range(3):
        design[:, axis, axis] = 1.0
        design[:, axis, 3 + 3 * np.arange(k) + axis] = columns
    design[:, :, 3 + 3 * k:] = np.transpose(vectors, (0, 2, 1))
    w = np.repeat(blocks.count.astype(float), 3)
    coef, sigma = weighted_lstsq(design.reshape(nb * 3, -1), blocks.values.reshape(-1, 1), w)
    coef, sigma = coef[:, 0], sigma[:, 0]
    return GyroFit(offset=coef[:3], theta=coef[3:3 + 3 * k].reshape(k, 3),
                   vector_coef=coef[3 + 3 * k:],
                   sigma={"offset": sigma[:3], "theta": sigma[3:3 + 3 * k].reshape(k, 3),
                          "vector_coef": sigma[3 + 3 * k:]})
