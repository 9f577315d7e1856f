"""ArduPilot's IMU temperature calibration parameters (INS_TCALn_*) and the correction they make.

ArduPilot 4.1+ libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp
(``polynomial_eval``, ``correct_sensor``, ``Learn::save_calibration``; parameter table
``AP_InertialSensor::TCal::var_info``), AP_InertialSensor.cpp (groups ``_TCAL1_`` .. ``_TCAL3_``,
``_ACC1_CALTEMP`` .. ``_GYR3_CALTEMP``) and AP_InertialSensor_Backend.cpp
(``_rotate_and_correct_accel`` / ``_gyro``); see docs/tcal.md for what is relied on:

* per IMU n = 1..3: INS_TCALn_ENABLE (0 off, 1 on, 2 learn), INS_TCALn_TMIN, INS_TCALn_TMAX
  [°C], INS_TCALn_ACC{1,2,3}_{X,Y,Z} and INS_TCALn_GYR{1,2,3}_{X,Y,Z}: the 1st, 2nd and 3rd
  order coefficients, stored ×1e6 (SCALE_FACTOR) of m/s²/K^k (accelerometer) and rad/s/K^k
  (gyro); the calibration temperature of the offsets INS_ACCn_CALTEMP / INS_GYRn_CALTEMP [°C]
  (default −300, i.e. clamped to TMIN);
* with d = T − 35 °C (TEMP_REFERENCE), P(d) = (c1 + (c2 + c3·d)·d)·d·1e-6 per axis;
* when ENABLE = 1 the firmware corrects, in the SENSOR frame, before the offsets and scales and
  before AHRS_ORIENTATION: v −= P(clamp(T) − 35) − P(clamp(T_cal) − 35), clamp to [TMIN, TMAX].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from apmcal.core.errors import ApmcalError

TEMP_REFERENCE_C = 35.0       # AP_InertialSensor_tempcal.cpp TEMP_REFERENCE
SCALE_FACTOR = 1.0e6          # ... SCALE_FACTOR: parameters hold the coefficients × 1e6
TEMP_RANGE_MIN_C = 10.0       # ... TEMP_RANGE_MIN: the learner's smallest temperature range
TEMP_PARAM_RANGE_C = (-70.0, 80.0)   # INS_TCALn_TMIN / TMAX @Range
CALTEMP_DEFAULT_C = -300.0    # INS_ACCn_CALTEMP / INS_GYRn_CALTEMP default (AP_InertialSensor.cpp)
KINDS = {"acc": "ACC", "gyr": "GYR"}
AXES = ("X", "Y", "Z")


def tcal_names(instance: int, sensor: str) -> list[list[str]]:
    """[[c1_X, c1_Y, c1_Z], [c2_...], [c3_...]] parameter names of IMU ``instance`` (0-based),
    ``sensor`` "acc" or "gyr"."""
    n = _number(instance)
    return [[f"INS_TCAL{n}_{KINDS[sensor]}{k}_{a}" for a in AXES] for k in (1, 2, 3)]


def caltemp_name(instance: int, sensor: str) -> str:
    """INS_ACCn_CALTEMP / INS_GYRn_CALTEMP of IMU ``instance`` (0-based)."""
    return f"INS_{KINDS[sensor]}{_number(instance)}_CALTEMP"


def _number(instance: int) -> int:
    if instance not in (0, 1, 2):
        raise ApmcalError(f"IMU instance {instance} has no INS_TCAL parameters (ArduPilot has "
                          f"INS_TCAL1..3)")
    return instance + 1


@dataclass
class TcalSet:
    """One IMU's temperature calibration as the firmware holds it.

    Attributes
    ----------
    enable : int
        INS_TCALn_ENABLE (0 off, 1 applied, 2 learning).
    tmin_c, tmax_c : float
        INS_TCALn_TMIN / TMAX [°C].
    coeffs : dict
        "acc" / "gyr" → (3, 3) array, row k−1 = c_k for X, Y, Z, in parameter units (×1e6 of
        m/s²/K^k or rad/s/K^k).
    caltemp_c : dict
        "acc" / "gyr" → INS_ACCn_CALTEMP / INS_GYRn_CALTEMP [°C].
    """

    enable: int
    tmin_c: float
    tmax_c: float
    coeffs: dict
    caltemp_c: dict

    def correction(self, sensor: str, temp_c: np.ndarray) -> np.ndarray:
        """What the firmware subtracts [m/s² or rad/s] (n, 3) at temperatures ``temp_c`` (n,)
        [°C]: P(clamp(T) − 35) − P(clamp(T_cal) − 35) when enabled (=1), else zeros.

        AP_InertialSensor_tempcal.cpp ``correct_sensor``: both temperatures clamped
        to [TMIN, TMAX], the polynomial evaluated at their difference from TEMP_REFERENCE.

        Parameters
        ----------
        sensor : str
            "acc" or "gyr".
        temp_c : numpy.ndarray, shape (n,)
            IMU temperature [°C].

        Returns
        -------
        numpy.ndarray, shape (n, 3)
            [m/s²] for "acc", [rad/s] for "gyr".
        """
        temp_c = np.asarray(temp_c, dtype=float)
        if self.enable != 1:
            return np.zeros((temp_c.shape[0], 3))
        c = self.coeffs[sensor]
        at_t = polynomial(c, np.clip(temp_c, self.tmin_c, self.tmax_c) - TEMP_REFERENCE_C)
        at_cal = polynomial(c, np.clip([self.caltemp_c[sensor]], self.tmin_c, self.tmax_c)
                            - TEMP_REFERENCE_C)
        return at_t - at_cal


def polynomial(coeffs: np.ndarray, d_k: np.ndarray) -> np.ndarray:
    """ArduPilot's P(d) = (c1 + (c2 + c3·d)·d)·d·1e-6 (``polynomial_eval``), per axis.

    Parameters
    ----------
    coeffs : (3, 3) array
        Row k−1 = c_k (X, Y, Z) in parameter units.
    d_k : (n,) array
        Temperature minus 35 °C [K].

    Returns
    -------
    (n, 3) array
        In the sensor's unit (m/s² or rad/s).
    """
    c = np.asarray(coeffs, dtype=float)
    d = np.asarray(d_k, dtype=float)[:, None]
    return (c[0] + (c[1] + c[2] * d) * d) * d / SCALE_FACTOR


def tcal_from_params(params: dict[str, float], instance: int) -> TcalSet | None:
    """The set in force for IMU ``instance`` per ``params`` (a log's PARM / PARAM_VALUE), or
    None when the firmware has no INS_TCALn_ENABLE (older than 4.1, or built without it).

    Raises ApmcalError naming the parameter when ENABLE = 1 but a value it needs is missing or
    not finite.

    Parameters
    ----------
    params : dict of str to float
    instance : int
        IMU instance, 0-based.

    Returns
    -------
    TcalSet or None
    """
    n = _number(instance)
    enable_name = f"INS_TCAL{n}_ENABLE"
    if enable_name not in params:
        return None
    enable = int(round(float(params[enable_name])))
    if enable != 1:
        return TcalSet(enable, 0.0, 70.0, {s: np.zeros((3, 3)) for s in KINDS},
                       {s: CALTEMP_DEFAULT_C for s in KINDS})

    def value(name, default=None):
        v = params.get(name, default)
        if v is None or not math.isfinite(float(v)):
            raise ApmcalError(f"needed to undo the temperature calibration in force "
                              f"({enable_name} = 1) but {'missing' if v is None else v}",
                              where=f"param {name}")
        return float(v)

    coeffs = {s: np.array([[value(nm) for nm in row] for row in tcal_names(instance, s)])
              for s in KINDS}
    caltemp = {s: value(caltemp_name(instance, s), CALTEMP_DEFAULT_C) for s in KINDS}
    return TcalSet(1, value(f"INS_TCAL{n}_TMIN"), value(f"INS_TCAL{n}_TMAX"), coeffs, caltemp)


def tcal_param_values(instance: int, coeffs: dict, tmin_c: float, tmax_c: float
                      ) -> dict[str, float]:
    """INS_TCALn_ENABLE = 1, TMIN, TMAX and the 18 coefficients of a fit, as parameter values.

    Parameters
    ----------
    instance : int
        IMU instance, 0-based (INS_TCAL1 for 0).
    coeffs : dict
        "acc" / "gyr" → (3, 3) array, row k−1 = c_k (X, Y, Z) in parameter units (×1e6).
    tmin_c, tmax_c : float
        Temperature range of the data [°C]; refused outside the parameters' range −70..80 °C.

    Returns
    -------
    dict of str to float
        Parameter name → value (coefficients ×1e6, temperatures [°C]).

    Raises
    ------
    ApmcalError
        An instance other than 0..2, or TMIN/TMAX outside −70..80 °C.
    """
    n = _number(instance)
    lo, hi = TEMP_PARAM_RANGE_C
    for name, t in ((f"INS_TCAL{n}_TMIN", tmin_c), (f"INS_TCAL{n}_TMAX", tmax_c)):
        if not lo <= t <= hi:
            raise ApmcalError(f"{t:.1f} °C is outside the parameter's range {lo:g}..{hi:g} °C",
                              where=f"param {name}")
    values = {f"INS_TCAL{n}_ENABLE": 1.0, f"INS_TCAL{n}_TMIN": float(tmin_c),
              f"INS_TCAL{n}_TMAX": float(tmax_c)}
    for sensor in KINDS:
        for row_names, row in zip(tcal_names(instance, sensor), np.asarray(coeffs[sensor])):
            values.update({nm: float(v) for nm, v in zip(row_names, row)})
    return values
