"""The 42-parameter sensor model of [Chow] §3.1: parameter vector ↔ matrices, corrections.

[Chow] (Chow, Hol, Luinge), §3.1. Upper-case letters are 3×3 matrices, S diagonal scale, N
lower-triangular non-orthogonality (unit diagonal), R a rotation:

* eq. 1, accelerometer:  y_a = S_a·N_a·a + b_a + ε_a                          [m/s²]
* eq. 2, gyroscope:      y_ω = S_ω·N_ω·R_ω·ω + b_ω + G_ω·a + ε_ω                [rad/s]
* eq. 3, magnetometer:   y_m = D_m·m + o_m + ε_m                               [mGauss]

Frames: a, ω and m are in the ACCELEROMETER frame (x along the accelerometer's x axis, y in
its xy plane: that is what a lower-triangular N_a means); R_ω is the gyro triad's misalignment
to it, and D_m holds the magnetometer's misalignment as well as its soft iron ([Chow] note
under eq. 3). The g-sensitivity acts on the true specific force a.

Parameter vector (:data:`NAMES`, 42 entries): b_a, s_a (S_a = diag(1 + s_a)), n_a (the three
sub-diagonal entries of N_a, row-major), b_ω, s_ω, n_ω, G_ω (row-major), r_ω (R_ω = Exp(r_ω),
rotation vector [rad]), D_m (row-major), o_m. :data:`NOMINAL` is the error-free sensor.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from apmcal.solvers.result import SensorCalibration

_AX = "xyz"
NAMES = ([f"acc_bias_{a}" for a in _AX] + [f"acc_scale_{a}" for a in _AX]
         + ["acc_nonorth_yx", "acc_nonorth_zx", "acc_nonorth_zy"]
         + [f"gyr_bias_{a}" for a in _AX] + [f"gyr_scale_{a}" for a in _AX]
         + ["gyr_nonorth_yx", "gyr_nonorth_zx", "gyr_nonorth_zy"]
         + [f"gyr_gsens_{r}{c}" for r in _AX for c in _AX]
         + [f"gyr_misalign_{a}" for a in _AX]
         + [f"mag_soft_{r}{c}" for r in _AX for c in _AX] + [f"mag_hard_{a}" for a in _AX])
UNITS = (["m/s²"] * 3 + ["1"] * 6 + ["rad/s"] * 3 + ["1"] * 6 + ["rad/s per m/s²"] * 9
         + ["rad"] * 3 + ["1"] * 9 + ["mGauss"] * 3)
N_PARAMS = len(NAMES)                   # 42, [Chow] §3
SLICES = {"b_a": slice(0, 3), "s_a": slice(3, 6), "n_a": slice(6, 9), "b_w": slice(9, 12),
          "s_w": slice(12, 15), "n_w": slice(15, 18), "G_w": slice(18, 27),
          "r_w": slice(27, 30), "D_m": slice(30, 39), "o_m": slice(39, 42)}
SLICES_RANGE = {k: range(v.start, v.stop) for k, v in SLICES.items()}
ACC_PARAMS = range(9)
GYR_PARAMS = range(9, 30)
MAG_PARAMS = range(30, 42)
NOMINAL = np.zeros(N_PARAMS)
NOMINAL[SLICES["D_m"]] = np.eye(3).ravel()
_LOWER = (np.array([1, 2, 2]), np.array([0, 0, 1]))     # sub-diagonal entries of N, row-major


def lower(n: np.ndarray) -> np.ndarray:
    """Unit lower-triangular non-orthogonality matrix N from its three sub-diagonal entries.

    Parameters
    ----------
    n : (3,) array
        Entries (1, 0), (2, 0), (2, 1) (dimensionless).

    Returns
    -------
    (3, 3) array
    """
    out = np.eye(3)
    out[_LOWER] = n
    return out


def matrices(x: np.ndarray) -> dict[str, np.ndarray]:
    """The model's matrices from the (42,) parameter vector ``x``.

    Parameters
    ----------
    x : (42,) array
        Parameters laid out as :data:`NAMES`.

    Returns
    -------
    dict
        "b_a" (3,) m/s², "K_a" = S_a·N_a (3, 3), "b_w" (3,) rad/s, "K_w" = S_ω·N_ω·R_ω,
        "G_w" (3, 3) rad/s per m/s², "D_m" (3, 3), "o_m" (3,) mGauss.
    """
    x = np.asarray(x, dtype=float)
    k_a = np.diag(1.0 + x[SLICES["s_a"]]) @ lower(x[SLICES["n_a"]])
    r_w = Rotation.from_rotvec(x[SLICES["r_w"]]).as_matrix()
    k_w = np.diag(1.0 + x[SLICES["s_w"]]) @ lower(x[SLICES["n_w"]]) @ r_w
    return {"b_a": x[SLICES["b_a"]], "K_a": k_a, "b_w": x[SLICES["b_w"]], "K_w": k_w,
            "G_w": x[SLICES["G_w"]].reshape(3, 3), "D_m": x[SLICES["D_m"]].reshape(3, 3),
            "o_m": x[SLICES["o_m"]]}


def matrices_many(xs: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`matrices` of many parameter vectors at once (the same numbers, stacked).

    Parameters
    ----------
    xs : (k, 42) array
        Parameter vectors laid out as :data:`NAMES`.

    Returns
    -------
    dict
        As :func:`matrices`, each entry with a leading axis of length k.
    """
    xs = np.asarray(xs, dtype=float)
    k = len(xs)

    def lower_many(n):
        out = np.broadcast_to(np.eye(3), (k, 3, 3)).copy()
        out[:, _LOWER[0], _LOWER[1]] = n
        return out

    k_a = (1.0 + xs[:, SLICES["s_a"]])[:, :, None] * lower_many(xs[:, SLICES["n_a"]])
    r_w = Rotation.from_rotvec(xs[:, SLICES["r_w"]]).as_matrix().reshape(k, 3, 3)
    k_w = (1.0 + xs[:, SLICES["s_w"]])[:, :, None] * lower_many(xs[:, SLICES["n_w"]]) @ r_w
    return {"b_a": xs[:, SLICES["b_a"]], "K_a": k_a, "b_w": xs[:, SLICES["b_w"]], "K_w": k_w,
            "G_w": xs[:, SLICES["G_w"]].reshape(k, 3, 3),
            "D_m": xs[:, SLICES["D_m"]].reshape(k, 3, 3), "o_m": xs[:, SLICES["o_m"]]}


def accelerometer_frame(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Q, L): a board-frame accelerometer matrix M (calibrated = M·(raw − offset)) split as
    M = Q·L, Q a rotation (the accelerometer frame → the board's) and L lower triangular with a
    positive diagonal (the model's K_a⁻¹, in the accelerometer frame).

    From MᵀM = LᵀL: L is the Cholesky factor of MᵀM taken in reversed axis order (the "QL"
    factorisation), so that it comes out lower rather than upper triangular.

    Parameters
    ----------
    matrix : (3, 3) array
        Invertible.

    Returns
    -------
    q : (3, 3) array
    low : (3, 3) array
    """
    m = np.asarray(matrix, float)
    flip = np.fliplr(np.eye(3))
    low = flip @ np.linalg.cholesky(flip @ m.T @ m @ flip).T @ flip
    return m @ np.linalg.inv(low), low


def from_board(acc_offset, acc_matrix, gyr_offset, mag_offset=None,
               mag_matrix=None) -> np.ndarray:
    """The parameter vector of calibrations given in the board frame (the project's
    convention, calibrated = matrix·(raw − offset)): an accelerometer's offset and matrix, a
    gyro offset alone (identity matrix on the board, no g-sensitivity) and, optionally, a
    compass's offset and matrix — e.g. the ellipsoid and static results the joint fit starts
    from. The joint model's frame is the accelerometer's (M = Q·L, :func:`accelerometer_frame`),
    so the identity gyro becomes K_ω = Q (R_ω = Q) and the compass's D_m = E⁻¹·Q; every
    condition of :mod:`apmcal.solvers.joint.residuals` then sees exactly the given
    calibrations.

    Parameters
    ----------
    acc_offset : (3,) array, m/s²
    acc_matrix : (3, 3) array
    gyr_offset : (3,) array, rad/s
    mag_offset : (3,) array, mGauss, optional
    mag_matrix : (3, 3) array, optional

    Returns
    -------
    (42,) array
        Laid out as :data:`NAMES` (the compass's entries nominal without one).
    """
    q, low = accelerometer_frame(acc_matrix)
    k_a = np.linalg.inv(low)
    scale = np.diag(k_a)
    x = NOMINAL.copy()
    x[SLICES["b_a"]] = acc_offset
    x[SLICES["s_a"]] = scale - 1.0
    x[SLICES["n_a"]] = (k_a / scale[:, None])[_LOWER]
    x[SLICES["b_w"]] = gyr_offset
    x[SLICES["r_w"]] = Rotation.from_matrix(q).as_rotvec()
    if mag_matrix is not None:
        x[SLICES["D_m"]] = (np.linalg.inv(mag_matrix) @ q).ravel()
        x[SLICES["o_m"]] = mag_offset
    return x


def correct_acc(y_a: np.ndarray, mats: dict) -> np.ndarray:
    """True specific force a [m/s²] (n, 3) from measured y_a, eq. 1 inverted.

    Parameters
    ----------
    y_a : (n, 3) array
        Measured specific force [m/s²].
    mats : dict
        :func:`matrices`.

    Returns
    -------
    (n, 3) array, m/s²
    """
    return (np.asarray(y_a) - mats["b_a"]) @ np.linalg.inv(mats["K_a"]).T


def correct_gyr(y_w: np.ndarray, a: np.ndarray, mats: dict) -> np.ndarray:
    """True angular rate ω [rad/s] (n, 3) from measured y_ω and true specific force a, eq. 2.

    Parameters
    ----------
    y_w : (n, 3) array
        Measured angular rate [rad/s].
    a : (n, 3) array
        True specific force [m/s²] (:func:`correct_acc`).
    mats : dict
        :func:`matrices`.

    Returns
    -------
    (n, 3) array, rad/s
    """
    return (np.asarray(y_w) - mats["b_w"] - a @ mats["G_w"].T) @ np.linalg.inv(mats["K_w"]).T


def correct_mag(y_m: np.ndarray, mats: dict) -> np.ndarray:
    """True field m [mGauss] (n, 3) in the accelerometer frame from measured y_m, eq. 3.

    Parameters
    ----------
    y_m : (n, 3) array
        Measured field [mGauss].
    mats : dict
        :func:`matrices`.

    Returns
    -------
    (n, 3) array, mGauss
    """
    return (np.asarray(y_m) - mats["o_m"]) @ np.linalg.inv(mats["D_m"]).T


def calibration_parts(x: np.ndarray) -> np.ndarray:
    """The result in the project's convention ``calibrated = matrix @ (measured − offset)``:
    flat vector of acc offset, acc matrix, gyro offset, gyro matrix, g-sensitivity, mag offset,
    mag matrix (see :func:`unflatten_parts`).

    Parameters
    ----------
    x : (42,) array
        Parameters laid out as :data:`NAMES`.

    Returns
    -------
    (45,) array
        Offsets [m/s², rad/s, mGauss], matrices (dimensionless) and g-sensitivity
        [rad/s per m/s²], each 3×3 row-major.
    """
    m = matrices(x)
    return np.concatenate([m["b_a"], np.linalg.inv(m["K_a"]).ravel(), m["b_w"],
                           np.linalg.inv(m["K_w"]).ravel(), m["G_w"].ravel(), m["o_m"],
                           np.linalg.inv(m["D_m"]).ravel()])


_PARTS = (("acc", "offset", 3), ("acc", "matrix", 9), ("gyr", "offset", 3),
          ("gyr", "matrix", 9), ("gyr", "g_sensitivity", 9), ("mag", "offset", 3),
          ("mag", "matrix", 9))


def unflatten_parts(v: np.ndarray) -> dict[tuple[str, str], np.ndarray]:
    """(sensor, part) → array, from a vector laid out as :func:`calibration_parts`.

    Parameters
    ----------
    v : (45,) array

    Returns
    -------
    dict
        (sensor, part) → (3,) offset or (3, 3) matrix / g-sensitivity.
    """
    out, k = {}, 0
    for sensor, part, size in _PARTS:
        val = np.asarray(v[k:k + size])
        out[(sensor, part)] = val.reshape(3, 3) if size == 9 else val
        k += size
    return out


def sensor_calibrations(x: np.ndarray, cov: np.ndarray, sensors=("acc", "gyr", "mag"),
                        step: float = 1e-7) -> tuple[dict[str, SensorCalibration], dict]:
    """SensorCalibrations (with one-sigma figures) of the parameters ``x`` and their (42, 42)
    covariance ``cov``; the σ of the derived offsets and matrices come from J·cov·Jᵀ with a
    forward-difference Jacobian J of :func:`calibration_parts`.

    Returns (sensor → SensorCalibration, {"gyr_g_sensitivity": (3, 3), "..._sigma": (3, 3)}).

    Parameters
    ----------
    x : (42,) array
        Parameters laid out as :data:`NAMES`.
    cov : (42, 42) array
        Their covariance.
    sensors : tuple of str
        The sensors to return ("acc", "gyr", "mag").
    step : float
        Forward-difference step of the Jacobian.

    Returns
    -------
    dict
        sensor → SensorCalibration (offset (3,), matrix (3, 3), their σ).
    dict
        "gyr_g_sensitivity" and "gyr_g_sensitivity_sigma", (3, 3) [rad/s per m/s²].
    """
    f0 = calibration_parts(x)
    xs = x[None] + step * np.eye(x.size)                  # one forward step per parameter
    m = matrices_many(xs)
    inv = {k: np.linalg.inv(m[k]).reshape(x.size, 9) for k in ("K_a", "K_w", "D_m")}
    parts = np.concatenate([m["b_a"], inv["K_a"], m["b_w"], inv["K_w"],
                            m["G_w"].reshape(x.size, 9), m["o_m"], inv["D_m"]], axis=1)
    jac = ((parts - f0) / step).T
    sig = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", jac, cov, jac), 0, None))
    val, s = unflatten_parts(f0), unflatten_parts(sig)
    out = {name: SensorCalibration(offset=val[(name, "offset")], matrix=val[(name, "matrix")],
                                   sigma={"offset": s[(name, "offset")],
                                          "matrix": s[(name, "matrix")]})
           for name in sensors}
    extra = {"gyr_g_sensitivity": val[("gyr", "g_sensitivity")],
             "gyr_g_sensitivity_sigma": s[("gyr", "g_sensitivity")]}
    return out, extra
