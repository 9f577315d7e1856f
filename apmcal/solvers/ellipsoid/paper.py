"""Niespodziany's static ellipsoid calibration ([Niespodziany]), exactly as the paper gives it.

Model ([Niespodziany] eq. 1): ``S_p = W·S + V0`` with symmetric ``W``; inverse (eq. 4)
``S = W⁻¹·(S_p − V0)``. In apmcal's convention (apmcal/solvers/result.py)
``calibrated = matrix @ (measured − offset)``, so ``offset = V0`` and ``matrix = W⁻¹``.

* :func:`fit_ellipsoid_analytical` — Fig. 2: step 1 sphere LS for V0 and S (W⁻¹ = I), step 2
  LS for the symmetric quadratic form on the centred samples, then a matrix square root.
* :func:`fit_ellipsoid_numerical` — Fig. 3-4: quasi-Newton minimisation of the RMS of
  ``|W⁻¹(S_p − V0)| − S`` started from the analytical V0 and W⁻¹ = I.
* ``diagonal_only`` — [Niespodziany] §VII.A: with few accelerometer orientations w4, w5, w6 are nulled.
* :func:`gyro_offset` — [Niespodziany] §VIII: the gyroscope gets an offset only (mean at rest).
* :func:`relative_mse` — the paper's figure of merit on a held-out set.
"""
from __future__ import annotations

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.solvers.result import SensorCalibration

# Parameter → matrix entries, paper order ([Niespodziany] eq. 7 / Fig. 3): w1, w2, w3 on the diagonal,
# w4 = (x,y), w5 = (x,z), w6 = (y,z), each mirrored (W⁻¹ symmetric).
SYMMETRIC_ENTRIES = [((0, 0),), ((1, 1),), ((2, 2),),
                     ((0, 1), (1, 0)), ((0, 2), (2, 0)), ((1, 2), (2, 1))]
UPPER_ENTRIES = [((0, 0),), ((1, 1),), ((2, 2),), ((0, 1),), ((0, 2),), ((1, 2),)]
DIAGONAL_ENTRIES = SYMMETRIC_ENTRIES[:3]


def check_samples(samples, min_rows: int, what: str = "samples") -> np.ndarray:
    """(n, 3) finite float array with at least ``min_rows`` rows, else ApmcalError.

    Parameters
    ----------
    samples : array_like, (n, 3)
        Samples [sensor units]; rows with a NaN or inf are dropped.
    min_rows : int
        Finite rows needed.
    what : str
        Name of the samples in the error message.

    Returns
    -------
    (m, 3) array
        The finite rows, as floats.

    Raises
    ------
    ApmcalError
        When the shape is not (n, 3) or fewer than ``min_rows`` rows are finite.
    """
    s = np.asarray(samples, dtype=float)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ApmcalError(f"{what} must be an (n, 3) array, got shape {s.shape}")
    finite = np.isfinite(s).all(axis=1)
    if not finite.all():                 # copy only when something must go
        s = s[finite]
    if len(s) < min_rows:
        raise ApmcalError(f"{what}: {len(s)} finite samples, at least {min_rows} needed")
    return s


def params_to_matrix(m: np.ndarray, entries) -> np.ndarray:
    """3x3 matrix from its free parameters ``m`` laid out as ``entries``.

    Parameters
    ----------
    m : (k,) array
        Free parameters.
    entries : list
        k tuples of the (row, column) cells each parameter fills (e.g. ``SYMMETRIC_ENTRIES``).

    Returns
    -------
    (3, 3) array
        The matrix (zero in cells no entry names).
    """
    M = np.zeros((3, 3))
    for value, cells in zip(m, entries):
        for a, b in cells:
            M[a, b] = value
    return M


def matrix_to_params(M: np.ndarray, entries) -> np.ndarray:
    """Free parameters of ``M`` (first cell of each entry).

    Parameters
    ----------
    M : (3, 3) array
    entries : list
        As for :func:`params_to_matrix` (k entries).

    Returns
    -------
    (k,) array
    """
    return np.array([M[cells[0]] for cells in entries])


def geometric_residual(x: np.ndarray, s: np.ndarray, radius: float, entries,
                       jac: bool = False):
    """Residual ``|M(s − o)| − radius`` for parameters ``x = [o (3), m (len(entries))]``.

    Returns ``r`` (n,) or ``(r, J)`` with the analytic Jacobian J (n, 3 + len(entries)):
    ``∂r/∂o = −Mᵀn`` and ``∂r/∂M_ab = n_a·c_b`` with ``n = M c / |M c|``, ``c = s − o``.

    Parameters
    ----------
    x : (3 + k,) array
        Offset o [sensor units] and the k free matrix parameters.
    s : (n, 3) array
        Samples [sensor units].
    radius : float
        Field magnitude [sensor units].
    entries : list
        Layout of the matrix parameters (:func:`params_to_matrix`).
    jac : bool
        Also return the Jacobian.

    Returns
    -------
    r : (n,) array
        The residuals [sensor units].
    J : (n, 3 + k) array
        Only with ``jac``.
    """
    o = x[:3]
    M = params_to_matrix(x[3:], entries)
    c = s - o
    u = c @ M.T
    norm = np.linalg.norm(u, axis=1)
    r = norm - radius
    if not jac:
        return r
    n = u / np.where(norm > 0, norm, 1.0)[:, None]
    J = np.empty((len(s), 3 + len(entries)))
    J[:, :3] = -n @ M
    for k, cells in enumerate(entries):
        J[:, 3 + k] = sum(n[:, a] * c[:, b] for a, b in cells)
    return r, J


def _sqrtm_spd(A: np.ndarray, what: str) -> np.ndarray:
    """Principal square root of a symmetric positive-definite matrix (eigen-decomposition)."""
    A = 0.5 * (A + A.T)
    lam, V = np.linalg.eigh(A)
    if np.any(lam <= 0):
        raise ApmcalError(f"{what}: fitted quadric is not an ellipsoid (eigenvalues "
                          f"{np.array2string(lam, precision=3)}): too few or too clustered "
                          "orientations")
    return (V * np.sqrt(lam)) @ V.T


def _lstsq_full_rank(X: np.ndarray, y: np.ndarray, what: str) -> np.ndarray:
    """``(XᵀX)⁻¹Xᵀy`` as in Fig. 2, but refusing a rank-deficient design instead of inverting it."""
    beta, _, rank, sv = np.linalg.lstsq(X, y, rcond=None)
    if rank < X.shape[1] or sv[-1] < 1e-10 * sv[0]:
        raise ApmcalError(f"{what}: design rank {rank} < {X.shape[1]} unknowns: the samples do "
                          "not span enough orientations (try diagonal_only=True)")
    return beta


def sphere_fit(samples: np.ndarray) -> tuple[np.ndarray, float]:
    """Fig. 2 step 1: LS sphere ``|s|² = 2·V0·s + (S² − |V0|²)`` → (V0, S).

    Parameters
    ----------
    samples : (n, 3) array
        Sensor output [sensor units], n ≥ 4.

    Returns
    -------
    V0 : (3,) array
        Centre [sensor units].
    S : float
        Radius [sensor units].

    Raises
    ------
    ApmcalError
        On too few finite samples, a rank-deficient design or a negative squared radius.
    """
    s = check_samples(samples, 4)
    X = np.column_stack([s, np.ones(len(s))])
    y = np.sum(s ** 2, axis=1)
    beta = _lstsq_full_rank(X, y, "sphere fit ([Niespodziany] Fig. 2 step 1)")
    V0 = beta[:3] / 2.0
    S2 = beta[3] + V0 @ V0
    if S2 <= 0:
        raise ApmcalError("sphere fit ([Niespodziany] Fig. 2 step 1): negative squared radius")
    return V0, float(np.sqrt(S2))


def fit_ellipsoid_analytical(samples, radius: float | None = None, *, diagonal_only: bool = False,
                             info: dict | None = None) -> SensorCalibration:
    """Two-step analytical LS ellipsoid fit ([Niespodziany] §V.A, Fig. 2).

    Parameters
    ----------
    samples : (n, 3) array
        Sensor output in sensor units (mGauss, m/s² or raw counts).
    radius : float, optional
        Known field magnitude in the same units (|g| or the WMM field). ``None`` uses the paper's
        own step-1 estimate S, as Fig. 2 does; a given radius replaces S² in step 2.
    diagonal_only : bool
        Null w4, w5, w6 ([Niespodziany] §VII.A: accelerometer with few orientations).
    info : dict, optional
        Filled with ``S`` (step-1 radius) and ``radius_used``.

    Returns
    -------
    SensorCalibration
        ``offset = V0``, ``matrix = W⁻¹`` (symmetric); no sigma (the paper gives none).

    Raises
    ------
    ApmcalError
        On too few samples, a rank-deficient design or a quadric that is not an ellipsoid.
    """
    s = check_samples(samples, 6 if diagonal_only else 10)     # [Niespodziany] §V: ≥ 10 for 10 unknowns
    V0, S = sphere_fit(s)                       # step 1, W⁻¹ = I
    c = s - V0                                  # "hard-iron calibration application"
    R = S if radius is None else float(radius)
    # step 2: [x², y², z², xy, xz, yz]·β = S²; the cross terms carry 2·w (hence β/2 below).
    cols = [c ** 2] if diagonal_only else [c ** 2, c[:, [0]] * c[:, [1]], c[:, [0]] * c[:, [2]],
                                           c[:, [1]] * c[:, [2]]]
    X = np.hstack(cols)
    beta = _lstsq_full_rank(X, np.full(len(c), R ** 2), "[Niespodziany] Fig. 2 step 2")
    if diagonal_only:
        A = np.diag(beta)
    else:
        A = np.array([[beta[0], beta[3] / 2, beta[4] / 2],
                      [beta[3] / 2, beta[1], beta[5] / 2],
                      [beta[4] / 2, beta[5] / 2, beta[2]]])
    W_inv = _sqrtm_spd(A, "[Niespodziany] Fig. 2 step 2")   # W⁻² = A  →  W⁻¹ = A^(1/2)
    if info is not None:
        info.update({"S": S, "radius_used": R, "method": "analytical ([Niespodziany] Fig. 2)"})
    return SensorCalibration(offset=V0, matrix=W_inv)


def fit_ellipsoid_numerical(samples, radius: float | None = None, *, diagonal_only: bool = False,
                            x0=None, info: dict | None = None) -> SensorCalibration:
    """Quasi-Newton fit of V0 and symmetric W⁻¹ ([Niespodziany] §V.B, Fig. 3-4).

    Minimises the performance function of Fig. 4, ``sqrt(mean((|W⁻¹(S_p − V0)| − S)²))``, with
    BFGS (MATLAB fminunc 'quasi-newton'), from the paper's start ``[V0_analytical; 1;1;1; 0;0;0]``.
    S is fixed: ``radius`` if given, else the analytical step-1 estimate (as in the paper).
    The problem is scaled by S internally (all parameters O(1)), the analytic gradient is
    supplied and the mean square replaces the RMS; none of these changes the minimiser.

    Parameters
    ----------
    samples, radius, diagonal_only
        As for :func:`fit_ellipsoid_analytical`: (n, 3) samples [sensor units], field magnitude
        [sensor units] (None: the step-1 estimate), diagonal W⁻¹ only.
    x0 : array, optional
        Start ``[V0 (3), w1, w2, w3, w4, w5, w6]`` (first 6 only when ``diagonal_only``).
    info : dict, optional
        Filled with ``S``, ``radius_used``, ``rms`` [sensor units], ``success`` and
        ``iterations``.

    Returns
    -------
    SensorCalibration
        ``offset = V0`` (3,) [sensor units], ``matrix = W⁻¹`` (3, 3) symmetric; no sigma.

    Raises
    ------
    ApmcalError
        On too few samples or a failed sphere fit (the start).
    """
    from scipy.optimize import minimize  # here: scipy.optimize costs ~0.2 s to import

    s = check_samples(samples, 6 if diagonal_only else 10)     # [Niespodziany] §V: ≥ 10 for 10 unknowns
    V0a, S = sphere_fit(s)
    R = S if radius is None else float(radius)
    entries = DIAGONAL_ENTRIES if diagonal_only else SYMMETRIC_ENTRIES
    if x0 is None:
        x0 = np.concatenate([V0a, np.ones(3), np.zeros(len(entries) - 3)])
    x0 = np.asarray(x0, dtype=float).copy()
    x0[:3] /= R
    sn = s / R

    def perf(x):
        """Square of [Niespodziany] Fig. 4's RMS, in units of S: same minimiser, but smooth at an exact
        fit (the RMS has a |·|-like kink at zero where BFGS's line search stalls)."""
        r, J = geometric_residual(x, sn, 1.0, entries, jac=True)
        return np.mean(r * r), 2.0 * (r @ J) / len(r)

    res = minimize(perf, x0, jac=True, method="BFGS",
                   options={"maxiter": 2000, "gtol": 1e-12})
    x = res.x
    W_inv = params_to_matrix(x[3:], entries)
    if info is not None:
        info.update({"S": S, "radius_used": R, "rms": float(np.sqrt(res.fun)) * R,
                     "success": res.success,
                     "iterations": int(res.nit), "method": "numerical ([Niespodziany] Fig. 3-4)"})
    return SensorCalibration(offset=x[:3] * R, matrix=W_inv)


def gyro_offset(samples, *, n_batches: int = 10) -> SensorCalibration:
    """Gyroscope offset = mean of samples at rest ([Niespodziany] §VIII), matrix = I.

    sigma["offset"] uses batch means (``n_batches`` consecutive blocks) because low-pass filtered
    sensor noise is correlated: std(batch means)/sqrt(n_batches), not std/sqrt(n).

    Parameters
    ----------
    samples : (n, 3) array
        Gyro samples at rest [rad/s], n ≥ 2·``n_batches``.
    n_batches : int
        Number of consecutive blocks for the sigma.

    Returns
    -------
    SensorCalibration
        offset (3,) [rad/s], identity matrix, sigma["offset"] (3,) [rad/s].

    Raises
    ------
    ApmcalError
        On fewer than 2·``n_batches`` finite samples.
    """
    s = check_samples(samples, 2 * n_batches, "gyroscope samples at rest")
    blocks = np.array_split(s, n_batches)
    means = np.array([b.mean(axis=0) for b in blocks])
    sigma = means.std(axis=0, ddof=1) / np.sqrt(n_batches)
    return SensorCalibration(offset=s.mean(axis=0), matrix=np.eye(3), sigma={"offset": sigma})


def relative_mse(samples_test, cal: SensorCalibration | None, radius: float) -> float:
    """Relative mean squared magnitude error on a (held-out) test set ([Niespodziany] §VI.B, §VII.B).

    ``mean((|cal(s)| − S)²) / S²`` (dimensionless); ``cal=None`` scores the raw samples.
    The paper names the figure ("magnitude relative mean squared error") without a formula;
    this is the plain reading: MSE of the magnitude relative to the squared true magnitude.

    Parameters
    ----------
    samples_test : (n, 3) array
        Raw samples [sensor units].
    cal : SensorCalibration or None
        The calibration to score; None scores the raw samples.
    radius : float
        True field magnitude S [sensor units].

    Returns
    -------
    float
        The relative MSE (dimensionless).
    """
    s = check_samples(samples_test, 1, "test samples")
    y = s if cal is None else cal.apply(s)
    m = np.linalg.norm(y, axis=1)
    return float(np.mean((m - radius) ** 2) / radius ** 2)
