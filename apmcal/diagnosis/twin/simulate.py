"""The simulated twin of a real session, made by sitl's own error model.

The twin has the real session's sample times, temperatures, battery current, hold orientations
and moves (:mod:`apmcal.diagnosis.session.trajectory`); its sensor errors are the fitted model written
as a :class:`apmcal.sensor_model.truth.Truth` (:func:`twin_truth`) and run through
:class:`apmcal.sensor_model.imu.ImuErrorModel` at the log's rate. What sitl computes in its vehicle
rather than in the error model — Earth rate, gravity, the accelerometer's time offset, hand
tremor — is computed here the way :meth:`apmcal_sim.vehicle.SimVehicle._sense` does it.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from apmcal.core.constants import EARTH_RATE
from apmcal.diagnosis.compute import reuse
from apmcal.diagnosis.model.nominal import ModelFit, calibrated_rate, hold_vectors, per_hold
from apmcal.diagnosis.session import trajectory
from apmcal.diagnosis.twin.draws import replayed

DEG = np.pi / 180.0
# the twin's noise seeds live far from any seed a simulated "real" log is made with (sitl's
# --seed): the same seed would give the twin the very noise of the data it is compared with
TWIN_SEEDS = 0x7D1A << 32


def twin_truth(fit: ModelFit, noise, fs: float):
    """The fitted model as sitl's Truth (sensor frame = board frame, no mounting rotation).

    Parameters
    ----------
    fit : ModelFit
    noise : NoiseModel
    fs : float
        The log's sample rate [Hz] (sitl's noise densities are set for it).

    Returns
    -------
    apmcal.sensor_model.truth.Truth
    """
    from apmcal.sensor_model.truth import DIAGNOSIS_EFFECTS, NOMINAL_EFFECTS, Truth

    truth = Truth()
    on = set(NOMINAL_EFFECTS)
    for effect in fit.effects:
        on.update(DIAGNOSIS_EFFECTS.get(effect, ()))
    _acc_truth(truth, fit)
    _gyro_truth(truth, fit)
    _mag_truth(truth, fit)
    _noise_truth(truth, noise, fs, on)
    truth.enabled = {e: (e in on) for e in truth.enabled}
    return truth


def _theta(names: list, theta: np.ndarray, effect: str) -> np.ndarray:
    rows = [i for i, n in enumerate(names) if n == effect]
    return theta[rows] if rows else np.zeros((0, 3))


def _acc_truth(truth, fit: ModelFit) -> None:
    geo = fit.acc
    if geo.geometry:
        scale = np.exp(np.asarray(geo.params["log_scale"]))
        truth.acc_scale = scale.tolist()
        truth.acc_cross_axis = list(geo.params.get("alpha", [0.0, 0.0, 0.0]))
        truth.acc_bias = geo.offset.tolist()
    truth.scale_nonlinearity = {"acc": geo.k2.tolist(), "gyro": [0.0, 0.0, 0.0]}
    temp = _theta(fit.acc_column_names, geo.theta, "temperature_drift")
    truth.temperature = {"ambient_c": fit.refs.temp_c, "rise_k": 0.0, "tau_s": 1.0,
                         "acc_coef": (temp[0] if len(temp) else np.zeros(3)).tolist(),
                         "gyro_coef": [0.0, 0.0, 0.0]}


def _gyro_truth(truth, fit: ModelFit) -> None:
    g = fit.gyr
    drift = _theta(fit.gyr_columns, g.theta, "bias_drift")
    drift = drift[0] if len(drift) else np.zeros(3)
    truth.gyro_bias = (g.offset - drift * fit.refs.t_s).tolist()    # sitl adds drift·t
    truth.gyro_bias_drift = drift.tolist()
    temp = _theta(fit.gyr_columns, g.theta, "temperature_drift")
    if len(temp):
        truth.temperature["gyro_coef"] = temp[0].tolist()
    gsens = _theta(fit.gyr_columns, g.theta, "g_sensitivity")
    truth.g_sensitivity = (gsens.T if len(gsens) else np.zeros((3, 3))).tolist()
    dyn = fit.dynamics
    truth.gyro_scale, truth.gyro_misalignment = dyn.gyro_scale.tolist(), dyn.gyro_gamma.tolist()
    truth.time_offset = dyn.time_offset_s
    if "triangle_drift" in fit.gyr_vectors:
        speed = g.vector_coef[fit.gyr_vectors.index("triangle_drift")]
        truth.triangle_drift = {"speed_dps_per_min": float(np.degrees(speed)),
                                "time_min": fit.refs.drift_time_min}


def _mag_truth(truth, fit: ModelFit) -> None:
    if fit.mag is None or not fit.mag.geometry:
        truth.mag_hard_iron, truth.mag_soft_iron = [0.0] * 3, np.eye(3).tolist()
        return
    from apmcal.sensor_model.truth import FULL_THROTTLE_CURRENT_A

    k_amp = _theta(fit.mag_column_names, fit.mag.theta, "mag_interference")
    k_amp = k_amp[0] if len(k_amp) else np.zeros(3)
    # the fit's offset holds k·I_ref; sitl adds i·throttle with throttle = I / 20 A
    truth.mag_hard_iron = (fit.mag.offset - k_amp * fit.refs.current_a).tolist()
    truth.mag_soft_iron = fit.mag.forward.tolist()
    truth.mag_interference = (k_amp * FULL_THROTTLE_CURRENT_A).tolist()


def _noise_truth(truth, noise, fs: float, on: set) -> None:
    density = lambda s: (np.asarray(s) / np.sqrt(fs / 2)).tolist()  # noqa: E731  σ = N·√(fs/2)
    truth.acc_noise = density(noise["acc"].sigma)
    truth.gyro_noise = density(noise["gyr"].sigma)
    if "mag" in noise:
        truth.mag_noise = np.asarray(noise["mag"].sigma).tolist()
    gyr, acc = noise["gyr"], noise["acc"]
    if gyr.rw_q is not None:
        truth.gyro_bias_random_walk = np.asarray(gyr.rw_q).tolist()
    cut = {k: (n.cutoff_hz if n.cutoff_hz is not None else fs) for k, n in
           (("acc", acc), ("gyro", gyr))}
    truth.lowpass_hz = cut
    # sitl rounds acc and gyro to its ADC steps when "quantization" is on: a sensor whose log
    # samples are not on a lattice gets an lsb of 0, which leaves it unrounded (a step "far
    # below its noise" would saturate it at 32767 steps: ±3e-5 rad/s for a 1e-9 step)
    truth.quantization = dict(truth.quantization)
    truth.quantization["acc_lsb_per_g"] = 9.80665 / float(np.mean(acc.step)) \
        if acc.step is not None else 0.0
    truth.quantization["gyro_lsb_per_dps"] = DEG / float(np.mean(gyr.step)) \
        if gyr.step is not None else 0.0
    if acc.step is None and gyr.step is None:
        on.discard("quantization")
    truth.motion_contamination = dict(truth.motion_contamination,
                                      tremor_deg=gyr.tremor_deg, sway_deg=gyr.sway_deg)


def motion_of(session, fit: ModelFit) -> tuple[list, "trajectory.Trajectory"]:
    """Hold attitudes and the trajectory of the session, as ``fit`` sees them.

    Returns
    -------
    hold_rot : list of (3, 3) arrays
        Attitude R_nb of each hold.
    trajectory : Trajectory
        At the IMU sample times, moves following the calibrated gyro.
    """
    n_holds = len(session.holds)
    up = per_hold(fit.up, n_holds)
    north = per_hold(fit.north, n_holds) if fit.north is not None else None
    hold_rot = trajectory.hold_attitudes(session.holds, up, north)
    true_rate = calibrated_rate(session, fit) @ np.linalg.inv(fit.dynamics.forward).T
    return hold_rot, trajectory.build(session, hold_rot, true_rate)


def simulate(session, fit: ModelFit, noise, seed: int = 0, motion_path=None):
    """A copy of ``session`` whose acc, gyr (and mag) samples come from the twin.

    ``motion_path``: (hold attitudes, trajectory) to reuse (:func:`motion_of`); the real poses
    and moves are the same for every model of a session, so an evaluator builds them once.
    The real motion inside the holds (``fit.hold_motion``, when ``motion_contamination`` is
    modelled) is the twin's too.

    Parameters
    ----------
    session : Session
    fit : ModelFit
    noise : NoiseModel
    seed : int
        Offset of the twin's noise seed from ``TWIN_SEEDS``.
    motion_path : tuple, optional
        (hold attitudes, trajectory) of :func:`motion_of`.

    Returns
    -------
    twin : Session
        acc [m/s²], gyr [rad/s] (and mag [mGauss]) simulated at the real sample times.
    truth : apmcal.sensor_model.truth.Truth
        The error model that made them.
    """
    from apmcal.sensor_model.imu import ImuErrorModel

    hold_rot, traj = motion_path or motion_of(session, fit)
    t = session.t
    truth = twin_truth(fit, noise, session.fs)
    formatted = _truncated_format(session, truth)
    tremor = fit.hold_motion is not None
    if tremor:
        traj = trajectory.with_hold_motion(traj, session, *fit.hold_motion)
    rot, rate = traj.rot, traj.rate
    f_hold, b_hold = hold_vectors(fit, len(session.holds))
    f_body = _carried(traj, hold_rot, f_hold, still_holds=not tremor)
    w_body = rate + _earth_rate(fit, rot)
    tau = fit.dynamics.time_offset_s
    # (a copy for scipy's apply, which refuses the read-only, shared f_body)
    f_acc = Rotation.from_rotvec(rate * tau).apply(f_body.copy()) if tau else f_body
    model = ImuErrorModel(truth, session.fs, TWIN_SEEDS + seed)
    # the same seed model after model: its draws are made once (the same samples)
    model.rng = replayed(model.rng, TWIN_SEEDS + seed)
    acc = model.accel(t, f_acc, temperature=session.temp)
    gyr = model.gyro(t, w_body, f_body, temperature=session.temp)
    if "acc" in formatted:
        origin, step = formatted["acc"]
        acc = truncated_reading(acc, step, origin)
    if "gyr" in formatted:
        origin, step = formatted["gyr"]
        gyr = truncated_reading(gyr, step, origin)
    twin = replace(session, acc=acc, gyr=gyr)
    if session.mag is not None and fit.mag is not None:
        twin.mag = replace(session.mag, values=_mag(session, traj, hold_rot, b_hold, model, noise,
                                                     still_holds=not tremor))
    return twin, truth


def truncated_reading(x: np.ndarray, step, origin=0.0) -> np.ndarray:
    """Readings as an int16 telemetry log holds them, after the reader's correction: counts
    truncated toward zero (C's float → int16 cast), then moved half a step away from zero
    (:func:`apmcal.preprocessing.resolution.undo_truncation`; a count of 0 stays 0).

    Parameters
    ----------
    x : array
        Readings [unit].
    step : float or (3,) array
        The format's step [unit] (per axis, in raw units: :attr:`~apmcal.diagnosis.session.
        log.Session.lattice`).
    origin : float or (3,) array
        The raw value of a count of 0 [unit]: the firmware truncates its corrected output,
        which the reader turns back into raw units (offsets and scales undone).

    Returns
    -------
    array
        The same shape, on the lattice the real session's readings are on.
    """
    counts = np.clip(np.trunc((x - origin) / step), -32768, 32767)
    return origin + (counts + 0.5 * np.sign(counts)) * step


def _truncated_format(session, truth) -> dict:
    """The sensors whose real readings are truncated integers ({sensor: (origin, step)}): the
    twin is formatted the same way (:func:`truncated_reading`) instead of rounded to nearest by the
    error model, whose own rounding of them is switched off here."""
    if not getattr(session, "truncated", False):
        return {}
    out = {s: session.format_of(s) for s in session.resolution if s in ("acc", "gyr")}
    q = dict(truth.quantization)
    if "acc" in out:
        q["acc_lsb_per_g"] = 0.0
    if "gyr" in out:
        q["gyro_lsb_per_dps"] = 0.0
    truth.quantization = q
    return out


# the holds' vectors carried along a motion path, recent ones; an entry keeps its path alive
# (rotations and rates: four times the carried vectors' size)
_CARRIED = reuse.Recent(8, reuse.BUDGET, lambda key, value: 5 * np.asarray(value).nbytes)


def _carried(traj, hold_rot, vectors: np.ndarray, still_holds: bool) -> np.ndarray:
    """:func:`trajectory.carried`, or its result for the same path (the very objects: one path
    per fold serves every model) and equal vectors, which most models leave as the nominal
    model has them (read-only: shared between twins)."""
    vectors = np.asarray(vectors)

    def match(key) -> bool:
        kept_traj, kept_rot, kept_vectors, kept_still = key
        return kept_traj is traj and kept_rot is hold_rot and kept_still == still_holds and \
            kept_vectors.shape == vectors.shape and np.array_equal(kept_vectors, vectors)

    known = _CARRIED.find(match)
    if known is None:
        known = trajectory.carried(traj, hold_rot, vectors, still_holds)
        known.flags.writeable = False
        _CARRIED.keep((traj, hold_rot, vectors.copy(), still_holds), known)
    return known


_IMU_INDEX = reuse.Recent(4)   # compass sample -> IMU sample, per pair of time axes


def _imu_index(t_imu: np.ndarray, t_mag: np.ndarray) -> np.ndarray:
    """The IMU sample at or after each compass sample (the last one beyond the end): found
    once for a session's two time axes (the very arrays), which every twin shares."""
    known = _IMU_INDEX.find(lambda key: key[0] is t_imu and key[1] is t_mag)
    if known is None:
        known = np.clip(np.searchsorted(t_imu, t_mag), 0, len(t_imu) - 1)
        known.flags.writeable = False
        _IMU_INDEX.keep((t_imu, t_mag), known)
    return known


def _earth_rate(fit: ModelFit, rot: np.ndarray) -> np.ndarray:
    """The fitted Earth rate in the body frame: Ω(a_north, 0, −a_up) in NED, rotated."""
    if "earth_rate" not in fit.effects:
        return np.zeros((len(rot), 3))
    coef = dict(zip(fit.gyr_vectors, fit.gyr.vector_coef))
    ned = EARTH_RATE * np.array([coef.get("earth_rate_north", 0.0), 0.0,
                                 -coef.get("earth_rate_up", 0.0)])
    return np.einsum("nji,j->ni", rot, ned)


def _mag(session, traj, hold_rot, b_hold, model, noise, still_holds: bool) -> np.ndarray:
    """Twin compass samples at the compass's own times (nearest IMU attitude)."""
    from apmcal.sensor_model.truth import FULL_THROTTLE_CURRENT_A

    m = session.mag
    b_imu = _carried(traj, hold_rot, b_hold, still_holds)
    idx = _imu_index(session.t, m.t)
    throttle = (m.current / FULL_THROTTLE_CURRENT_A if m.current is not None
                else np.zeros(len(m.t)))
    values = model.mag(np.take(b_imu, idx, axis=0), throttle)
    step = noise["mag"].step if "mag" in noise else None
    if getattr(session, "truncated", False) and "mag" in session.resolution:
        return truncated_reading(values, session.resolution["mag"])
    if step is not None:    # the log's integer mGauss (dataflash MAG, RAW_IMU): the vehicle's
        values = np.round(values / step) * step     # rounding, not the sensor's (sitl's writer)
    return values
