"""The firmware's own correction of IMU samples, forwards (:func:`correct`) and backwards
(:func:`uncorrect`).

ardupilot-facts.md "How the firmware applies the parameters" (all vectors 3-D, ⊙ per axis,
R = rotation of AHRS_ORIENTATION, see :mod:`apmcal.ardupilot.orientation`):

* generation "3.3+" (Copter 3.3 and newer; calibration in the sensor frame, rotation last)::

      acc_body = R · ((raw − INS_ACCOFFS) ⊙ INS_ACCSCAL)        [m/s²]
      gyr_body = R · (raw − INS_GYROFFS)                         [rad/s]

* generation "3.2" (Copter 3.2.x and older, the last for APM 2.x; body frame, scale first)::

      acc_body = INS_ACCSCAL ⊙ (R · raw) − INS_ACCOFFS
      gyr_body = R · raw − INS_GYROFFS

* compass, every generation, body frame, offset ADDED, then COMPASS_SCALE (newer firmware;
  a factor only within [COMPASS_MIN_SCALE_FACTOR, COMPASS_MAX_SCALE_FACTOR], else none: s = 1)::

      mag_body = M(DIA, ODI) · s · (R_mag · raw + COMPASS_OFS)   [mGauss]

  M = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]; identity when the
  DIA/ODI parameters are absent (3.2, builds without them) or DIA is all zero (the firmware's
  ``correct_field`` then uses (1, 1, 1)). R_mag: on 3.3+ AHRS_ORIENTATION for an internal compass
  and COMPASS_ORIENT for an external one (AP_Compass_Backend ``publish_field``/``rotate_field``);
  on 3.2 COMPASS_ORIENT always, then AHRS_ORIENTATION too if internal (``_copy_to_frontend``).
  COMPASS_MOT·(throttle or current) is NOT modelled: it is zero while the motors are off
  (the firmware skips it when throttle/current is zero), which is when a calibration is recorded.

Not modelled either: the driver's fixed sensor→board rotation (done before everything, so our
"sensor frame" is the board frame), INS temperature calibration (4.1+, INS_TCALn_*), the INS
low-pass filter and RAW_IMU's int16 truncation.

Second and third instances use INS_ACC2OFFS_*/INS_ACC2SCAL_*/INS_GYR2OFFS_*/COMPASS_OFS2_*/
COMPASS_DIA2_*/COMPASS_ODI2_*/COMPASS_ORIENT2/COMPASS_EXTERN2 (3 likewise).
"""
from __future__ import annotations

import math
import re

import numpy as np

from apmcal.ardupilot.orientation import rotation_matrix
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import SENSOR_COLUMNS, Recording

GENERATIONS = ("3.2", "3.3+")
AXES = ("X", "Y", "Z")
# COMPASS_SCALE is applied only within these bounds, else not at all (ardupilot-facts.md "How
# the firmware applies the parameters": Compass::have_scale_factor; CompassCalibrator.h)
COMPASS_MIN_SCALE_FACTOR = 0.85
COMPASS_MAX_SCALE_FACTOR = 1.4


# ----------------------------------------------------------------------------- parameter names
def _suffix(instance: int) -> str:
    if instance not in (0, 1, 2):
        raise ApmcalError(f"sensor instance {instance} has no parameters (ArduPilot has 0..2)")
    return "" if instance == 0 else str(instance + 1)


def acc_param_names(instance: int = 0) -> tuple[list[str], list[str]]:
    """(offset names, scale names): INS_ACCOFFS_X.. / INS_ACC2OFFS_X.. and the SCAL twins."""
    s = _suffix(instance)
    return ([f"INS_ACC{s}OFFS_{a}" for a in AXES], [f"INS_ACC{s}SCAL_{a}" for a in AXES])


def gyr_param_names(instance: int = 0) -> list[str]:
    """INS_GYROFFS_X.. for instance 0, INS_GYR2OFFS_X.. for 1, INS_GYR3OFFS_X.. for 2."""
    s = _suffix(instance)
    return [f"INS_GYR{s}OFFS_{a}" for a in AXES]


def mag_param_names(instance: int = 0) -> dict[str, list[str] | str]:
    """Names of the compass parameters of one instance: ofs, dia, odi, mot lists; scale
    (COMPASS_SCALE, COMPASS_SCALE2, COMPASS_SCALE3), orient, external."""
    s = _suffix(instance)
    return {"ofs": [f"COMPASS_OFS{s}_{a}" for a in AXES],
            "dia": [f"COMPASS_DIA{s}_{a}" for a in AXES],
            "odi": [f"COMPASS_ODI{s}_{a}" for a in AXES],
            "mot": [f"COMPASS_MOT{s}_{a}" for a in AXES],
            "scale": f"COMPASS_SCALE{s}",
            "orient": f"COMPASS_ORIENT{s}",
            "external": "COMPASS_EXTERNAL" if instance == 0 else f"COMPASS_EXTERN{s}"}


def correction_param_names(sensor: str, instance: int = 0) -> set[str]:
    """Every parameter the firmware's correction of ``sensor`` ("acc", "gyr", "mag") of one
    instance depends on, AHRS_ORIENTATION included; for the compass also COMPASS_MOT*, which
    the firmware adds (ardupilot-facts.md "How the firmware applies the parameters")."""
    if sensor == "acc":
        offsets, scales = acc_param_names(instance)
        names = {*offsets, *scales}
    elif sensor == "gyr":
        names = set(gyr_param_names(instance))
    else:
        m, s = mag_param_names(instance), _suffix(instance)
        names = {*m["ofs"], *m["dia"], *m["odi"], m["scale"], m["orient"], m["external"],
                 "COMPASS_MOTCT",
                 *(f"COMPASS_MOT{s}_{a}" for a in AXES)}
    return names | {"AHRS_ORIENTATION"}


def _value(params: dict[str, float], name: str, path: str | None = None) -> float:
    if name not in params:
        raise ApmcalError("parameter missing: needed to undo/apply the firmware correction",
                          path, f"param {name}")
    v = float(params[name])
    if not math.isfinite(v):
        raise ApmcalError(f"parameter is {v!r}, cannot undo/apply the firmware correction",
                          path, f"param {name}")
    return v


def _vector(params: dict[str, float], names: list[str], path: str | None = None) -> np.ndarray:
    return np.array([_value(params, n, path) for n in names])


def _board_rotation(params: dict[str, float], path: str | None = None) -> np.ndarray:
    return rotation_matrix(_value(params, "AHRS_ORIENTATION", path), params, "AHRS_ORIENTATION")


def _check_generation(generation: str) -> None:
    if generation not in GENERATIONS:
        raise ApmcalError(f"unknown firmware generation {generation!r}; use '3.2' or '3.3+'")


# ----------------------------------------------------------------------------- generation
_VERSION = re.compile(r"V(\d+)\.(\d+)")


def firmware_generation(params: dict[str, float] | None, firmware_string: str | None = None) -> str:
    """Which correction formula the firmware uses: "3.2" or "3.3+".

    From the version string when there is one ("ArduCopter V3.2.1", "APM:Copter V3.3-dev",
    "ArduSub V4.1.0", ...): Copter < 3.3 → "3.2"; Plane < 3.3 → "3.2", Plane ≥ 3.4 → "3.3+";
    Rover ≥ 3, Sub, any major version ≥ 4 → "3.3+". Otherwise (no string, or Plane 3.3 /
    Rover 2.x where the release that switched is uncertain) from the parameters:

    * COMPASS_DIA_X or COMPASS_OFFS_MAX present ⇒ "3.3+" (both appeared with 3.3 or later);
    * INS_ACCOFFS_X present but no INS_ACC2OFFS_X ⇒ "3.2" (a single-IMU parameter table is the
      AVR build, i.e. APM 2.x, which ends at Copter 3.2.1);
    * otherwise the default "3.3+" (every current release). Note that Copter 3.1/3.2 on PX4
      boards do have INS_ACC2OFFS_X: pass the firmware string for those.

    Parameters
    ----------
    params : dict of str to float, or None
        The log's parameters.
    firmware_string : str, optional
        E.g. "ArduCopter V3.2.1".

    Returns
    -------
    str
        "3.2" or "3.3+".
    """
    if firmware_string:
        m = _VERSION.search(firmware_string)
        if m:
            major, minor = int(m.group(1)), int(m.group(2))
            name = firmware_string.lower()
            if major >= 4 or "sub" in name:
                return "3.3+"
            if "copter" in name:
                return "3.2" if (major, minor) < (3, 3) else "3.3+"
            if "plane" in name and (major, minor) != (3, 3):
                return "3.2" if (major, minor) < (3, 3) else "3.3+"
            if "rover" in name and major >= 3:
                return "3.3+"
    params = params or {}
    if "COMPASS_DIA_X" in params or "COMPASS_OFFS_MAX" in params:
        return "3.3+"
    if "INS_ACCOFFS_X" in params and "INS_ACC2OFFS_X" not in params:
        return "3.2"
    return "3.3+"


# ----------------------------------------------------------------------------- accelerometer
def correct_acc(raw: np.ndarray, params: dict[str, float], generation: str, instance: int = 0,
                rotate: bool = True) -> np.ndarray:
    """What the firmware outputs [m/s², body frame] for sensor-frame ``raw`` (n, 3) [m/s²].

    ``rotate=False`` leaves out AHRS_ORIENTATION (3.3+ only: its correction is in sensor frame).

    Parameters
    ----------
    raw : numpy.ndarray, shape (n, 3)
        Raw sensor-frame accelerometer samples [m/s²].
    params : dict of str to float
        The parameters in force (offsets, scales, AHRS_ORIENTATION, ...).
    generation : str
        "3.2" or "3.3+" (:func:`firmware_generation`).
    instance : int, optional
        Sensor instance 0..2 (selects the parameter names).
    rotate : bool, optional
        Include AHRS_ORIENTATION; False only for generation "3.3+".

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Corrected body-frame samples [m/s²] (sensor frame when ``rotate`` is False).

    Raises
    ------
    ApmcalError
        A parameter needed is missing or not finite; an unknown generation or rotation code.
    """
    _check_generation(generation)
    offs_names, scal_names = acc_param_names(instance)
    o, s = _vector(params, offs_names), _vector(params, scal_names)
    raw = np.asarray(raw, dtype=float)
    if generation == "3.3+":
        # ardupilot-facts.md: 3.3+ subtracts the offset, then scales, in sensor frame; rotates last.
        sensor = (raw - o) * s
        return sensor @ _board_rotation(params).T if rotate else sensor
    _no_unrotated_32(rotate)
    # ardupilot-facts.md: 3.2 rotates first, then scales, then subtracts the offset (body frame).
    return s * (raw @ _board_rotation(params).T) - o


def uncorrect_acc(acc_body: np.ndarray, params: dict[str, float], generation: str,
                  instance: int = 0, rotate: bool = True) -> np.ndarray:
    """Sensor-frame raw accelerometer samples [m/s²] that :func:`correct_acc` maps to
    ``acc_body``.

    Parameters
    ----------
    acc_body : numpy.ndarray, shape (n, 3)
        Firmware output [m/s²], body frame (sensor frame when ``rotate`` is False).
    params : dict of str to float
        The parameters in force (offsets, scales, AHRS_ORIENTATION, ...).
    generation : str
        "3.2" or "3.3+" (:func:`firmware_generation`).
    instance : int, optional
        Sensor instance 0..2 (selects the parameter names).
    rotate : bool, optional
        Include AHRS_ORIENTATION; False only for generation "3.3+".

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Raw sensor-frame samples [m/s²].

    Raises
    ------
    ApmcalError
        A parameter needed is missing or not finite, or a scale is zero; an unknown generation
        or rotation code; ``rotate=False`` with generation "3.2".
    """
    _check_generation(generation)
    offs_names, scal_names = acc_param_names(instance)
    o, s = _vector(params, offs_names), _vector(params, scal_names)
    _nonzero(s, scal_names)
    acc = np.asarray(acc_body, dtype=float)
    if generation == "3.3+":
        sensor = acc @ _board_rotation(params) if rotate else acc     # R⁻¹ = Rᵀ
        return sensor / s + o
    _no_unrotated_32(rotate)
    return ((acc + o) / s) @ _board_rotation(params)


# ----------------------------------------------------------------------------- gyroscope
def correct_gyr(raw: np.ndarray, params: dict[str, float], generation: str, instance: int = 0,
                rotate: bool = True) -> np.ndarray:
    """Firmware gyro output [rad/s, body frame] for sensor-frame ``raw`` (n, 3) [rad/s].

    Parameters
    ----------
    raw : numpy.ndarray, shape (n, 3)
        Raw sensor-frame gyro samples [rad/s].
    params : dict of str to float
        The parameters in force (offsets, scales, AHRS_ORIENTATION, ...).
    generation : str
        "3.2" or "3.3+" (:func:`firmware_generation`).
    instance : int, optional
        Sensor instance 0..2 (selects the parameter names).
    rotate : bool, optional
        Include AHRS_ORIENTATION; False only for generation "3.3+".

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Corrected body-frame samples [rad/s] (sensor frame when ``rotate`` is False).

    Raises
    ------
    ApmcalError
        A parameter needed is missing or not finite; an unknown generation or rotation code.
    """
    _check_generation(generation)
    o = _vector(params, gyr_param_names(instance))
    raw = np.asarray(raw, dtype=float)
    if generation == "3.3+":
        sensor = raw - o
        return sensor @ _board_rotation(params).T if rotate else sensor
    _no_unrotated_32(rotate)
    return raw @ _board_rotation(params).T - o


def uncorrect_gyr(gyr_body: np.ndarray, params: dict[str, float], generation: str,
                  instance: int = 0, rotate: bool = True) -> np.ndarray:
    """Sensor-frame raw gyro samples [rad/s] that :func:`correct_gyr` maps to ``gyr_body``.

    Parameters
    ----------
    gyr_body : numpy.ndarray, shape (n, 3)
        Firmware output [rad/s], body frame (sensor frame when ``rotate`` is False).
    params : dict of str to float
        The parameters in force (offsets, scales, AHRS_ORIENTATION, ...).
    generation : str
        "3.2" or "3.3+" (:func:`firmware_generation`).
    instance : int, optional
        Sensor instance 0..2 (selects the parameter names).
    rotate : bool, optional
        Include AHRS_ORIENTATION; False only for generation "3.3+".

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Raw sensor-frame samples [rad/s].

    Raises
    ------
    ApmcalError
        A parameter needed is missing or not finite; an unknown generation or rotation code.
    """
    _check_generation(generation)
    o = _vector(params, gyr_param_names(instance))
    gyr = np.asarray(gyr_body, dtype=float)
    if generation == "3.3+":
        return (gyr @ _board_rotation(params) if rotate else gyr) + o
    _no_unrotated_32(rotate)
    return (gyr + o) @ _board_rotation(params)


# ----------------------------------------------------------------------------- compass
def compass_matrix(params: dict[str, float], instance: int = 0) -> np.ndarray:
    """The soft-iron matrix M(DIA, ODI); identity when DIA/ODI are absent.

    An all-zero DIA counts as (1, 1, 1) with ODI still applied: Copter 3.3's
    ``AP_Compass_Backend::apply_corrections`` (and ``correct_field`` later) resets zero diagonals
    to 1 before building the matrix (not in ardupilot-facts.md; see sitl/firmware.py).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        Symmetric, dimensionless.
    """
    names = mag_param_names(instance)
    if not all(n in params for n in names["dia"]):
        return np.eye(3)
    dia = _vector(params, names["dia"])
    if not np.any(dia):
        dia = np.ones(3)
    odi = _vector(params, names["odi"]) if all(n in params for n in names["odi"]) else np.zeros(3)
    return np.array([[dia[0], odi[0], odi[1]],
                     [odi[0], dia[1], odi[2]],
                     [odi[1], odi[2], dia[2]]])


def compass_scale(params: dict[str, float], instance: int = 0) -> float:
    """The factor COMPASS_SCALE{,2,3} applies: its value when within
    [COMPASS_MIN_SCALE_FACTOR, COMPASS_MAX_SCALE_FACTOR], else 1 (the default 0, a value out of
    bounds, or firmware without the parameter: no scaling)."""
    name = mag_param_names(instance)["scale"]
    value = float(params.get(name, 0.0))
    if not math.isfinite(value):
        raise ApmcalError(f"parameter is {value!r}, cannot undo/apply the firmware correction",
                          where=f"param {name}")
    return value if COMPASS_MIN_SCALE_FACTOR <= value <= COMPASS_MAX_SCALE_FACTOR else 1.0


def compass_rotation(params: dict[str, float], generation: str, instance: int = 0) -> np.ndarray:
    """Sensor → body rotation the firmware applies to compass ``instance`` (see module doc).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``R`` with ``v_body = R @ v_sensor``.

    Raises
    ------
    ApmcalError
        An external compass without COMPASS_ORIENTn, no AHRS_ORIENTATION for an internal
        one, or an unknown generation or rotation.
    """
    _check_generation(generation)
    names = mag_param_names(instance)
    external = bool(params.get(names["external"], 0))
    orient = (rotation_matrix(_value(params, names["orient"]), params, names["orient"])
              if names["orient"] in params else None)
    if generation == "3.3+":
        if external:
            if orient is None:
                _value(params, names["orient"])      # raises: the parameter is needed
            return orient
        return _board_rotation(params)
    r = orient if orient is not None else np.eye(3)
    return r if external else _board_rotation(params) @ r


def correct_mag(raw: np.ndarray, params: dict[str, float], generation: str,
                instance: int = 0) -> np.ndarray:
    """Firmware compass output [mGauss, body frame] for sensor-frame ``raw`` (n, 3) [mGauss].

    Parameters
    ----------
    raw : numpy.ndarray, shape (n, 3)
        Raw sensor-frame compass samples [mGauss].
    params : dict of str to float
        The parameters in force (offsets, scales, AHRS_ORIENTATION, ...).
    generation : str
        "3.2" or "3.3+" (:func:`firmware_generation`).
    instance : int, optional
        Sensor instance 0..2 (selects the parameter names).

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Corrected body-frame samples [mGauss].

    Raises
    ------
    ApmcalError
        A parameter needed is missing or not finite; an unknown generation or rotation code.
    """
    ofs = _vector(params, mag_param_names(instance)["ofs"])
    r = compass_rotation(params, generation, instance)
    m = compass_matrix(params, instance) * compass_scale(params, instance)
    # ardupilot-facts.md: mag = M(DIA,ODI)·SCALE·(raw + COMPASS_OFS), offset ADDED, body frame.
    return (np.asarray(raw, dtype=float) @ r.T + ofs) @ m.T


def uncorrect_mag(mag_body: np.ndarray, params: dict[str, float], generation: str,
                  instance: int = 0) -> np.ndarray:
    """Sensor-frame raw compass samples [mGauss] that :func:`correct_mag` maps to ``mag_body``.

    Parameters
    ----------
    mag_body : numpy.ndarray, shape (n, 3)
        Firmware output [mGauss], body frame.
    params : dict of str to float
        The parameters in force (offsets, scales, AHRS_ORIENTATION, ...).
    generation : str
        "3.2" or "3.3+" (:func:`firmware_generation`).
    instance : int, optional
        Sensor instance 0..2 (selects the parameter names).

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Raw sensor-frame samples [mGauss].

    Raises
    ------
    ApmcalError
        A parameter needed is missing or not finite, or the soft-iron matrix is singular; an
        unknown generation or rotation code.
    """
    ofs = _vector(params, mag_param_names(instance)["ofs"])
    r = compass_rotation(params, generation, instance)
    m = compass_matrix(params, instance) * compass_scale(params, instance)   # SCALE undone too
    if abs(np.linalg.det(m)) < 1e-9:
        raise ApmcalError("compass matrix from COMPASS_DIA/ODI is singular, cannot undo it",
                          where=f"param {mag_param_names(instance)['dia'][0]}")
    # one 3×3 inverse applied to every row: a solve with n right-hand sides copies them to
    # Fortran order first, ~50× slower on a 250 000-sample compass
    body_raw = np.asarray(mag_body, dtype=float) @ np.linalg.inv(m).T - ofs
    return body_raw @ r


# ----------------------------------------------------------------------------- recordings
_FORWARD = {"acc": correct_acc, "gyr": correct_gyr}
_BACKWARD = {"acc": uncorrect_acc, "gyr": uncorrect_gyr}


def uncorrect(recording: Recording, params: dict[str, float] | None = None,
              generation: str | None = None) -> Recording:
    """The recording as the sensors produced it: corrected=False, frame="sensor".

    Undoes the firmware's offsets/scales (when ``recording.corrected``) and the board rotation
    (when ``recording.frame == "body"``), using ``params`` (default ``recording.params``) and
    ``generation`` (default :func:`firmware_generation` of those params and
    ``recording.firmware``). Columns other than acc/gyr/mag are kept unchanged.

    Raises
    ------
    ApmcalError
        Naming the parameter when one needed is missing or NaN.
    """
    params = recording.params if params is None else params
    if not recording.corrected and recording.frame == "sensor":
        return _copy(recording, recording.data.copy(), corrected=False, frame="sensor")
    generation = generation or firmware_generation(params, recording.firmware)
    _check_generation(generation)
    rotate = recording.frame == "body"
    data = recording.data.copy()
    try:
        for sensor in recording.sensors:
            cols = SENSOR_COLUMNS[sensor]
            x = data[cols].to_numpy(dtype=float)
            if not recording.corrected:          # only rotated (neutral parameters)
                r = (compass_rotation(params, generation, recording.instance) if sensor == "mag"
                     else _board_rotation(params))
                data[cols] = x @ r
            elif sensor == "mag":
                if not rotate:
                    raise ApmcalError("a corrected compass is always in body frame")
                data[cols] = uncorrect_mag(x, params, generation, recording.instance)
            else:
                data[cols] = _BACKWARD[sensor](x, params, generation, recording.instance, rotate)
    except ApmcalError as err:
        raise ApmcalError(err.why, recording.source, err.where) from None
    return _copy(recording, data, corrected=False, frame="sensor")


def correct(recording: Recording, params: dict[str, float], generation: str) -> Recording:
    """What the firmware would output for raw sensor-frame ``recording``: corrected, body frame.

    Parameters
    ----------
    recording : Recording
        Raw samples (corrected=False, frame="sensor").
    params : dict of str to float
        The parameters to apply.
    generation : str
        "3.2" or "3.3+".

    Returns
    -------
    Recording
        corrected=True, frame="body", ``params`` attached.

    Raises
    ------
    ApmcalError
        A recording that is not raw, or a parameter needed is missing or not finite.
    """
    if recording.corrected or recording.frame != "sensor":
        raise ApmcalError("correct() needs raw sensor-frame samples (use uncorrect() first)",
                          recording.source)
    _check_generation(generation)
    data = recording.data.copy()
    try:
        for sensor in recording.sensors:
            cols = SENSOR_COLUMNS[sensor]
            x = data[cols].to_numpy(dtype=float)
            if sensor == "mag":
                data[cols] = correct_mag(x, params, generation, recording.instance)
            else:
                data[cols] = _FORWARD[sensor](x, params, generation, recording.instance)
    except ApmcalError as err:
        raise ApmcalError(err.why, recording.source, err.where) from None
    out = _copy(recording, data, corrected=True, frame="body")
    out.params = dict(params)
    return out


def _copy(rec: Recording, data, corrected: bool, frame: str) -> Recording:
    return Recording(data=data, source=rec.source, message=rec.message, instance=rec.instance,
                     vehicle=rec.vehicle, firmware=rec.firmware, params=dict(rec.params),
                     corrected=corrected, frame=frame)


def _nonzero(values: np.ndarray, names: list[str]) -> None:
    for v, n in zip(values, names):
        if v == 0:
            raise ApmcalError("scale is 0, the correction cannot be undone", where=f"param {n}")


def _no_unrotated_32(rotate: bool) -> None:
    if not rotate:
        raise ApmcalError("firmware 3.2 corrects in body frame: a corrected sensor-frame "
                          "recording cannot come from it")
