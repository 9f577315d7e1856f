"""Slow regressors of the deterministic effects, at samples or at block means.

Each effect that adds a slowly varying term to a sensor contributes columns ``X`` with one
coefficient per sensor axis (``X·θ``, θ of shape (k, 3)):

=================== ======== ==================================== ============================
effect              sensors  column                               coefficient unit
=================== ======== ==================================== ============================
temperature_drift   acc, gyr T − T_ref [K]                        sensor unit per K
bias_drift          gyr      t − t_ref [s] ([Oppong] eq. 5)       rad/s per s
mag_interference    mag      I − I_ref [A] (battery current)      mGauss per A
=================== ======== ==================================== ============================

Like sitl (``gyro_bias_drift``) and the Ferraris model, the linear bias drift is the gyro's.
ArduPilot SITL's triangle drift is one value on all three axes, so it is a whole-vector
regressor of the gyro fit (:func:`triangle`, one coefficient), not a column here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COLUMN_EFFECTS = {"acc": ("temperature_drift",),
                  "gyr": ("temperature_drift", "bias_drift"),
                  "mag": ("mag_interference",)}


@dataclass(frozen=True)
class References:
    """Where the slow terms are zero: the session's mean time, temperature and current.

    Attributes
    ----------
    t_s : float
        Reference time [s].
    temp_c : float
        Reference temperature [°C].
    current_a : float
        Reference battery current [A].
    drift_time_min : float
        SIM_DRIFT_TIME of the triangle drift [min] (fitted).
    """

    t_s: float
    temp_c: float = 0.0
    current_a: float = 0.0
    drift_time_min: float = 5.0     # SIM_DRIFT_TIME of the triangle drift (fitted)


def triangle(t_s: np.ndarray, drift_time_min: float) -> np.ndarray:
    """ArduPilot SITL's gyro drift shape [min] at times since boot ``t_s``.

    libraries/AP_InertialSensor/AP_InertialSensor_SITL.cpp ``gyro_drift``: with period
    P = 2·SIM_DRIFT_TIME [min] and m = fmod(t / 60, P), the shape is m for m < P/2, else P − m;
    the drift [rad/s] is radians(SIM_DRIFT_SPEED) × shape on every axis.

    Parameters
    ----------
    t_s : (n,) array
        Times since boot [s].
    drift_time_min : float
        SIM_DRIFT_TIME [min].

    Returns
    -------
    (n,) array
        Shape [min].
    """
    period = 2.0 * drift_time_min
    m = np.fmod(np.asarray(t_s, float) / 60.0, period)
    return np.where(m < period / 2, m, period - m)


def columns(effects, sensor: str, refs: References, t, temp=None, current=None
            ) -> tuple[np.ndarray, list[str]]:
    """Regressor columns (n, k) of ``sensor`` for the active ``effects`` and their effect names.

    Effects whose covariate is missing (no temperature, no current) add no column.

    Parameters
    ----------
    effects : collection of str
    sensor : str
        "acc", "gyr" or "mag".
    refs : References
    t : (n,) array
        Times [s].
    temp : (n,) array, optional
        Temperatures [°C].
    current : (n,) array, optional
        Battery currents [A].

    Returns
    -------
    columns : (n, k) array
        T − T_ref [K], t − t_ref [s], I − I_ref [A], as the effects call for.
    names : list of str
        The effect of each column.
    """
    cols, names = [], []
    wanted = [e for e in COLUMN_EFFECTS[sensor] if e in effects]
    for effect in wanted:
        if effect == "temperature_drift" and temp is not None:
            cols.append(np.asarray(temp, float) - refs.temp_c)
        elif effect == "bias_drift":
            cols.append(np.asarray(t, float) - refs.t_s)
        elif effect == "mag_interference" and current is not None:
            cols.append(np.asarray(current, float) - refs.current_a)
        else:
            continue
        names.append(effect)
    n = len(np.atleast_1d(t))
    return (np.column_stack(cols) if cols else np.zeros((n, 0))), names
