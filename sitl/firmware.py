"""How the simulated ArduCopter firmware turns raw sensor samples into what it reports.

Written from ../shared/ardupilot-facts.md ("How the firmware applies the parameters") alone.

Generations
-----------
"3.2" (Copter 3.2.x, APM 2.x): body frame, scale FIRST then offset::

    acc = INS_ACCSCAL ⊙ (R·raw) − INS_ACCOFFS        gyr = R·raw − INS_GYROFFS

"3.3" (Copter 3.3 and newer): sensor frame, offset then scale, then the board rotation::

    acc = R·((raw − INS_ACCOFFS) ⊙ INS_ACCSCAL)      gyr = R·(raw − INS_GYROFFS)

Compass, every generation, body frame, offset ADDED (DIA/ODI only on 3.3+, identity on 3.2)::

    mag = M(DIA, ODI)·(R·raw + COMPASS_OFS) + COMPASS_MOT·throttle

R is the AHRS_ORIENTATION rotation (board frame → vehicle body frame).
"""
from __future__ import annotations

import numpy as np

GENERATIONS = ("3.2", "3.3")

# AHRS_ORIENTATION enum (ArduPilot "Rotation"): value -> (roll, pitch, yaw) [deg]; the rotation
# applied to a board vector is Rz(yaw)·Ry(pitch)·Rx(roll) (roll first), e.g. ROLL_180_YAW_90
# maps (x, y, z) to (y, x, −z).
ROTATIONS = {
    0: (0, 0, 0), 1: (0, 0, 45), 2: (0, 0, 90), 3: (0, 0, 135), 4: (0, 0, 180),
    5: (0, 0, 225), 6: (0, 0, 270), 7: (0, 0, 315), 8: (180, 0, 0), 9: (180, 0, 45),
    10: (180, 0, 90), 11: (180, 0, 135), 12: (0, 180, 0), 13: (180, 0, 225),
    14: (180, 0, 270), 15: (180, 0, 315), 16: (90, 0, 0), 17: (90, 0, 45), 18: (90, 0, 90),
    19: (90, 0, 135), 20: (270, 0, 0), 21: (270, 0, 45), 22: (270, 0, 90), 23: (270, 0, 135),
    24: (0, 90, 0), 25: (0, 270, 0),
}


def euler_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Rz(yaw)·Ry(pitch)·Rx(roll), the ZYX Euler direction-cosine matrix (body → reference)."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rotation_matrix(orientation: int) -> np.ndarray:
    """Board → body rotation for an AHRS_ORIENTATION value (exact 0/±1 entries for right angles)."""
    try:
        rpy = ROTATIONS[int(orientation)]
    except KeyError:
        raise ValueError(f"AHRS_ORIENTATION {orientation} is not simulated") from None
    return np.round(euler_matrix(*rpy), 15)


def _vec(params: dict, fmt: str, default: float) -> np.ndarray:
    return np.array([float(params.get(fmt.format(a), default)) for a in "XYZ"])


def apply_accel(raw: np.ndarray, params: dict, generation: str) -> np.ndarray:
    """Reported accelerometer [m/s², body frame] from raw (n, 3) samples [m/s², board frame]."""
    rot = rotation_matrix(params.get("AHRS_ORIENTATION", 0))
    offs, scal = _vec(params, "INS_ACCOFFS_{}", 0.0), _vec(params, "INS_ACCSCAL_{}", 1.0)
    raw = np.atleast_2d(raw)
    if generation == "3.2":
        # ardupilot-facts.md: 3.2 rotates to body, scales FIRST, then subtracts the offset
        return (raw @ rot.T) * scal - offs
    # ardupilot-facts.md: 3.3+ applies offset then scale in the sensor frame, then rotates
    return ((raw - offs) * scal) @ rot.T


def apply_gyro(raw: np.ndarray, params: dict, generation: str) -> np.ndarray:
    """Reported gyroscope [rad/s, body frame] from raw (n, 3) samples [rad/s, board frame]."""
    rot = rotation_matrix(params.get("AHRS_ORIENTATION", 0))
    offs = _vec(params, "INS_GYROFFS_{}", 0.0)
    raw = np.atleast_2d(raw)
    if generation == "3.2":
        return raw @ rot.T - offs          # ardupilot-facts.md: 3.2 offset in body frame
    return (raw - offs) @ rot.T            # ardupilot-facts.md: 3.3+ offset in sensor frame


def soft_iron_matrix(params: dict, generation: str) -> np.ndarray:
    """M(DIA, ODI) of ardupilot-facts.md; identity on 3.2 where DIA/ODI do not exist."""
    if generation == "3.2":
        return np.eye(3)
    dx, dy, dz = _vec(params, "COMPASS_DIA_{}", 1.0)
    ox, oy, oz = _vec(params, "COMPASS_ODI_{}", 0.0)
    return np.array([[dx, ox, oy], [ox, dy, oz], [oy, oz, dz]])


def apply_compass(raw: np.ndarray, params: dict, generation: str,
                  throttle: np.ndarray | float = 0.0, current_a: np.ndarray | float = 0.0
                  ) -> np.ndarray:
    """Reported field [mGauss, body frame] from raw (n, 3) samples [mGauss, board frame].

    COMPASS_MOTCT selects the compensation input: 0 none, 1 throttle (0..1), 2 current [A].
    """
    rot = rotation_matrix(params.get("AHRS_ORIENTATION", 0))
    ofs = _vec(params, "COMPASS_OFS_{}", 0.0)
    m = soft_iron_matrix(params, generation)
    # ardupilot-facts.md: compass offsets are ADDED, in the body frame, then DIA/ODI
    out = (np.atleast_2d(raw) @ rot.T + ofs) @ m.T
    motct = int(params.get("COMPASS_MOTCT", 0))
    if motct in (1, 2):
        drive = np.asarray(throttle if motct == 1 else current_a, dtype=float)
        out = out + np.multiply.outer(np.broadcast_to(drive, out.shape[:1]),
                                      _vec(params, "COMPASS_MOT_{}", 0.0))
    return out


def gyro_boot_offsets(raw_gyro: np.ndarray, params: dict, generation: str) -> np.ndarray:
    """INS_GYROFFS the firmware measures at boot (INS_GYR_CAL=1): the mean still-gyro reading.

    In the frame where the generation subtracts it (body on 3.2, sensor on 3.3+).
    """
    raw_gyro = np.atleast_2d(raw_gyro)
    if generation == "3.2":
        return (raw_gyro @ rotation_matrix(params.get("AHRS_ORIENTATION", 0)).T).mean(axis=0)
    return raw_gyro.mean(axis=0)
