"""A calibration turned into the ArduPilot parameters that make the firmware apply it.

Input: :class:`apmcal.solvers.result.Calibration` of raw SENSOR-frame samples,
``calibrated = A @ (raw − o)`` with acc [m/s²], gyr [rad/s], mag [mGauss]. The firmware formulas
it must reproduce are those of :mod:`apmcal.ardupilot.firmware` (ardupilot-facts.md "How the
firmware applies the parameters"); the firmware output is in body frame, so the target is
``R @ A @ (raw − o)`` with R the board rotation. Writing ``B = R A Rᵀ`` and ``o_b = R o`` (the
same calibration seen in body frame), ``R A (raw − o) = B (R raw − o_b)``.

* 3.3+ accelerometer (sensor frame, offset then scale): INS_ACCOFFS = o, INS_ACCSCAL = diag(A).
* 3.2 accelerometer (body frame, scale then offset): ``SCAL ⊙ (R raw) − OFFS`` must equal
  ``diag(B) ⊙ (R raw − o_b)``, so INS_ACCSCAL = diag(B) and INS_ACCOFFS = diag(B) ⊙ o_b.
  For 90°-step rotations diag(B) is diag(A) permuted; for 45° ones the off-diagonal part of B
  is dropped too (its cost is reported).
* Gyro: INS_GYROFFS = o (3.3+) or o_b (3.2). No gyro scale parameter exists.
* Compass (body frame on every version, offset ADDED):
  ``M (R_m raw + OFS) = B_m (R_m raw − R_m o)`` gives COMPASS_OFS = −R_m o and M = B_m. M must
  be symmetric, so the symmetric positive factor P of the polar decomposition B_m = U P is used
  (|P x| = |B_m x|: field magnitudes are kept exactly; the dropped U is a pure rotation, reported
  in degrees). 3.2 has no DIA/ODI: only OFS.
  Newer firmware multiplies by COMPASS_SCALE between the two: ``M·SCALE·(R_m raw + OFS)``.
  OFS does not depend on it; with DIA/ODI proposed, a SCALE in force is set to 0 (none) so that
  M = B_m holds the whole gain; with offsets only, it is kept.

Per-axis parameters cannot hold cross-axis terms; :func:`cost_of_diagonal_only` gives the
worst-case error that costs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from apmcal.ardupilot.firmware import (
    GENERATIONS,
    acc_param_names,
    compass_rotation,
    compass_scale,
    gyr_param_names,
    mag_param_names,
)
from apmcal.ardupilot.orientation import rotation_matrix
from apmcal.core.constants import STANDARD_GRAVITY
from apmcal.core.errors import ApmcalError

# Firmware limits (ardupilot-facts.md "How the firmware applies the parameters" and
# "ArduPilot's own calibrators").
ACC_OFFSET_MAX = 3.5            # m/s², INS_ACCOFFS range
ACC_SCALE_RANGE = (0.8, 1.2)    # INS_ACCSCAL range
ACC_SCALE_MAX_DEV_32 = 0.1      # 3.2's own 6-face fit rejected |scale − 1| > 0.1
COMPASS_OFS_MAX_32 = 400.0      # mGauss, 3.2
# Copter config.h before COMPASS_OFFS_MAX existed (3.2 included): "max compass offset length",
# the pre-arm check's limit on |COMPASS_OFS| [mGauss]
COMPASS_OFFSETS_LENGTH_MAX_OLD = 600.0
DIA_RANGE = (0.2, 5.0)
ODI_MAX = 1.0                   # |ODI| must stay below 1
TYPICAL_FIELD_MGAUSS = 500.0    # for the compass cost figures when no field strength is given


@dataclass
class ParamProposal:
    """Parameters proposed for one calibration.

    Attributes
    ----------
    values : dict of str to float
        name -> value (float32-representable) the firmware would accept
    rejected : dict of str to str
        name -> reason, for values out of the firmware's limits (whole sensor withheld)
    notes : list of str
        human-readable remarks (what could not be represented, and what that costs)
    generation : str
        "3.2" or "3.3+"
    costs : dict of str to float
        name -> worst-case error of the per-axis representation (m/s², rad/s, mGauss, deg)
    """

    values: dict[str, float] = field(default_factory=dict)
    rejected: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    generation: str = "3.3+"
    costs: dict[str, float] = field(default_factory=dict)

    def write(self, path, header_comment: str = "", fmt: str = "param",
              values: dict[str, float] | None = None) -> None:
        """The proposed values (or ``values``, those of them that may be written:
        :class:`apmcal.ardupilot.limits.Writable`) as a .param file, or QGroundControl's
        .params with ``fmt="qgc"`` (:func:`apmcal.ardupilot.paramfile.write_param_file`),
        recording the generation they were made for.

        Raises
        ------
        ApmcalError
            When the file cannot be written.
        """
        from apmcal.ardupilot.paramfile import write_param_file

        try:
            write_param_file(path, self.values if values is None else values, header_comment,
                             fmt=fmt, generation=self.generation)
        except OSError as exc:     # write_param_file wraps its own; this is belt and braces
            raise ApmcalError(f"cannot write parameter file ({exc.strerror or exc})",
                              str(path)) from None

    def uploadable(self, where: str) -> dict[str, float]:
        """The proposed values that passed the firmware's limits, to upload.

        A sensor out of limits is withheld whole (:attr:`rejected`); the others are uploaded all
        the same, since a rejected compass (say) says nothing against the accelerometer and gyro
        values.

        Parameters
        ----------
        where : str
            The vehicle's connection, for the message.

        Raises
        ------
        ApmcalError
            When no value is within the firmware's limits.
        """
        if not self.values:
            why = ", ".join(self.rejected) if self.rejected else "none proposed"
            raise ApmcalError(f"not uploading: no parameter within the firmware's limits ({why})",
                              where)
        return dict(self.values)


def cost_of_approximation(matrix: np.ndarray, used: np.ndarray, magnitude: float) -> float:
    """Worst-case error over all directions when ``used`` replaces the true ``matrix``.

    A true quantity v (|v| = ``magnitude``) is seen, offset removed, as x = A⁻¹ v; the
    approximation outputs ``used`` @ x, so the error is (used A⁻¹ − I) v, whose maximum over
    the sphere is ``magnitude`` times the largest singular value of (used A⁻¹ − I).

    Parameters
    ----------
    matrix : numpy.ndarray, shape (3, 3)
        The true calibration matrix A (invertible, dimensionless).
    used : numpy.ndarray, shape (3, 3)
        What replaces it.
    magnitude : float
        |v|, in the quantity's unit (m/s², rad/s, mGauss).

    Returns
    -------
    float
        Worst-case error, in the unit of ``magnitude``.
    """
    a = np.asarray(matrix, dtype=float)
    e = np.asarray(used, dtype=float) @ np.linalg.inv(a) - np.eye(3)
    return float(magnitude * np.linalg.norm(e, 2))


def cost_of_diagonal_only(matrix: np.ndarray, magnitude: float) -> float:
    """Worst-case error [units of ``magnitude``] of keeping only diag(``matrix``).

    E.g. ``cost_of_diagonal_only(A, 9.80665)`` is the largest accelerometer error [m/s²] over
    every gravity direction between the full-matrix and the per-axis calibration.

    Parameters
    ----------
    matrix : numpy.ndarray, shape (3, 3)
    magnitude : float

    Returns
    -------
    float
    """
    a = np.asarray(matrix, dtype=float)
    return cost_of_approximation(a, np.diag(np.diag(a)), magnitude)


def to_ardupilot_params(calibration, generation: str, instance: int = 0,
                        current_params: dict[str, float] | None = None, *,
                        field_mgauss: float = TYPICAL_FIELD_MGAUSS) -> ParamProposal:
    """ArduPilot parameters that make the firmware apply ``calibration`` (see module doc).

    Parameters
    ----------
    calibration : apmcal.solvers.result.Calibration
        Sensors "acc" [m/s²], "gyr" [rad/s], "mag" [mGauss], sensor frame, raw-sample corrections.
    generation : str
        "3.2" or "3.3+"
    instance : int
        IMU / compass instance (0..2; 3.2 has only 0)
    current_params : dict of str to float, optional
        The vehicle's parameters (AHRS_ORIENTATION, COMPASS_ORIENT/EXTERNAL,
        COMPASS_OFFS_MAX; also used to refuse names the vehicle does not have)
    field_mgauss : float
        Field strength used for the compass cost figures [mGauss]

    Returns
    -------
    ParamProposal

    Raises
    ------
    ApmcalError
        An unknown generation, an instance other than 0 on 3.2, or an unknown or incomplete
        board/compass rotation.
    """
    if generation not in GENERATIONS:
        raise ApmcalError(f"unknown firmware generation {generation!r}; use '3.2' or '3.3+'")
    if generation == "3.2" and instance != 0:
        raise ApmcalError(f"firmware 3.2 has a single IMU and compass; no instance {instance}")
    params = dict(current_params or {})
    prop = ParamProposal(generation=generation)
    if "AHRS_ORIENTATION" not in params:
        params["AHRS_ORIENTATION"] = 0.0
        prop.notes.append("AHRS_ORIENTATION unknown: assumed 0 (no board rotation)")
    r = rotation_matrix(params["AHRS_ORIENTATION"], params, "AHRS_ORIENTATION")
    sensors = calibration.sensors
    if "acc" in sensors:
        _accelerometer(sensors["acc"], r, generation, instance, prop)
    if "gyr" in sensors:
        _gyroscope(sensors["gyr"], r, generation, instance, prop, params)
    if "mag" in sensors:
        _compass(sensors["mag"], params, generation, instance, prop, field_mgauss,
                 known=any(k.startswith("COMPASS_") for k in (current_params or {})))
    _check_known(prop, current_params)
    return prop


# ----------------------------------------------------------------------------- per sensor
def _accelerometer(cal, r, generation, instance, prop: ParamProposal) -> None:
    a, o = cal.matrix, cal.offset
    offs_names, scal_names = acc_param_names(instance)
    if generation == "3.3+":
        scale, offset = np.diag(a).copy(), o.copy()
        cost = cost_of_diagonal_only(a, STANDARD_GRAVITY)
    else:
        b = r @ a @ r.T
        scale = np.diag(b).copy()
        offset = scale * (r @ o)          # SCAL ⊙ (R raw) − OFFS = diag(B)(R raw − R o)
        cost = cost_of_diagonal_only(b, STANDARD_GRAVITY)
    prop.costs["acc_diagonal_only_ms2"] = cost
    if generation == "3.2":
        # ardupilot-facts.md "How the firmware applies the parameters": 3.2 scales first, then
        # subtracts INS_ACCOFFS, so its offset is the scaled one, not the one the report shows
        frame = "" if np.allclose(r, np.eye(3)) else ", in the body frame (AHRS_ORIENTATION)"
        prop.notes.append(f"accelerometer: INS_ACCOFFS = INS_ACCSCAL × the offset shown above"
                          f"{frame}, because firmware 3.2 scales the reading before it "
                          "subtracts the offset")
    prop.notes.append(f"accelerometer: per-axis scale only (no cross-axis parameter); worst-case "
                      f"error over all gravity directions {cost:.4f} m/s²")
    values = dict(zip(offs_names, offset)) | dict(zip(scal_names, scale))
    _accept_or_withhold(prop, values, acc_violations(values, instance, generation),
                        "accelerometer")


def _gyroscope(cal, r, generation, instance, prop: ParamProposal, params) -> None:
    names = gyr_param_names(instance)
    offset = cal.offset if generation == "3.3+" else r @ cal.offset
    cost = cost_of_approximation(cal.matrix, np.eye(3), 1.0)
    prop.costs["gyr_matrix_dropped_rad_s_at_1rad_s"] = cost
    prop.notes.append(f"gyroscope: only offsets exist; the scale/misalignment matrix is dropped "
                      f"(worst-case {cost:.4f} rad/s at 1 rad/s)")
    if np.any(cal.drift):
        prop.notes.append("gyroscope: bias drift cannot be represented; offset at t_ref used")
    if generation == "3.3+" and params.get("INS_GYR_CAL", 1) != 0:
        prop.notes.append("gyroscope: INS_GYROFFS is re-measured at every boot unless "
                          "INS_GYR_CAL=0")
    _accept_or_withhold(prop, dict(zip(names, offset)), {}, "gyroscope")


def polar(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right polar decomposition ``a = u @ p`` (u orthogonal, p symmetric positive
    semi-definite) from the SVD ``a = W·S·Vᵀ``: u = W·Vᵀ, p = V·S·Vᵀ (what
    ``scipy.linalg.polar(a, side="right")`` computes; here without importing scipy.linalg,
    ~0.3 s of every ``apmcal log`` run).

    Parameters
    ----------
    a : numpy.ndarray, shape (3, 3)

    Returns
    -------
    u, p : numpy.ndarray, shape (3, 3) each
    """
    w, s, vh = np.linalg.svd(a)
    return w @ vh, (vh.T * s) @ vh


def _compass(cal, params, generation, instance, prop: ParamProposal, field_mgauss,
             known: bool) -> None:
    names = mag_param_names(instance)
    rm = compass_rotation(params, generation, instance)
    b = rm @ cal.matrix @ rm.T                    # the calibration in body frame
    values = dict(zip(names["ofs"], -(rm @ cal.offset)))   # offset is ADDED by the firmware
    # ardupilot-facts.md "How the firmware applies the parameters": mag = M·(raw + COMPASS_OFS),
    # so the sign flips; said in words, since the report shows apmcal's subtracted offset
    frame = "" if np.allclose(rm, np.eye(3)) else " (turned into the body frame)"
    prop.notes.append("compass: COMPASS_OFS is minus the offset shown above" + frame + ": "
                      "ArduPilot adds COMPASS_OFS to the raw reading, apmcal's offset is "
                      "subtracted from it; the same correction")
    # a 3.3+ vehicle whose parameter list lacks DIA (built without them) gets offsets only
    has_dia = generation == "3.3+" and (not known or all(n in params for n in names["dia"]))
    if has_dia:
        u, p = polar(b)                           # b = u @ p, p symmetric positive
        # rotation angle θ of u from ‖u − I‖_F = 2√2·sin(θ/2) (accurate for small θ, unlike acos)
        chord = np.linalg.norm(u - np.eye(3)) / (2 * math.sqrt(2))
        angle = math.degrees(2 * math.asin(min(1.0, chord)))
        prop.costs["mag_rotation_dropped_deg"] = angle
        prop.costs["mag_rotation_dropped_mgauss"] = cost_of_approximation(b, p, field_mgauss)
        prop.notes.append(f"compass: DIA/ODI from the symmetric factor of the matrix; the dropped "
                          f"rotation is {angle:.3f}° (magnitudes unchanged)")
        values |= dict(zip(names["dia"], np.diag(p)))
        values |= dict(zip(names["odi"], (p[0, 1], p[0, 2], p[1, 2])))
        scale = compass_scale(params, instance)
        if scale != 1.0 and names["scale"] in params:
            # the firmware would multiply DIA/ODI by it: none, the matrix holds the gain
            values[names["scale"]] = 0.0
            prop.notes.append(f"compass: {names['scale']} {scale:g} in force is set to 0 (no "
                              f"scaling): the proposed DIA/ODI hold the whole gain")
    else:
        cost = cost_of_approximation(b, np.eye(3), field_mgauss)
        prop.costs["mag_matrix_dropped_mgauss"] = cost
        why = "3.2 has" if generation == "3.2" else "this firmware has"
        prop.notes.append(f"compass: {why} no COMPASS_DIA/ODI, only offsets are proposed; the "
                          f"dropped soft-iron matrix costs up to {cost:.1f} mGauss at "
                          f"{field_mgauss:g} mGauss")
        if compass_scale(params, instance) != 1.0:
            prop.notes.append(f"compass: {names['scale']} {compass_scale(params, instance):g} "
                              f"in force is kept (the offsets do not depend on it)")
    reasons = offset_violations([values[n] for n in names["ofs"]], names["ofs"], params,
                                generation)
    _accept_or_withhold(prop, values, reasons | soft_iron_violations(values, names), "compass")


# The firmware stores any finite value; these are its parameter ranges, its own calibrators'
# acceptance limits and its pre-arm checks. Each checks the names present in ``values``.
def acc_violations(values: dict[str, float], instance: int, generation: str) -> dict[str, str]:
    """name -> reason for INS_ACC*OFFS / INS_ACC*SCAL values of one IMU instance.

    Parameters
    ----------
    values : dict of str to float
        Offsets [m/s²] and scales (dimensionless) by parameter name; other names ignored.
    instance : int
        IMU instance 0..2.
    generation : str
        "3.2" or "3.3+".

    Returns
    -------
    dict of str to str
        Empty when every value is within the limits.
    """
    offs_names, scal_names = acc_param_names(instance)
    reasons = {}
    for n in [n for n in offs_names if n in values]:
        if abs(values[n]) > ACC_OFFSET_MAX:
            reasons[n] = f"|offset| {abs(values[n]):.3f} > {ACC_OFFSET_MAX} m/s²"
    for n in [n for n in scal_names if n in values]:
        v = values[n]
        if not ACC_SCALE_RANGE[0] <= v <= ACC_SCALE_RANGE[1]:
            reasons[n] = f"scale {v:.4f} outside {ACC_SCALE_RANGE[0]}..{ACC_SCALE_RANGE[1]}"
        elif generation == "3.2" and abs(v - 1) > ACC_SCALE_MAX_DEV_32:
            reasons[n] = f"|scale − 1| = {abs(v - 1):.4f} > {ACC_SCALE_MAX_DEV_32} (3.2 limit)"
    return reasons


def soft_iron_violations(values: dict[str, float], names: dict) -> dict[str, str]:
    """name -> reason for COMPASS_DIA / COMPASS_ODI values (``names``: mag_param_names)."""
    reasons = {}
    for n in [n for n in names["dia"] if n in values]:
        if not DIA_RANGE[0] <= values[n] <= DIA_RANGE[1]:
            reasons[n] = f"diagonal {values[n]:.4f} outside {DIA_RANGE[0]}..{DIA_RANGE[1]}"
    for n in [n for n in names["odi"] if n in values]:
        if abs(values[n]) >= ODI_MAX:
            reasons[n] = f"|off-diagonal| {abs(values[n]):.4f} >= {ODI_MAX}"
    return reasons


def offset_violations(offsets, names: list[str], params: dict[str, float],
                      generation: str) -> dict[str, str]:
    """name -> reason for compass offsets [mGauss] the firmware's checks reject.

    The pre-arm check compares the length of the offset vector with COMPASS_OFFS_MAX, or, on
    firmware without that parameter, with config.h's COMPASS_OFFSETS_MAX (600); 3.2 also bounds
    each axis to ±400 (ardupilot-facts.md "How the firmware applies the parameters").

    Parameters
    ----------
    offsets : array_like, shape (3,)
        COMPASS_OFS X, Y, Z [mGauss].
    names : list of str
        Their parameter names.
    params : dict of str to float
        The vehicle's parameters (COMPASS_OFFS_MAX when it has one).
    generation : str
        "3.2" or "3.3+".

    Returns
    -------
    dict of str to str
    """
    reasons = {}
    if generation == "3.2":
        reasons = {n: f"|offset| {abs(v):.1f} > {COMPASS_OFS_MAX_32:g} mGauss"
                   for n, v in zip(names, offsets) if abs(v) > COMPASS_OFS_MAX_32}
    if "COMPASS_OFFS_MAX" in params:
        limit, what = float(params["COMPASS_OFFS_MAX"]), "COMPASS_OFFS_MAX"
    else:
        limit, what = COMPASS_OFFSETS_LENGTH_MAX_OLD, "the pre-arm limit of this firmware"
    length = float(np.linalg.norm(offsets))
    if length > limit and names[0] not in reasons:
        reasons[names[0]] = f"offset vector length {length:.1f} > {what} {limit:g} mGauss"
    return reasons


def _accept_or_withhold(prop: ParamProposal, values: dict, reasons: dict, sensor: str) -> None:
    """Add ``values`` (float32) unless one is refused: then the whole sensor is withheld, so a
    vehicle never gets half a calibration."""
    # float32 as the vehicle stores it; rounding residue (1e-16) and −0.0 written as plain 0
    values = {n: (0.0 if abs(v) < 1e-12 else float(np.float32(v))) for n, v in values.items()}
    for n, v in values.items():
        if not math.isfinite(v):
            reasons[n] = f"value {v!r} is not finite"
    if not reasons:
        prop.values.update(values)
        return
    first = next(iter(reasons))
    for n in values:
        prop.rejected[n] = reasons.get(
            n, f"withheld with the rest of the {sensor} ({first} refused)")
    prop.notes.append(f"{sensor}: not proposed, out of the firmware's limits: "
                      + "; ".join(f"{n}: {why}" for n, why in reasons.items()))


def _check_known(prop: ParamProposal, current_params: dict[str, float] | None) -> None:
    """Refuse names the vehicle does not have (it would drop them silently).

    Only judged for a family (INS_, COMPASS_) of which ``current_params`` holds some names: a
    partial dictionary (e.g. just AHRS_ORIENTATION) says nothing about the others.
    """
    current = current_params or {}
    families = {n.split("_", 1)[0] for n in current}
    for n in [n for n in prop.values
              if n not in current and n.split("_", 1)[0] in families]:
        prop.rejected[n] = "the vehicle has no such parameter (wrong firmware generation?)"
        del prop.values[n]


SENSOR_PARAM_PREFIXES = {"acc": ("INS_ACC",), "gyr": ("INS_GYR",), "mag": ("COMPASS_",)}


def withhold_undetermined(proposal: ParamProposal, undetermined: dict[str, str]) -> None:
    """Drop the parameters (proposed or rejected) of sensors the method could not determine.

    ``undetermined`` maps a sensor ("acc", "gyr", "mag") to the reason; it becomes a note, so
    the user sees why nothing is proposed rather than a misleading rejection.
    """
    for sensor, why in undetermined.items():
        prefixes = SENSOR_PARAM_PREFIXES[sensor]
        names = [n for n in [*proposal.values, *proposal.rejected] if n.startswith(prefixes)]
        for name in names:
            proposal.values.pop(name, None)
            proposal.rejected.pop(name, None)
        if names:
            proposal.notes.append(f"{', '.join(names)} withheld: {why}")
