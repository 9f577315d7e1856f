"""Clean calibration sessions made apart from the simulator: exact continuous-time motion and
this module's own error and noise code (nothing of apmcal_sim or apmcal.sensor_model).

A session: the board still on each of its six faces, then three full turns in 90° steps, one
about each body axis, every change of pose a real turn the gyro sees; each still pose lasts
5-9 s and each turn 1.5-3 s (drawn per session). The motion is known in closed form: a turn
rotates the board about one body-fixed axis u by θ(t) with the minimum-jerk profile
θ(t) = Θ (10 s³ − 15 s⁴ + 6 s⁵), s = (t − t₀)/T, so the body rate is exactly θ'(t) u and the
attitude exactly R(t₀)·exp(θ(t) [u]×) at every sample time — no integration.

The sensors are apmcal's nominal model and nothing else: the accelerometer's per-axis scale
and offset, the gyro's offset, white Gaussian noise on both; accelerometer f_b = R_nbᵀ (0, 0,
−g) (NED frame), gyro ω_b (no Earth rate, no temperature, no compass). The gyro's scale is 1:
its scale factors are a candidate effect (``gyro_scale``), not part of the nominal model.
Written as apmcal's CSV layout [s, m/s², rad/s].
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

G = 9.80665             # [m/s²]
DOWN_NED = np.array([0.0, 0.0, -G])     # what a still accelerometer reads, level [m/s²]


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """exp(angle [axis]×) by Rodrigues' formula (``axis`` a unit vector)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def _turns() -> list[tuple[np.ndarray, float]]:
    """(body axis, angle [rad]) of each turn: through the six faces (z, y, then x vertical),
    then 4 × 90° about x, y and z."""
    x, _, z = np.eye(3)
    half = np.pi / 2
    faces = [(x, np.pi), (x, half), (x, np.pi), (z, half), (z, np.pi)]
    full = [(axis, half) for axis in np.eye(3) for _ in range(4)]
    return faces + full


def motion(fs: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample times [s], specific force [m/s²] and angular rate [rad/s] in the body frame.

    Parameters
    ----------
    fs : float
        Sample rate [Hz].
    rng : numpy.random.Generator
        Draws the holds' and turns' durations.

    Returns
    -------
    t : (n,) array
    f_body : (n, 3) array
    w_body : (n, 3) array
    """
    turns = _turns()
    holds = rng.uniform(5.0, 9.0, len(turns) + 1)
    spans = rng.uniform(1.5, 3.0, len(turns))
    t = np.arange(int((holds.sum() + spans.sum()) * fs)) / fs
    f_body, w_body = np.zeros((len(t), 3)), np.zeros((len(t), 3))
    attitude = np.eye(3)            # R_nb of the current pose (level: body z down)
    t0 = holds[0]
    f_body[t < t0] = attitude.T @ DOWN_NED
    for (axis, angle), span, hold in zip(turns, spans, holds[1:]):
        posed = (t >= t0) & (t < t0 + span + hold)      # this turn and the hold after it
        s = np.clip((t[posed] - t0) / span, 0.0, 1.0)
        theta = angle * (10 * s**3 - 15 * s**4 + 6 * s**5)
        rate = angle * (30 * s**2 - 60 * s**3 + 30 * s**4) / span    # dθ/dt, 0 once s = 1
        f_body[posed] = [(attitude @ _rotation(axis, a)).T @ DOWN_NED for a in theta]
        w_body[posed] = rate[:, None] * axis
        attitude = attitude @ _rotation(axis, angle)
        t0 += span + hold
    return t, f_body, w_body


def session(seed: int, fs: float = 200.0, gyro_scale=None) -> np.ndarray:
    """One clean session as rows ``t, acc_x..z, gyr_x..z`` [s, m/s², rad/s].

    The board's errors are drawn from ``seed``: accelerometer offsets ±0.5 m/s², scales
    1 ± 3 %; gyro offsets ±0.05 rad/s; white noise per sample σ 0.003-0.03 m/s² and
    0.0003-0.003 rad/s (log-uniform: quiet and noisy boards). ``gyro_scale`` (3,), when
    given, multiplies the gyro's readings axis by axis: an effect beyond the nominal model,
    for a check that the diagnosis still finds one.
    """
    rng = np.random.default_rng([0x1DE, seed])
    t, f_body, w_body = motion(fs, rng)
    acc_scale = 1.0 + rng.uniform(-0.03, 0.03, 3)
    acc_offset, gyr_offset = rng.uniform(-0.5, 0.5, 3), rng.uniform(-0.05, 0.05, 3)
    acc_sigma, gyr_sigma = 10.0 ** rng.uniform(-1.0, 0.0, 2) * np.array([0.03, 0.003])
    acc = f_body * acc_scale + acc_offset + rng.normal(0.0, acc_sigma, f_body.shape)
    gyr = w_body * (1.0 if gyro_scale is None else np.asarray(gyro_scale)) + gyr_offset \
        + rng.normal(0.0, gyr_sigma, w_body.shape)
    return np.column_stack([t, acc, gyr])


def write_csv(path: Path, seed: int, fs: float = 200.0, gyro_scale=None) -> Path:
    """:func:`session` written as apmcal's CSV layout; returns ``path``."""
    np.savetxt(path, session(seed, fs, gyro_scale), delimiter=",", fmt="%.9g",
               header="t,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z", comments="")
    return path
