"""The resolution of integer telemetry, and the bias its truncation leaves.

ardupilot-facts.md "What the telemetry really carries": RAW_IMU and SCALED_IMU/2/3 carry int16
values in mG, mrad/s and mGauss, converted from float by C's truncation toward zero. A mean of
truncated samples is biased toward zero by up to one step when the noise is smaller than a step
(the gyro at rest: 1 mrad/s step, noise ~0.1 mrad/s), so the samples are moved to the middle of the
interval they stand for, and the remaining uncertainty (uniform over one step, step/√12) is added
to the calibration's sigma (:mod:`apmcal.solvers.resolution_floor`). When the noise spans several
steps the rounding is dithered away: its variance (step²/12 per sample) is already in the
residual-based sigma, and a floor would only inflate it (5-10× for a 50 Hz accelerometer), so the
floor applies only to sensors whose noise is below one step (:func:`resolution_limited`).
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from apmcal.core.constants import MG_TO_MS2, MRAD_TO_RAD

if TYPE_CHECKING:   # apmcal.core.recording loads pandas, which noise_std's users (the diagnosis) lack
    from apmcal.core.recording import Recording

INT16_TELEMETRY = {"RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"}
STEP_SI = {"acc": MG_TO_MS2, "gyr": MRAD_TO_RAD, "mag": 1.0}   # m/s², rad/s, mGauss per count
ONE_SIGMA_OF_UNIFORM_STEP = 1.0 / np.sqrt(12.0)


def telemetry_steps(recording: Recording) -> dict[str, float]:
    """Quantisation step per sensor in SI units; empty for floating-point sources.

    Returns
    -------
    dict of str to float
        Sensor → step: acc [m/s²], gyr [rad/s], mag [mGauss].
    """
    if recording.message not in INT16_TELEMETRY:
        return {}
    return {s: STEP_SI[s] for s in recording.sensors}


# a floating-point compass whose every reading is within this of a whole mGauss is quantized
WHOLE_UNIT_TOLERANCE = 1e-3


def integer_valued_steps(recording: Recording) -> dict[str, float]:
    """{"mag": 1.0} when a floating-point source's compass readings are all whole mGauss (a
    real ArduPilot SITL's are, in HIGHRES_IMU and dataflash MAG alike: its compass is
    quantized before it is sent), else {}. Rounded, not truncated: nothing to undo, but the
    step is the readings' resolution.

    Returns
    -------
    dict of str to float
        Sensor → step [mGauss].
    """
    if "mag" not in recording.sensors:
        return {}
    x = recording.xyz("mag")
    x = x[np.isfinite(x).all(axis=1)]
    if len(x) == 0 or not np.any(x):
        return {}
    whole = np.max(np.abs(x - np.round(x))) <= WHOLE_UNIT_TOLERANCE
    return {"mag": STEP_SI["mag"]} if whole else {}


def noise_std(x: np.ndarray) -> float:
    """Robust per-sample noise [units of x]: MAD of successive differences / (0.6745·√2).

    Differences cancel slow motion and the median ignores the turns between holds, so a mostly
    still recording gives its resting noise without finding the holds first.

    Parameters
    ----------
    x : numpy.ndarray, shape (n,) or (n, k)
        Samples, any unit.

    Returns
    -------
    float
        The largest of the k axes' noise σ, in the unit of ``x``.
    """
    d = np.diff(np.asarray(x, dtype=float), axis=0)
    if len(d) == 0:
        return 0.0
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return float(np.max(mad) / (0.6745 * np.sqrt(2.0)))


def resolution_limited(recording: Recording, steps: dict[str, float]) -> dict[str, float]:
    """The subset of ``steps`` whose sensor's resting noise is below one step.

    Only there does truncation leave a systematic error in a hold mean (up to half a step)
    that averaging cannot remove.

    Parameters
    ----------
    recording : Recording
    steps : dict of str to float
        From :func:`telemetry_steps` (SI units).

    Returns
    -------
    dict of str to float
    """
    return {s: step for s, step in steps.items() if noise_std(recording.xyz(s)) < step}


def undo_truncation(recording: Recording) -> Recording:
    """Samples moved half a step away from zero: the centre of what a truncated count means.

    A count of 0 stands for (−1, 1) steps and is left at 0.
    """
    from apmcal.core.recording import SENSOR_COLUMNS

    steps = telemetry_steps(recording)
    if not steps:
        return recording
    data = recording.data.copy()
    for sensor, step in steps.items():
        cols = SENSOR_COLUMNS[sensor]
        x = data[cols].to_numpy(dtype=float)
        data[cols] = x + 0.5 * step * np.sign(x)
    return replace(recording, data=data)
