"""The resolution floor of a calibration from integer telemetry: what a mean of samples
truncated to whole steps cannot know, added to the result's sigma.

The samples were moved to the middle of the step they stand for
(:func:`apmcal.preprocessing.resolution.undo_truncation`); the true value is anywhere in that
step, uniformly, so each mean keeps an uncertainty of step/√12. Applied only to sensors whose
noise is below one step (:func:`apmcal.preprocessing.resolution.resolution_limited`): above it
the rounding is dithered away and its variance is already in the residual-based sigma.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from apmcal.preprocessing.resolution import ONE_SIGMA_OF_UNIFORM_STEP
from apmcal.solvers.result import SensorCalibration


def with_resolution_floor(sensors: dict[str, SensorCalibration], steps: dict[str, float],
                          field: dict[str, float]) -> dict[str, SensorCalibration]:
    """The sensors with offset (and accelerometer/magnetometer matrix) sigmas widened by the
    step's own spread.

    ``field`` gives the magnitude the matrix was fitted to (|g| m/s², |B| mGauss): a step error in
    a mean is a relative error step/|field| in the matrix terms it feeds. Only sigmas the method
    gave are widened: an estimate without one (undetermined) stays without.

    Parameters
    ----------
    sensors : dict
        sensor → SensorCalibration; not changed.
    steps : dict
        sensor → resolution step of its samples [sensor units: m/s², rad/s, mGauss].
    field : dict
        sensor → field magnitude the matrix was fitted to [sensor units].

    Returns
    -------
    dict
        sensor → SensorCalibration: a widened copy for each sensor of ``steps``, the others as
        they were.
    """
    out = dict(sensors)
    for sensor, step in steps.items():
        cal = sensors.get(sensor)
        if cal is None:
            continue
        floor = step * ONE_SIGMA_OF_UNIFORM_STEP
        sigma = dict(cal.sigma)
        if "offset" in sigma:
            sigma["offset"] = np.hypot(sigma["offset"], floor)
        if "matrix" in sigma and field.get(sensor, 0) > 0:
            sigma["matrix"] = np.hypot(sigma["matrix"], floor / field[sensor])
        out[sensor] = replace(cal, sigma=sigma)
    return out
