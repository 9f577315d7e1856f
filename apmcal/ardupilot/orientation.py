"""ArduPilot's board rotations (AHRS_ORIENTATION, COMPASS_ORIENT) as rotation matrices.

The firmware rotates a sensor-frame vector into the body frame with ``v_body = R @ v_sensor``.
Every entry of ArduPilot's ``enum Rotation`` (libraries/AP_Math/rotations.h) is a named Euler
rotation, and ArduPilot's own rotation test (AP_Math/tests/test_rotations.cpp, ``test_euler``)
checks that ``v.rotate(r)`` equals ``Matrix3f::from_euler(roll, pitch, yaw) * v``, i.e. the
321 (yaw-pitch-roll) direction cosine matrix ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. So the table
below holds (roll, pitch, yaw) in degrees, in the enum's numeric order, and the matrices are
built from them rather than from hand-written axis swaps. Entry 38 is the one odd angle set
(90, 68.8, 293.3), taken from that same test.

Custom rotations (100 = ROTATION_CUSTOM, 4.1, angles AHRS_CUSTOM_ROLL/PIT/YAW; 101/102 =
ROTATION_CUSTOM_1/2, 4.2+, angles CUSTOM_ROT1_ROLL/PITCH/YAW and CUSTOM_ROT2_*; degrees, euler 321
per AP_CustomRotations_params.cpp) need those parameters, else :class:`ApmcalError`.
"""
from __future__ import annotations

import math

import numpy as np

from apmcal.core.errors import ApmcalError

# enum Rotation value -> (name, roll, pitch, yaw) [deg]; AP_Math/rotations.h, numeric order.
ROTATIONS: dict[int, tuple[str, float, float, float]] = {
    0: ("NONE", 0, 0, 0),
    1: ("YAW_45", 0, 0, 45),
    2: ("YAW_90", 0, 0, 90),
    3: ("YAW_135", 0, 0, 135),
    4: ("YAW_180", 0, 0, 180),
    5: ("YAW_225", 0, 0, 225),
    6: ("YAW_270", 0, 0, 270),
    7: ("YAW_315", 0, 0, 315),
    8: ("ROLL_180", 180, 0, 0),
    9: ("ROLL_180_YAW_45", 180, 0, 45),
    10: ("ROLL_180_YAW_90", 180, 0, 90),
    11: ("ROLL_180_YAW_135", 180, 0, 135),
    12: ("PITCH_180", 0, 180, 0),
    13: ("ROLL_180_YAW_225", 180, 0, 225),
    14: ("ROLL_180_YAW_270", 180, 0, 270),
    15: ("ROLL_180_YAW_315", 180, 0, 315),
    16: ("ROLL_90", 90, 0, 0),
    17: ("ROLL_90_YAW_45", 90, 0, 45),
    18: ("ROLL_90_YAW_90", 90, 0, 90),
    19: ("ROLL_90_YAW_135", 90, 0, 135),
    20: ("ROLL_270", 270, 0, 0),
    21: ("ROLL_270_YAW_45", 270, 0, 45),
    22: ("ROLL_270_YAW_90", 270, 0, 90),
    23: ("ROLL_270_YAW_135", 270, 0, 135),
    24: ("PITCH_90", 0, 90, 0),
    25: ("PITCH_270", 0, 270, 0),
    26: ("PITCH_180_YAW_90", 0, 180, 90),      # same matrix as 14
    27: ("PITCH_180_YAW_270", 0, 180, 270),    # same matrix as 10
    28: ("ROLL_90_PITCH_90", 90, 90, 0),
    29: ("ROLL_180_PITCH_90", 180, 90, 0),
    30: ("ROLL_270_PITCH_90", 270, 90, 0),
    31: ("ROLL_90_PITCH_180", 90, 180, 0),
    32: ("ROLL_270_PITCH_180", 270, 180, 0),
    33: ("ROLL_90_PITCH_270", 90, 270, 0),
    34: ("ROLL_180_PITCH_270", 180, 270, 0),
    35: ("ROLL_270_PITCH_270", 270, 270, 0),
    36: ("ROLL_90_PITCH_180_YAW_90", 90, 180, 90),
    37: ("ROLL_90_YAW_270", 90, 0, 270),
    38: ("ROLL_90_PITCH_68_YAW_293", 90, 68.8, 293.3),
    39: ("PITCH_315", 0, 315, 0),
    40: ("ROLL_90_PITCH_315", 90, 315, 0),
    41: ("PITCH_7", 0, 7, 0),
    42: ("ROLL_45", 45, 0, 0),
    43: ("ROLL_315", 315, 0, 0),
}

# Custom rotation codes -> candidate parameter triples holding their Euler angles [deg]. 100 was
# ROTATION_CUSTOM with AHRS_CUSTOM_ROLL/PIT/YAW (4.1); 4.2+ moves it to CUSTOM_ROT1_*.
_CUSTOM = {
    100: [("AHRS_CUSTOM_ROLL", "AHRS_CUSTOM_PIT", "AHRS_CUSTOM_YAW"),
          ("CUSTOM_ROT1_ROLL", "CUSTOM_ROT1_PITCH", "CUSTOM_ROT1_YAW")],
    101: [("CUSTOM_ROT1_ROLL", "CUSTOM_ROT1_PITCH", "CUSTOM_ROT1_YAW")],
    102: [("CUSTOM_ROT2_ROLL", "CUSTOM_ROT2_PITCH", "CUSTOM_ROT2_YAW")],
}


def euler_to_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Direction cosine matrix ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (ArduPilot ``from_euler``).

    Angles in degrees. Entries within 1e-15 of 0 or ±1 are snapped so that the 90° rotations
    are exact signed permutations (no 6e-17 residue from cos(90°)).

    Parameters
    ----------
    roll_deg, pitch_deg, yaw_deg : float
        Euler 321 angles [deg].

    Returns
    -------
    numpy.ndarray, shape (3, 3)
    """
    r, p, y = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp = math.cos(r), math.sin(r), math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    m = rz @ ry @ rx
    for target in (-1.0, 0.0, 1.0):
        m[np.abs(m - target) < 1e-15] = target
    return m


def rotation_matrix(code: float | int, params: dict[str, float] | None = None,
                    param_name: str = "AHRS_ORIENTATION") -> np.ndarray:
    """Rotation matrix (sensor → body) for an ArduPilot ``enum Rotation`` value.

    Parameters
    ----------
    code : int or float
        The parameter value (parameters arrive as float32, so 2.0 is accepted as 2).
    params : dict, optional
        Needed only for the custom rotations 100..102 (CUSTOM_ROTn_ROLL/PITCH/YAW, degrees).
    param_name : str
        Name used in error messages ("AHRS_ORIENTATION", "COMPASS_ORIENT", ...).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``R`` with ``v_body = R @ v_sensor``.

    Raises
    ------
    ApmcalError
        For non-integer, unknown, or custom codes without their angle parameters.
    """
    where = f"param {param_name}"
    if code is None or not math.isfinite(float(code)) or float(code) != int(float(code)):
        raise ApmcalError(f"rotation value {code!r} is not an integer", where=where)
    code = int(float(code))
    if code in ROTATIONS:
        _, roll, pitch, yaw = ROTATIONS[code]
        return euler_to_matrix(roll, pitch, yaw)
    if code in _CUSTOM:
        params = params or {}
        found = [names for names in _CUSTOM[code] if all(n in params for n in names)]
        if not found:
            raise ApmcalError(f"custom rotation {code} needs the parameters "
                              f"{', '.join(_CUSTOM[code][-1])}", where=where)
        names = found[0]
        angles = [float(params[n]) for n in names]
        if not all(math.isfinite(a) for a in angles):
            raise ApmcalError(f"custom rotation {code}: non-finite angle in {', '.join(names)}",
                              where=where)
        return euler_to_matrix(*angles)
    raise ApmcalError(f"unknown rotation {code} (ArduPilot knows 0..43 and 100..102)", where=where)


def rotation_name(code: int) -> str:
    """``ROTATION_<NAME>`` for a code, e.g. 2 -> "ROTATION_YAW_90"."""
    if int(code) in ROTATIONS:
        return "ROTATION_" + ROTATIONS[int(code)][0]
    return {100: "ROTATION_CUSTOM_OLD", 101: "ROTATION_CUSTOM_1",
            102: "ROTATION_CUSTOM_2"}.get(int(code), f"rotation {code}")
