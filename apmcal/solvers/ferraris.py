"""Ferraris et al. (1995) six-position + three-rotation calibration, the benchmark of [Oppong] §4.

Sensor models ([Oppong] eq. 1, 2), sensor frame::

    a_s = K_a R_a a_p + b_a          ω_s = K_g R_g ω_p + b_g(t) + K_ga a_p

so the calibration in apmcal's convention (apmcal/solvers/result.py) is
``matrix = (K R)⁻¹``, ``offset = b``: ``a_p = (K_a R_a)⁻¹ (a_s − b_a)``.

Accelerometer ([Oppong] §4.1-4.2): U+ holds the mean accelerometer vectors (as columns) of the
holds x_p, y_p, z_p (that axis UP, reading +g; imucal's naming), U− those of x_a, y_a, z_a.
Bias ``b = diag((U+ + U−)/2)`` (eq. 3), ``K_a R_a = (U+ − U−)/(2G)`` with G = Q, the mean column
norm of U+ (eq. 4), or a known local gravity.

Gyroscope: bias b0 + b1·t (eq. 5) fitted by least squares on all static samples, optionally with
g-sensitivity K_ga (imucal: (Ug+ − Ug−)/(2g)) and the Earth rate removed; ``K_g R_g`` from the
bias-corrected integral of each 360° rotation divided by the turned angle ([Oppong] §4.4).

Where this differs from imucal (FerrarisCalibration, the peer tool; ardupilot-facts.md "Peer
tool: imucal"): imucal's gyro bias is the plain mean of the six holds, with no drift and no Earth
rate. With ``bias_drift=False, earth_rate=False, gravity=9.81`` and the same sections this module
reproduces imucal to rounding (tests/test_ferraris.py). With drift enabled the gyro bias is
referred to ``t_ref`` and the rotation integrals use the bias at their own time; on imucal's
example session the fitted drift is ~1.5e-6 rad/s² (about 1.5 sigma, i.e. barely detectable)
and changes the gyro matrix by 5e-5 relative; on a simulated session with 2e-4 rad/s² of drift
the constant-bias (imucal) matrix is off by 7.6e-3, ours by 6e-5 (tests/test_ferraris.py).

Earth rate: with only the latitude known, the component Ω sin φ along "up" (taken from the
accelerometer) is removed from every static mean; the horizontal component Ω cos φ needs the
heading, which a hand-held session does not give, so it is left in the bias (≤ 7.3e-5 rad/s,
reported as ``report.gyro_turns.earth_rate_left``).

Identifiability: the vertical Earth rate Ω sin φ · up is parallel to the specific force, so it is
indistinguishable from a diagonal g-sensitivity Ω sin φ / g · I. Without ``earth_rate`` (or with
no latitude) it ends up in K_ga, not in the bias; with it, K_ga is the sensor's own.

Uncertainty (``SensorCalibration.sigma``): each hold mean gets std/√n; accelerometer offset and
matrix sigmas are propagated through the equations above by a numerical Jacobian, each hold mean's σ
widened by the scatter the redundant holds show beyond their noise (apmcal/solvers/misfit.py:
quadratic scale, temperature drift between holds, faces not square); gyro bias and
drift sigmas come from the least-squares covariance; each rotation integral gets
σ_b·T ⊕ σ_noise·√(Σ Δt²) and goes through the same Jacobian. All assume white noise, so they are
lower bounds when the noise is correlated (hand tremor, slow thermal drift).

Default scale: without ``gravity`` or ``lat_deg`` the accelerometer is normalised to Q, the
sensor's own mean reading ([Oppong] eq. 4), so calibrated magnitudes come out ≈ Q, not g; a
warning says so.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.core.blas_threads import single_threaded_blas
from apmcal.core.constants import EARTH_RATE, normal_gravity
from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.ferraris_regions import AXES, FerrarisRegions
from apmcal.preprocessing.rotations import Rotation, integrate_slice, sample_intervals
from apmcal.preprocessing.static import ARDUPILOT_FACE, POSES, StaticSegment
from apmcal.solvers.gyro_bias import fit_gyro_bias, integrate_motions, motions_between_holds
from apmcal.solvers.misfit import hold_misfit
from apmcal.solvers.report_types import CalibrationReport, GyroTurns, Hold, Holds, SixFaceFit, Turn
from apmcal.solvers.result import Calibration, SensorCalibration
from apmcal.solvers.uncertainty import jacobian_sigma

MOTION_FACTOR = 3.0          # a hold noisier than 3 × the median hold is flagged
ANGLE_WARN_DEG = 20.0        # rotation integral further than this from ±360° is flagged (>5 % scale)


# --------------------------------------------------------------------------- pure equations
def u_matrices(means: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """U+ and U− ([Oppong] §4.2): columns are the mean vectors of x_p,y_p,z_p and x_a,y_a,z_a.

    Parameters
    ----------
    means : dict
        Pose name ("x_p", ..., "z_a") → (3,) mean vector [sensor units].

    Returns
    -------
    u_plus, u_minus : (3, 3) array
        One column per axis x, y, z [sensor units].
    """
    up = np.column_stack([means[a + "_p"] for a in AXES])
    um = np.column_stack([means[a + "_a"] for a in AXES])
    return up, um


def accel_bias(u_plus: np.ndarray, u_minus: np.ndarray) -> np.ndarray:
    """[Oppong] eq. 3: b_i = (a_{i,p_i} + a_{i,ap_i}) / 2, the diagonal of (U+ + U−)/2.

    Parameters
    ----------
    u_plus, u_minus : (3, 3) array
        From :func:`u_matrices` [m/s²].

    Returns
    -------
    (3,) array
        The bias b [m/s²].
    """
    return np.diag((u_plus + u_minus) / 2.0).copy()


def gravity_q(u_plus: np.ndarray) -> float:
    """[Oppong] eq. 4: Q = mean of the column norms of U+.

    Parameters
    ----------
    u_plus : (3, 3) array
        From :func:`u_matrices` [m/s²].

    Returns
    -------
    float
        Q [m/s²].
    """
    return float(np.mean(np.linalg.norm(u_plus, axis=0)))


def accel_coupling(u_plus: np.ndarray, u_minus: np.ndarray, g: float) -> np.ndarray:
    """[Oppong] §4.2: K_a R_a = (U+ − U−) / (2 g) (g = Q or the known local gravity).

    Parameters
    ----------
    u_plus, u_minus : (3, 3) array
        From :func:`u_matrices` [m/s²].
    g : float
        Gravity [m/s²].

    Returns
    -------
    (3, 3) array
        K_a R_a (dimensionless); the calibration matrix is its inverse.
    """
    return (u_plus - u_minus) / (2.0 * g)


def gyro_g_sensitivity(ug_plus: np.ndarray, ug_minus: np.ndarray, g: float) -> np.ndarray:
    """imucal's eq. 9: K_ga = (Ug+ − Ug−) / (2 g), gyro units per m/s².

    Parameters
    ----------
    ug_plus, ug_minus : (3, 3) array
        Gyro means of the six faces as :func:`u_matrices` lays them out [rad/s].
    g : float
        Gravity [m/s²].

    Returns
    -------
    (3, 3) array
        K_ga [rad/s per m/s²].
    """
    return (ug_plus - ug_minus) / (2.0 * g)


def gyro_coupling(integrals: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """[Oppong] §4.4: K_g R_g = W · diag(angles)⁻¹, column j = integral of rotation j / its angle.

    Parameters
    ----------
    integrals : (3, 3) array
        W: column j the bias-corrected gyro integral over rotation j [rad].
    angles : (3,) array
        Turned angle of each rotation [rad].

    Returns
    -------
    (3, 3) array
        K_g R_g (dimensionless); the calibration matrix is its inverse.
    """
    return np.asarray(integrals, dtype=float) / np.asarray(angles, dtype=float)[None, :]


def earth_rate_up(up_axes: np.ndarray, lat_deg: float) -> np.ndarray:
    """Vertical Earth-rate component [rad/s] seen by a still sensor, along its "up" unit vectors.

    In NED the Earth rate is Ω(cos φ, 0, −sin φ) (ardupilot-facts.md), i.e. +Ω sin φ along up;
    the horizontal part depends on the heading and is not included.

    Parameters
    ----------
    up_axes : (3,) or (n, 3) array
        Unit "up" vectors in the sensor frame.
    lat_deg : float
        Latitude [deg].

    Returns
    -------
    (1, 3) or (n, 3) array
        The vertical Earth rate along ``up_axes`` [rad/s].
    """
    return EARTH_RATE * np.sin(np.radians(lat_deg)) * np.atleast_2d(up_axes)


# --------------------------------------------------------------------------- accelerometer
def _accel_part(poses: dict[str, StaticSegment], gravity: float | None, lat_deg: float | None,
                segments=None):
    """Accelerometer bias and matrix ([Oppong] §4.1-4.2) with σ widened by the model misfit.

    The hold means' σ is their white noise (std/√n) plus τ, the scatter the redundant holds
    show beyond it on each axis (:mod:`apmcal.solvers.misfit`); the noise-only σ is kept in the
    report (:class:`~apmcal.solvers.report_types.SixFaceFit`).
    """
    up, um = u_matrices({k: s.acc_mean for k, s in poses.items()})
    sp, sm = u_matrices({k: s.acc_std / np.sqrt(s.n) for k, s in poses.items()})
    misfit = hold_misfit(poses, segments)
    q = gravity_q(up)
    if gravity is not None:
        g, source = float(gravity), "given"
    elif lat_deg is not None:
        g, source = normal_gravity(lat_deg), f"normal gravity at {lat_deg:.4f} deg"
    else:
        g, source = q, "Q ([Oppong] eq. 4)"

    def solve(x):
        u_p, u_m = x[:9].reshape(3, 3), x[9:].reshape(3, 3)
        gg = gravity_q(u_p) if gravity is None and lat_deg is None else g
        return np.concatenate([accel_bias(u_p, u_m), np.linalg.inv(accel_coupling(u_p, u_m, gg)).ravel()])

    x = np.concatenate([up.ravel(), um.ravel()])
    y = solve(x)
    noise_only = jacobian_sigma(solve, x, np.concatenate([sp.ravel(), sm.ravel()]))
    # row i of U± is sensor axis i: its readings get that axis' τ on top of their noise
    tau = misfit.tau[:, None]
    sy = jacobian_sigma(solve, x, np.concatenate([np.hypot(sp, tau).ravel(),
                                                  np.hypot(sm, tau).ravel()]))
    # an offset is further uncertain by how far its other estimates (the checks) lie from it
    sy[:3] = np.hypot(sy[:3], misfit.offset_spread)
    cal = SensorCalibration(offset=y[:3], matrix=y[3:].reshape(3, 3),
                            sigma={"offset": sy[:3], "matrix": sy[3:].reshape(3, 3)})
    info = SixFaceFit(u_plus=up, u_minus=um, q=q, gravity=g, gravity_source=source,
                      misfit=misfit, sigma_noise_only={"offset": noise_only[:3],
                                                       "matrix": noise_only[3:].reshape(3, 3)})
    return cal, info, g


# --------------------------------------------------------------------------- gyroscope
def _static_rows(t, gyr, segs, acc_cal, lat_deg, earth_rate):
    """Per-sample rows (t, gyro − known Earth rate, segment's mean calibrated acc)."""
    ts, ys, fs = [], [], []
    for s in segs:
        k = s.kept()               # merged holds leave their knocks out
        y = gyr[k]
        if earth_rate and lat_deg is not None:
            f = acc_cal[k].mean(axis=0)
            y = y - earth_rate_up(f / np.linalg.norm(f), lat_deg)
        ts.append(t[k])
        ys.append(y)
        fs.append(np.repeat(acc_cal[k].mean(axis=0)[None, :], len(k), axis=0))
    return np.concatenate(ts), np.vstack(ys), np.vstack(fs)


@dataclass(frozen=True)
class GyroModel:
    """What the gyro model of :func:`ferraris_calibration` includes.

    Attributes
    ----------
    bias_drift : bool
        Bias b0 + b1·(t − t_ref) ([Oppong] eq. 5) instead of a constant.
    earth_rate : bool
        Remove the vertical Earth rate from the static means (needs the latitude).
    g_sensitivity : bool
        Estimate and remove the g-sensitivity K_ga [rad/s per m/s²].
    expected_angle_deg : float or None
        Turned angle of each rotation (imucal: −360); None: ±360 with the integral's sign.
    gyro_step : float
        Quantisation step of integer telemetry [rad/s] (RAW_IMU: 1 mrad/s), counted in the
        matrix σ.
    """

    bias_drift: bool = True
    earth_rate: bool = True
    g_sensitivity: bool = True
    expected_angle_deg: float | None = None
    gyro_step: float = 0.0

    def removes_earth_rate(self, lat_deg: float | None) -> bool:
        """True when the vertical Earth rate is removed: asked for and the latitude known."""
        return self.earth_rate and lat_deg is not None

    def is_classic(self, lat_deg: float | None) -> bool:
        """imucal's model: a constant bias, no Earth rate."""
        return not self.bias_drift and not self.removes_earth_rate(lat_deg)


def _gyro_bias(t, gyr, acc_cal, regions, g, lat_deg, model: GyroModel):
    """Gyro bias [rad/s] (and drift [rad/s²], g-sensitivity) from the still holds.

    Returns (SensorCalibration with offset, drift, t_ref, g-sensitivity and their σ;
    GyroTurns with t_ref and the Earth rate left in the bias)."""
    if model.is_classic(lat_deg):
        # imucal: plain mean of all samples of the six holds; K_ga from the hold differences
        allg = np.vstack([gyr[regions.poses[p].kept()] for p in POSES])
        b0, b1 = allg.mean(axis=0), np.zeros(3)
        sb0, sb1 = allg.std(axis=0, ddof=1) / np.sqrt(len(allg)), np.zeros(3)
        ugp, uga = u_matrices({k: s.gyr_mean for k, s in regions.poses.items()})
        kga = gyro_g_sensitivity(ugp, uga, g) if model.g_sensitivity else None
        skga, t_ref = None, 0.0
    else:
        ts, ys, fs = _static_rows(t, gyr, regions.bias_holds(), acc_cal, lat_deg,
                                  model.earth_rate)
        t_ref = float(ts.mean())
        b0, b1, kga, sb0, sb1, skga = fit_gyro_bias(ts, ys, fs if model.g_sensitivity else None,
                                                    drift=model.bias_drift, t_ref=t_ref)
    # The Earth rate left in the bias (its horizontal part Ω cos φ, or all of Ω when it was not
    # removed) is a vector of known length and unknown heading: σ of one axis = length/√3.
    # On a clean simulated session it was 2-6σ of the noise-only σ (benchmarks/sigma_coverage.py).
    left = EARTH_RATE * (np.cos(np.radians(lat_deg)) if model.removes_earth_rate(lat_deg)
                         else 1.0)
    sb0 = np.hypot(sb0, left / np.sqrt(3.0))
    sigma = {"offset": sb0, "drift": sb1} if model.bias_drift else {"offset": sb0}
    if skga is not None:
        sigma["g_sensitivity"] = skga
    cal = SensorCalibration(offset=b0, drift=b1, t_ref=t_ref, sigma=sigma,
                            g_sensitivity=np.zeros((3, 3)) if kga is None else kga)
    earth_left = (EARTH_RATE * np.cos(np.radians(lat_deg)) if model.removes_earth_rate(lat_deg)
                  else None)
    return cal, GyroTurns(t_ref=t_ref, earth_rate_left=earth_left)


def _rotation_integral(t, gyr, acc_cal, r: Rotation, regions, bias: SensorCalibration,
                       lat_deg, model: GyroModel, noise: np.ndarray):
    """The bias-corrected gyro integral over rotation ``r`` [rad] (3,) and its σ (3,)."""
    moves = [] if model.is_classic(lat_deg) else motions_between_holds(r, regions.bias_holds())
    if moves:
        # Our improvement: only the motions are integrated, each against the bias of the
        # holds around it. Those holds carry everything static the bias model misses (the
        # horizontal Earth rate, whose body projection changes with every step, and the
        # bias random walk), which the global b0 + b1·t leaves in the integral over the
        # pauses (~Ω·cos φ·T ≈ 5e-3 rad for a 70 s turn, 8e-4 in the matrix).
        return integrate_motions(t, gyr, moves, model.gyro_step)
    sl = slice(r.i0, r.i1)
    cor = gyr[sl] - bias.offset - np.outer(t[sl] - bias.t_ref, bias.drift)
    if np.any(bias.g_sensitivity):
        cor = cor - acc_cal[sl] @ bias.g_sensitivity.T
    if model.removes_earth_rate(lat_deg):
        f = acc_cal[sl].mean(axis=0)
        cor = cor - earth_rate_up(f / np.linalg.norm(f), lat_deg)
    dur = t[r.i1 - 1] - t[r.i0]
    sigma = np.hypot(bias.sigma["offset"] * dur,
                     noise * np.sqrt((sample_intervals(t[sl]) ** 2).sum()))
    return integrate_slice(t[sl], cor), sigma


def _gyro_matrix(t, gyr, acc_cal, regions, bias: SensorCalibration, lat_deg,
                 model: GyroModel, warnings: list[str]):
    """Gyro coupling matrix and its σ from the three turns ([Oppong] §4.4; [Ferraris] eq. 22), or None (with a
    warning) when a turn is missing; and the integrals [rad] and angles [deg] of the turns."""
    missing = [a for a in AXES if a not in regions.rotations]
    if missing:
        warnings.append(f"no 360° rotation about {', '.join(missing)}: gyro matrix not estimated (identity)")
        return None, None, None
    w, sw, angles = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3)
    noise = np.median([s.gyr_std for s in regions.poses.values()], axis=0)
    for j, a in enumerate(AXES):
        w[:, j], sw[:, j] = _rotation_integral(t, gyr, acc_cal, regions.rotations[a], regions,
                                               bias, lat_deg, model, noise)
        expected = model.expected_angle_deg
        sign = np.sign(w[j, j]) if expected is None else np.sign(expected)
        angles[j] = np.radians(360.0 if expected is None else abs(expected)) * sign
        err = abs(abs(np.degrees(w[j, j])) - 360.0)
        if err > ANGLE_WARN_DEG:
            warnings.append(f"rotation about {a} integrates to {np.degrees(w[j, j]):.1f}°, "
                            f"{err:.1f}° from a full turn")

    def solve(x):
        return np.linalg.inv(gyro_coupling(x.reshape(3, 3), angles)).ravel()

    matrix = solve(w.ravel()).reshape(3, 3)
    sigma = jacobian_sigma(solve, w.ravel(), sw.ravel()).reshape(3, 3)
    return matrix, sigma, (w, np.degrees(angles))


def _gyro_part(t, gyr, acc_cal, regions, g, lat_deg, model: GyroModel, warnings: list[str]):
    """Gyro bias ([Oppong] eq. 5) then coupling matrix ([Oppong] §4.4): (SensorCalibration,
    GyroTurns)."""
    cal, info = _gyro_bias(t, gyr, acc_cal, regions, g, lat_deg, model)
    matrix, sigma, turns = _gyro_matrix(t, gyr, acc_cal, regions, cal, lat_deg, model, warnings)
    if matrix is not None:
        cal.matrix = matrix
        cal.sigma["matrix"] = sigma
        info.integrals_rad, info.angles_deg = turns
    return cal, info


# --------------------------------------------------------------------------- driver
def _quality_warnings(poses: dict[str, StaticSegment], warnings: list[str]) -> None:
    noise = np.array([np.linalg.norm(s.acc_std) for s in poses.values()])
    med = np.median(noise)
    for (name, s), nz in zip(poses.items(), noise):
        if nz > MOTION_FACTOR * med:
            warnings.append(f"hold {name} noisy (acc std {nz:.3g} > {MOTION_FACTOR} × median "
                            f"{med:.3g}): motion?")
        if s.tilt_deg > 10.0:
            warnings.append(f"hold {name} tilted {s.tilt_deg:.1f}° from its axis")


@single_threaded_blas
def ferraris_calibration(t, acc, gyr, regions: FerrarisRegions, *, lat_deg: float | None = None,
                         gravity: float | None = None, bias_drift: bool = True,
                         earth_rate: bool = True, g_sensitivity: bool = True,
                         expected_angle_deg: float | None = None,
                         gyro_step: float = 0.0) -> Calibration:
    """Ferraris calibration of accelerometer (m/s²) and gyroscope (rad/s), [Oppong] §4.

    Parameters
    ----------
    t : (n,) array, s
    acc : (n, 3) array
        Sensor frame (m/s² for a calibrated output in m/s² when gravity is known).
    gyr : (n, 3) array, rad/s, or None (accelerometer only)
    regions : FerrarisRegions
        The six faces, the turns and the holds
        (:func:`apmcal.preprocessing.ferraris_regions.ferraris_regions`).
    lat_deg : float, optional
        Latitude [deg]: normal gravity for the accelerometer scale, vertical Earth rate for the gyro.
    gravity : float, optional
        Local gravity [m/s²]; default normal_gravity(lat) or Q (eq. 4) when lat is unknown.
    bias_drift, earth_rate, g_sensitivity, expected_angle_deg, gyro_step
        The gyro model (:class:`GyroModel`): bias b0 + b1 (t − t_ref) ([Oppong] eq. 5) or
        constant; vertical Earth rate removed from the still means (needs ``lat_deg``); gyro
        g-sensitivity K_ga estimated and removed (the gyro's ``g_sensitivity``, applied with
        the calibrated specific force); turned angle of each rotation (imucal: −360;
        default ±360 with the integral's sign); quantisation step of integer telemetry [rad/s]
        (RAW_IMU: 1 mrad/s), whose error in the rotation integrals is counted in the matrix σ.

    Returns
    -------
    Calibration
        With sensors "acc" (and "gyr", with drift and K_ga), sigma filled, ``report``
        with the holds, turns, U+, U−, Q, gravity used, misfit, rotation integrals and warnings.

    Raises
    ------
    ApmcalError
        When a face is missing or the gyro bias is not identifiable.
    """
    t = np.asarray(t, dtype=float)
    acc = np.asarray(acc, dtype=float)
    gyr = None if gyr is None else np.asarray(gyr, dtype=float)
    poses = regions.poses
    missing = [p for p in POSES if p not in poses]
    if missing:
        faces = ", ".join(f"{p} ({ARDUPILOT_FACE[p]})" for p in missing)
        raise ApmcalError(f"Ferraris calibration needs all six holds; missing {faces}")
    warnings: list[str] = []
    _quality_warnings(poses, warnings)
    acc_cal, acc_info, g = _accel_part(poses, gravity, lat_deg, regions.holds)
    if acc_info.gravity_source.startswith("Q"):
        warnings.append(f"accelerometer scaled to Q = {acc_info.q:.4f} (its own mean norm), not "
                        "to local gravity: pass lat_deg or gravity for an absolute scale")
    report = CalibrationReport(warnings=warnings, six_face=acc_info, holds=Holds(
        count=None if regions.holds is None else len(regions.holds),
        used={k: Hold(s.start, s.end, s.n) for k, s in poses.items()}))
    sensors = {"acc": acc_cal}
    if gyr is not None:
        model = GyroModel(bias_drift, earth_rate, g_sensitivity, expected_angle_deg, gyro_step)
        if earth_rate and lat_deg is None:
            warnings.append("latitude unknown: Earth rate not removed from the gyro bias")
        gcal, ginfo = _gyro_part(t, gyr, acc_cal.apply(acc), regions, g, lat_deg, model,
                                 warnings)
        sensors["gyr"] = gcal
        report.gyro_turns = ginfo
        report.rotations = {a: Turn(r.start, r.end, r.angle_deg)
                            for a, r in regions.rotations.items()}
    return Calibration(method="ferraris", sensors=sensors, report=report)
