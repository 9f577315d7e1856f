"""How the simulated ArduCopter firmware turns raw sensor samples into what it reports.

Written from docs/ardupilot-facts.md ("How the firmware applies the parameters") alone.

Generations
-----------
"3.2" (Copter 3.2.x, APM 2.x): body frame, scale FIRST then offset::

    acc = INS_ACCSCAL ⊙ (R·raw) − INS_ACCOFFS        gyr = R·raw − INS_GYROFFS

"3.3" (Copter 3.3 and newer): sensor frame, offset then scale, then the board rotation::

    acc = R·((raw − INS_ACCOFFS) ⊙ INS_ACCSCAL)      gyr = R·(raw − INS_GYROFFS)

Compass, every generation, body frame, offset ADDED (ardupilot-facts.md; DIA/ODI only on 3.3+)::

    3.2:  mag = R_mag·raw + COMPASS_OFS + MOT·d
    3.3:  mag = M(DIA, ODI)·(SCALE·(R_mag·raw + COMPASS_OFS) + MOT·d)

SCALE is COMPASS_SCALE (the "3.3" table stands for 3.3 and newer, which have it), applied only
within [0.85, 1.4] and else 1 (its default 0 included), after the offsets and before the matrix
(ardupilot-facts.md, current ``correct_field``).

d = throttle (0..1, COMPASS_MOTCT=1) or current [A] (MOTCT=2), MOT·d applied only when MOTCT≠0
and d≠0. R is the AHRS_ORIENTATION rotation (board frame → vehicle body frame). The facts file
only says that COMPASS_ORIENT/COMPASS_EXTERNAL exist; how they combine with AHRS_ORIENTATION,
the all-zero-DIA rule and where MOT·d enters on 3.3 are taken from the firmware sources (see
:func:`compass_rotation`, :func:`soft_iron_matrix`, :func:`apply_compass`).
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


def temperature_correction(temp_c, params: dict, kind: str) -> np.ndarray | float:
    """The temperature correction [m/s² or rad/s] (n, 3) the firmware subtracts from the raw
    sensor-frame samples of IMU 1 (``kind`` "ACC" or "GYR"); 0 unless INS_TCAL1_ENABLE = 1.

    As ArduPilot 4.1+ does it (AP_InertialSensor_tempcal.cpp ``correct_sensor`` and
    ``polynomial_eval``; AP_InertialSensor_Backend.cpp ``_rotate_and_correct_accel/gyro`` apply
    it in the sensor frame before the offsets and scales): with T and the calibration
    temperature INS_ACC1_CALTEMP / INS_GYR1_CALTEMP each clamped to [TMIN, TMAX],
    P(d) = (c1 + (c2 + c3·d)·d)·d·1e-6 per axis, c_k = INS_TCAL1_{kind}k_X..Z, and the
    correction is P(T − 35) − P(T_cal − 35).
    """
    if temp_c is None or float(params.get("INS_TCAL1_ENABLE", 0)) != 1.0:
        return 0.0
    lo, hi = float(params["INS_TCAL1_TMIN"]), float(params["INS_TCAL1_TMAX"])
    c = [_vec(params, f"INS_TCAL1_{kind}{k}_{{}}", 0.0) for k in (1, 2, 3)]

    def poly(t):
        d = np.clip(np.asarray(t, float), lo, hi)[..., None] - 35.0
        return (c[0] + (c[1] + c[2] * d) * d) * d * 1e-6

    return poly(np.atleast_1d(temp_c)) - poly(float(params[f"INS_{kind}1_CALTEMP"]))


def apply_accel(raw: np.ndarray, params: dict, generation: str, temp_c=None) -> np.ndarray:
    """Reported accelerometer [m/s², body frame] from raw (n, 3) samples [m/s², board frame].

    ``temp_c`` (n,) [°C]: the board temperature, for the 3.3 generation's stand-in of 4.1+'s
    temperature calibration (:func:`temperature_correction`, applied first, in sensor frame).
    """
    rot = rotation_matrix(params.get("AHRS_ORIENTATION", 0))
    offs, scal = _vec(params, "INS_ACCOFFS_{}", 0.0), _vec(params, "INS_ACCSCAL_{}", 1.0)
    raw = np.atleast_2d(raw)
    if generation == "3.2":
        # ardupilot-facts.md: 3.2 rotates to body, scales FIRST, then subtracts the offset
        return (raw @ rot.T) * scal - offs
    raw = raw - temperature_correction(temp_c, params, "ACC")
    # ardupilot-facts.md: 3.3+ applies offset then scale in the sensor frame, then rotates
    return ((raw - offs) * scal) @ rot.T


def apply_gyro(raw: np.ndarray, params: dict, generation: str, temp_c=None) -> np.ndarray:
    """Reported gyroscope [rad/s, body frame] from raw (n, 3) samples [rad/s, board frame]
    (``temp_c`` as for :func:`apply_accel`)."""
    rot = rotation_matrix(params.get("AHRS_ORIENTATION", 0))
    offs = _vec(params, "INS_GYROFFS_{}", 0.0)
    raw = np.atleast_2d(raw)
    if generation == "3.2":
        return raw @ rot.T - offs          # ardupilot-facts.md: 3.2 offset in body frame
    raw = raw - temperature_correction(temp_c, params, "GYR")
    return (raw - offs) @ rot.T            # ardupilot-facts.md: 3.3+ offset in sensor frame


def dia_all_zero(params: dict) -> bool:
    """True when COMPASS_DIA_X/Y/Z all exist and are exactly 0 (``Vector3f::is_zero()``)."""
    names = [f"COMPASS_DIA_{a}" for a in "XYZ"]
    return all(n in params for n in names) and all(float(params[n]) == 0.0 for n in names)


def soft_iron_matrix(params: dict, generation: str) -> np.ndarray:
    """M(DIA, ODI) of ardupilot-facts.md; identity on 3.2 where DIA/ODI do not exist.

    All three COMPASS_DIA exactly 0 count as (1, 1, 1), the off-diagonals still applied (not in
    ardupilot-facts.md): Copter 3.3's ``AP_Compass_Backend::apply_corrections`` (the 3.3-based
    3drobotics/ardupilot-solo and SMT-sMart-Team/ardupilot-3.3; ``correct_field`` in
    ArduPilot/ardupilot libraries/AP_Compass/AP_Compass_Backend.cpp at 00ed6bbc) starts with
    ``if (state.diagonals.get().is_zero()) state.diagonals.set(Vector3f(1.0f,1.0f,1.0f));`` and
    then builds the matrix with ODI as stored. Only the all-zero case is special: DIA = (0, 1, 1)
    is used as it is (singular).
    """
    if generation == "3.2":
        return np.eye(3)
    dx, dy, dz = (1.0, 1.0, 1.0) if dia_all_zero(params) else _vec(params, "COMPASS_DIA_{}", 1.0)
    ox, oy, oz = _vec(params, "COMPASS_ODI_{}", 0.0)
    return np.array([[dx, ox, oy], [ox, dy, oz], [oy, oz, dz]])


def compass_rotation(params: dict, generation: str) -> np.ndarray:
    """Compass sensor → body rotation from AHRS_ORIENTATION, COMPASS_ORIENT, COMPASS_EXTERNAL.

    ardupilot-facts.md lists COMPASS_ORIENT and COMPASS_EXTERNAL (on every generation) but not
    how they are applied; from the firmware sources (``v.rotate(A)`` then ``v.rotate(B)`` is
    B·A·v; MAG_BOARD_ORIENTATION and the driver's fixed chip rotation are not modelled):

    * 3.2 (the pre-backend drivers' ``read()``, e.g. ``AP_Compass_HMC5843::read``, and the
      first ``AP_Compass_Backend::_copy_to_frontend``, in 3.2-era forks of ArduPilot):
      ``rotate(COMPASS_ORIENT)`` always, then ``if (!_external) rotate(_board_orientation)``,
      i.e. R = R_orient (external) or R_ahrs·R_orient (internal).
    * 3.3 (``AP_Compass_Backend::publish_field`` in SMT-sMart-Team/ardupilot-3.3;
      ``rotate_field`` in 3drobotics/ardupilot-solo and ArduPilot/ardupilot at 00ed6bbc):
      ``if (!state.external) rotate(_board_orientation); else rotate(state.orientation)``,
      i.e. R = R_orient (external) or R_ahrs (internal: COMPASS_ORIENT ignored).

    COMPASS_EXTERNAL is used as stored (the drivers' boot-time ``set_external`` is not modelled).
    """
    ahrs = rotation_matrix(params.get("AHRS_ORIENTATION", 0))
    orient = rotation_matrix(params.get("COMPASS_ORIENT", 0))
    external = float(params.get("COMPASS_EXTERNAL", 0)) != 0
    if generation == "3.2":
        return orient if external else ahrs @ orient
    return orient if external else ahrs


# COMPASS_SCALE applies only within these bounds (ardupilot-facts.md "How the firmware applies
# the parameters": Compass::have_scale_factor, CompassCalibrator.h)
SCALE_FACTOR_RANGE = (0.85, 1.4)


def compass_scale_factor(params: dict) -> float:
    """COMPASS_SCALE when within SCALE_FACTOR_RANGE, else 1 (none)."""
    value = float(params.get("COMPASS_SCALE", 0.0))
    return value if SCALE_FACTOR_RANGE[0] <= value <= SCALE_FACTOR_RANGE[1] else 1.0


def compass_motor_offset(params: dict, throttle: np.ndarray | float = 0.0,
                         current_a: np.ndarray | float = 0.0, n: int | None = None
                         ) -> np.ndarray:
    """COMPASS_MOT·d [mGauss, body frame] (n, 3), the firmware's ``motor_offset`` (MAG MOX..Z).

    COMPASS_MOTCT selects d: 0 none, 1 throttle (0..1), 2 battery current [A]. ADDED to the
    field (ardupilot-facts.md "How the firmware applies the parameters"; Copter 3.2/3.3
    ``mag += motor_offset`` only when the type is not disabled and d ≠ 0), never subtracted:
    compassmot stores MOT as minus the interference per unit d, so adding it cancels it.
    """
    motct = int(params.get("COMPASS_MOTCT", 0))
    drive = np.atleast_1d(np.asarray(throttle if motct == 1 else current_a, dtype=float))
    if n is not None:
        drive = np.broadcast_to(drive, (n,))
    if motct not in (1, 2):
        return np.zeros((len(drive), 3))
    return np.multiply.outer(drive, _vec(params, "COMPASS_MOT_{}", 0.0))


def apply_compass(raw: np.ndarray, params: dict, generation: str,
                  throttle: np.ndarray | float = 0.0, current_a: np.ndarray | float = 0.0
                  ) -> np.ndarray:
    """Reported field [mGauss, body frame] from raw (n, 3) samples [mGauss, compass frame].

    Copter 3.3 adds COMPASS_MOT·d BEFORE the DIA/ODI matrix (``apply_corrections`` /
    ``correct_field``, same sources as :func:`soft_iron_matrix`:
    ``mag += offsets; mag += motor_offset; mag = mat * mag``); later firmware (4.x
    ``AP_Compass_Backend::correct_field``: "we apply the motor offsets after we apply the
    elliptical correction") and ardupilot-facts.md's formula add it after. The simulated
    firmware is Copter 3.3.3, so it follows 3.3. On 3.2 (no matrix) both orders agree.
    """
    raw = np.atleast_2d(raw)
    rot = compass_rotation(params, generation)
    ofs = _vec(params, "COMPASS_OFS_{}", 0.0)
    m = soft_iron_matrix(params, generation)
    # ardupilot-facts.md: compass offsets are ADDED, in the body frame, then the scale factor
    # (SCALE_FACTOR_RANGE), then DIA/ODI
    body = (raw @ rot.T + ofs) * compass_scale_factor(params)
    if int(params.get("COMPASS_MOTCT", 0)) in (1, 2):
        body = body + compass_motor_offset(params, throttle, current_a, len(raw))
    return body @ m.T


def gyro_boot_offsets(raw_gyro: np.ndarray, params: dict, generation: str) -> np.ndarray:
    """INS_GYROFFS the firmware measures at boot (INS_GYR_CAL=1): the mean still-gyro reading.

    In the frame where the generation subtracts it (body on 3.2, sensor on 3.3+).
    """
    raw_gyro = np.atleast_2d(raw_gyro)
    if generation == "3.2":
        return (raw_gyro @ rotation_matrix(params.get("AHRS_ORIENTATION", 0)).T).mean(axis=0)
    return raw_gyro.mean(axis=0)
