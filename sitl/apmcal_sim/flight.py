"""A simulated multicopter flight written as an ArduCopter 4.x dataflash log, with known compass
errors: the test bed of apmcal's in-flight compass calibration.

    python -m apmcal_sim.flight --out flight.bin --truth-out flight.truth.json [--seed 1]
        [--rate 25] [--orient-error 0] [--yaw-bias 8]

The script (seconds at the default ``scale`` 1): on the ground disarmed, take-off, two full yaw
turns in the hover, four legs flown nose first at 8 m/s at headings 0°, 120°, 240° and 60° (with
the turns between them), a climb at 90 % throttle while yawing, a slow descent at 25 % throttle
yawing the other way, landing, on the ground again. It is kinematic: attitude, velocity and
throttle follow the script (smoothed), with a small roll/pitch wobble in the air.

The compass model, per instance, body frame FRD, mGauss (``I`` battery current in A)::

    raw_body  = A · (R_nbᵀ · B_ned + k · I) + h          (the physical field at the sensor)
    raw_sens  = R_physᵀ · raw_body                       (the sensor is mounted with R_phys)
    logged    = S0·M0 · (R_cfg · raw_sens + OFS0) + MOT0 · I     (the firmware's correct_field,
                ardupilot-facts.md "How the firmware applies the parameters", 4.x order)

so the ideal parameters are COMPASS_ORIENT = R_phys's code, M·S0 = A⁻¹ (DIA/ODI = A⁻¹/S0),
OFS = −h, MOT = −k [mGauss/A] with COMPASS_MOTCT = 2 (current). The truth JSON holds them as
``ideal`` per instance next to the values in force. B_ned is the WMM field at the site and date
(:mod:`apmcal.core.geomag`). The logged ATT yaw is the true yaw plus a bias that a
miscalibrated compass would give an EKF: a constant, a heading-dependent term and a drift
(``yaw_bias``); roll and pitch are logged with 0.1° noise.

Records (4.x layouts, only the columns used): PARM, MSG, ATT "QccccCC", GPS "QBBIHBcLLefff"
(5 Hz), MAG "QBhhhhhhhhhB" per instance, IMU with ``I``, BAT "QBfff" (10 Hz), RCOU "QHHHH"
(10 Hz, PWM 1000-2000 = throttle 0-1).
"""
from __future__ import annotations

import argparse
import datetime
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apmcal.ardupilot.orientation import rotation_matrix
from apmcal.core import geomag
from apmcal_sim.logwriter import DataflashWriter

START_UNIX = 1_780_000_000.0        # 2026-05-28 UTC, fixed so logs are byte-reproducible
SITE = {"lat": -35.3632, "lon": 149.1652, "alt": 584.0}   # ArduPilot SITL's default home (CMAC)
EARTH_RADIUS_M = 6_378_137.0
GPS_EPOCH_UNIX_S = 315964800
GPS_MINUS_UTC_S = 18
IDLE_CURRENT_A = 0.8                # avionics on the ground
FULL_THROTTLE_CURRENT_A = 45.0      # current [A] = idle + 45 A × throttle
FIRMWARE_TEXT = "ArduCopter V4.5.7 (apmcal_sim flight)"

FLIGHT_MESSAGES = {
    "ATT": (140, "QccccCC", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
    "GPS": (133, "QBBIHBcLLefff", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ"),
    "MAG": (132, "QBhhhhhhhhhB", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health"),
    "BAT": (134, "QBfff", "TimeUS,Inst,Volt,VoltR,Curr"),
    "RCOU": (141, "QHHHH", "TimeUS,C1,C2,C3,C4"),
}


@dataclass
class CompassTruth:
    """One compass instance's physical errors and the parameters in force.

    ``hard_iron`` h [mGauss, body], ``soft_iron`` A (symmetric, body), ``interference`` k
    [mGauss/A, body], ``orient_phys`` the rotation code the sensor is really mounted with and
    ``params`` the COMPASS_* values in force for this instance (unsuffixed names: OFS_X, DIA_X,
    ODI_X, MOT_X, SCALE, ORIENT, EXTERNAL).
    """

    hard_iron: list
    soft_iron: list
    interference: list
    orient_phys: int = 0
    params: dict = field(default_factory=dict)

    def ideal(self) -> dict:
        """The COMPASS_* values (unsuffixed) that correct this compass exactly."""
        scale = float(self.params.get("SCALE", 0.0)) or 1.0
        m = np.linalg.inv(np.asarray(self.soft_iron, float)) / scale
        out = {f"OFS_{a}": -float(v) for a, v in zip("XYZ", self.hard_iron)}
        out.update({f"DIA_{a}": float(m[i, i]) for i, a in enumerate("XYZ")})
        out.update({"ODI_X": float(m[0, 1]), "ODI_Y": float(m[0, 2]), "ODI_Z": float(m[1, 2])})
        out.update({f"MOT_{a}": -float(v) for a, v in zip("XYZ", self.interference)})
        out["ORIENT"] = int(self.orient_phys)
        return out


def default_compasses(seed: int, orient_error: int = 0) -> list[CompassTruth]:
    """Two compasses with errors drawn from ``seed``: instance 0 external (mounted with
    ``orient_error`` while COMPASS_ORIENT says 0), instance 1 internal, COMPASS_SCALE2 1.02."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(2):
        soft = np.eye(3) + np.diag(rng.normal(0, 0.06, 3))
        off = rng.normal(0, 0.03, 3)
        soft[0, 1] = soft[1, 0] = off[0]
        soft[0, 2] = soft[2, 0] = off[1]
        soft[1, 2] = soft[2, 1] = off[2]
        hard, inter = rng.normal(0, 120, 3), rng.normal(0, 1.5, 3)
        # in force: a stale calibration (offsets 20 mGauss off, no soft iron, half the motor
        # compensation), as a vehicle carries after a change of wiring
        ofs0, mot0 = -hard + rng.normal(0, 20, 3), -0.5 * inter
        params = {"OFS_X": float(ofs0[0]), "OFS_Y": float(ofs0[1]), "OFS_Z": float(ofs0[2]),
                  "DIA_X": 1.0, "DIA_Y": 1.0, "DIA_Z": 1.0, "ODI_X": 0.0, "ODI_Y": 0.0,
                  "ODI_Z": 0.0, "MOT_X": float(mot0[0]), "MOT_Y": float(mot0[1]),
                  "MOT_Z": float(mot0[2]), "SCALE": 0.0 if i == 0 else 1.02,
                  "ORIENT": 0, "EXTERNAL": 1 if i == 0 else 0}
        out.append(CompassTruth(hard_iron=hard.tolist(), soft_iron=soft.tolist(),
                                interference=inter.tolist(),
                                orient_phys=orient_error if i == 0 else 0, params=params))
    return out


# ----------------------------------------------------------------------------- trajectory
def _phases(scale: float) -> list[tuple]:
    """(duration [s], yaw rate [deg/s] or target heading ("to", deg), speed [m/s], climb
    [m/s], throttle, airborne) of each phase."""
    s = scale
    ph = [(15 * s, 0.0, 0.0, 0.0, 0.0, False), (8 * s, 0.0, 0.0, 2.5, 0.62, True),
          (20.0, 36.0, 0.0, 0.0, 0.45, True)]                     # two full turns: 720°
    for heading in (0.0, 120.0, 240.0, 60.0):
        ph.append((4.0, ("to", heading), 0.0, 0.0, 0.45, True))
        ph.append((10 * s, 0.0, 8.0, 0.0, 0.52, True))
    ph += [(6.0, 60.0, 0.0, 5.0, 0.9, True), (8.0, -45.0, 0.0, -2.0, 0.25, True),
           (4.0, 0.0, 0.0, 0.0, 0.45, True)]
    return ph


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    k = np.ones(n) / n
    pad = np.concatenate([np.full(n, x[0]), x, np.full(n, x[-1])])
    return np.convolve(pad, k, mode="same")[n:-n]


@dataclass
class Trajectory:
    """Samples of the flight at one rate: t [s], roll/pitch/yaw [rad] (body→NED, 321),
    velocity NED [m/s], position north/east/down [m] from home, throttle 0..1, current [A],
    body rates [rad/s], specific force [m/s², body]."""

    t: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    vel: np.ndarray
    pos: np.ndarray
    throttle: np.ndarray
    current: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray


def fly(rate_hz: float = 25.0, scale: float = 1.0, seed: int = 0) -> Trajectory:
    """The scripted flight sampled at ``rate_hz``; ``scale`` stretches the ground, take-off and
    leg phases (1: about 3 minutes)."""
    rng = np.random.default_rng(seed + 1000)
    dt = 1.0 / rate_hz
    yaw_rate, speed, climb, thr, air = [], [], [], [], []
    heading = 30.0
    for dur, yr, sp, cl, th, ab in _phases(scale):
        n = int(round(dur * rate_hz))
        if isinstance(yr, tuple):
            turn = (yr[1] - heading + 180.0) % 360.0 - 180.0
            yr = turn / dur
        heading += yr * n * dt
        yaw_rate += [yr] * n
        speed += [sp] * n
        climb += [cl] * n
        thr += [th] * n
        air += [ab] * n
    n_s = max(1, int(rate_hz))
    yaw_rate = _smooth(np.radians(yaw_rate), n_s // 2)
    speed, climb = _smooth(np.array(speed), n_s), _smooth(np.array(climb), n_s)
    throttle = _smooth(np.array(thr), n_s // 2)
    airborne = _smooth(np.array(air, float), n_s) > 0.5
    t = np.arange(len(speed)) * dt
    yaw = np.radians(30.0) + np.concatenate([[0.0], np.cumsum(yaw_rate[:-1]) * dt])
    accel_fwd = np.gradient(speed, dt)
    pitch = -np.radians(1.2) * speed - np.radians(3.0) * accel_fwd    # nose down to go forward
    roll = np.zeros_like(t)
    wob = airborne.astype(float)
    roll = roll + wob * (np.radians(4.0) * np.sin(2 * np.pi * 0.35 * t + rng.uniform(0, 6))
                         + np.radians(2.0) * np.sin(2 * np.pi * 0.9 * t))
    pitch = pitch + wob * np.radians(4.0) * np.sin(2 * np.pi * 0.27 * t + rng.uniform(0, 6))
    roll, pitch = _smooth(roll, n_s // 3), _smooth(pitch, n_s // 3)
    vel = np.stack([speed * np.cos(yaw), speed * np.sin(yaw), -climb], axis=1)
    pos = np.concatenate([[np.zeros(3)], np.cumsum(vel[:-1], axis=0) * dt])
    current = IDLE_CURRENT_A + FULL_THROTTLE_CURRENT_A * throttle * airborne
    throttle = throttle * airborne
    # body rates from Euler rates (321): p = φ̇ − ψ̇ sinθ, q = θ̇ cosφ + ψ̇ sinφ cosθ,
    # r = −θ̇ sinφ + ψ̇ cosφ cosθ
    dphi, dth, dpsi = (np.gradient(a, dt) for a in (roll, pitch, yaw))
    gyr = np.stack([dphi - dpsi * np.sin(pitch),
                    dth * np.cos(roll) + dpsi * np.sin(roll) * np.cos(pitch),
                    -dth * np.sin(roll) + dpsi * np.cos(roll) * np.cos(pitch)], axis=1)
    rot = dcm(roll, pitch, yaw)
    a_ned = np.gradient(vel, dt, axis=0) - np.array([0.0, 0.0, 9.80665])
    acc = np.einsum("nji,nj->ni", rot, a_ned)       # f_body = R_nbᵀ (a − g)
    return Trajectory(t, roll, pitch, yaw, vel, pos, throttle, current, gyr, acc)


def dcm(roll, pitch, yaw) -> np.ndarray:
    """(n, 3, 3) body→NED rotations R = Rz(yaw)·Ry(pitch)·Rx(roll) of angles [rad]."""
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    return np.stack([np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                     np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                     np.stack([-sp, cp * sr, cp * cr], -1)], axis=-2)


def yaw_bias(tr: Trajectory, bias_deg: float) -> np.ndarray:
    """The logged yaw's error [rad]: ``bias_deg`` constant + (bias_deg/2)·sin(ψ + 40°) (the
    heading-dependent error a miscalibrated compass gives) + a drift of 0.02°/s."""
    b = np.radians(bias_deg)
    return b + 0.5 * b * np.sin(tr.yaw + np.radians(40.0)) + np.radians(0.02) * tr.t


# ----------------------------------------------------------------------------- compass
def param_name(base: str, instance: int) -> str:
    """ArduPilot's name of COMPASS_<base> for ``instance`` (OFS_X → OFS2_X, SCALE → SCALE2,
    EXTERNAL → EXTERN2)."""
    if instance == 0:
        return f"COMPASS_{base}"
    s = str(instance + 1)
    if base == "EXTERNAL":
        return f"COMPASS_EXTERN{s}"
    if "_" in base:
        head, axis = base.split("_")
        return f"COMPASS_{head}{s}_{axis}"
    return f"COMPASS_{base}{s}"


def compass_logged(tr: Trajectory, field_ned: np.ndarray, c: CompassTruth,
                   rng: np.random.Generator, noise_mgauss: float = 2.0):
    """(logged corrected field, logged offsets, logged motor offset) [mGauss], each (n, 3)."""
    b_body = np.einsum("nji,j->ni", dcm(tr.roll, tr.pitch, tr.yaw), field_ned)
    a = np.asarray(c.soft_iron, float)
    raw_body = (b_body + np.outer(tr.current, c.interference)) @ a.T + np.asarray(c.hard_iron)
    raw_body = raw_body + rng.normal(0, noise_mgauss, raw_body.shape)
    raw_sens = raw_body @ rotation_matrix(c.orient_phys)          # R_physᵀ·v as rows
    p = c.params
    r_cfg = rotation_matrix(p["ORIENT"])
    ofs = np.array([p[f"OFS_{a}"] for a in "XYZ"])
    m0 = np.array([[p["DIA_X"], p["ODI_X"], p["ODI_Y"]], [p["ODI_X"], p["DIA_Y"], p["ODI_Z"]],
                   [p["ODI_Y"], p["ODI_Z"], p["DIA_Z"]]])
    scale = p["SCALE"] if p["SCALE"] > 0 else 1.0
    motor = np.outer(tr.current, [p[f"MOT_{a}"] for a in "XYZ"])
    logged = scale * (raw_sens @ r_cfg.T + ofs) @ m0.T + motor
    return logged, np.broadcast_to(ofs, logged.shape), motor


# ----------------------------------------------------------------------------- writing
def _i16(v) -> int:
    return int(max(-32768, min(32767, round(float(v)))))


def _i16_truncated(v) -> int:
    """An int16 as ArduPilot's MAG record casts its float (toward zero: Compass::Write_Compass)."""
    return int(max(-32768, min(32767, int(float(v)))))


def write_flight(out, truth_out=None, *, seed: int = 1, rate_hz: float = 25.0,
                 orient_error: int = 0, yaw_bias_deg: float = 8.0, scale: float = 1.0,
                 compasses: list[CompassTruth] | None = None) -> dict:
    """Simulate the flight and write the .bin ``out`` (and the truth JSON); return the truth."""
    rng = np.random.default_rng(seed)
    compasses = compasses or default_compasses(seed, orient_error)
    tr = fly(rate_hz, scale, seed)
    year = geomag.decimal_year(datetime.datetime.fromtimestamp(START_UNIX,
                                                               tz=datetime.timezone.utc))
    field_ned, _ = geomag.earth_field_ned(SITE["lat"], SITE["lon"], SITE["alt"], year)
    logs = [compass_logged(tr, field_ned, c, rng) for c in compasses]
    yaw_log = tr.yaw + yaw_bias(tr, yaw_bias_deg)
    roll_log = tr.roll + rng.normal(0, np.radians(0.1), len(tr.t))
    pitch_log = tr.pitch + rng.normal(0, np.radians(0.1), len(tr.t))
    params = {"AHRS_ORIENTATION": 0, "AHRS_EKF_TYPE": 3, "AHRS_TRIM_X": 0.0, "AHRS_TRIM_Y": 0.0,
              "AHRS_TRIM_Z": 0.0, "COMPASS_MOTCT": 2, "COMPASS_USE": 1, "MOT_PWM_MIN": 1000,
              "MOT_PWM_MAX": 2000}
    for i, c in enumerate(compasses):
        params.update({param_name(k, i): v for k, v in c.params.items()})
    lat = SITE["lat"] + np.degrees(tr.pos[:, 0] / EARTH_RADIUS_M)
    lon = SITE["lon"] + np.degrees(tr.pos[:, 1] / (EARTH_RADIUS_M * np.cos(np.radians(SITE["lat"]))))
    alt = SITE["alt"] - tr.pos[:, 2]
    with DataflashWriter(out, imu_instance=True, messages=FLIGHT_MESSAGES) as w:
        for name, value in params.items():
            w.parm(0, name, value)
        w.msg(0, FIRMWARE_TEXT)
        gps_every = max(1, int(round(rate_hz / 5)))
        slow_every = max(1, int(round(rate_hz / 10)))
        for k, t in enumerate(tr.t):
            us = int(round(t * 1e6)) + 1000
            w.imu(us, tr.gyr[k], tr.acc[k], 35.0)
            w._record("ATT", us, 0, _i16(np.degrees(roll_log[k]) * 100), 0,
                      _i16(np.degrees(pitch_log[k]) * 100), 0,
                      int(round((np.degrees(yaw_log[k]) % 360.0) * 100)) % 36000)
            for i, (mag, ofs, mo) in enumerate(logs):
                w._record("MAG", us, i, *(_i16_truncated(v) for v in (*mag[k], *ofs[k], *mo[k])),
                          1)
            if k % slow_every == 0:
                w._record("BAT", us, 0, 16.0, 16.0, float(tr.current[k]))
                pwm = int(round(1000 + 1000 * tr.throttle[k]))
                w._record("RCOU", us, pwm, pwm, pwm, pwm)
            if k % gps_every == 0:
                unix = START_UNIX + t
                gps_ms = int(round((unix - GPS_EPOCH_UNIX_S + GPS_MINUS_UTC_S) * 1000))
                week, ms = divmod(gps_ms, 604_800_000)
                v = tr.vel[k]
                course = np.degrees(np.arctan2(v[1], v[0])) % 360.0
                w._record("GPS", us, 0, 3, ms, week, 14, 80, int(round(lat[k] * 1e7)),
                          int(round(lon[k] * 1e7)), int(round(alt[k] * 100)),
                          float(np.hypot(v[0], v[1])), float(course), float(v[2]))
    truth = {"site": SITE, "start_unix": START_UNIX, "wmm_year": year,
             "earth_field_ned_mgauss": field_ned.tolist(), "rate_hz": rate_hz, "seed": seed,
             "yaw_bias_deg": yaw_bias_deg, "duration_s": float(tr.t[-1]),
             "current_range_a": [float(tr.current.min()), float(tr.current.max())],
             "compasses": [{"instance": i, "hard_iron": c.hard_iron, "soft_iron": c.soft_iron,
                            "interference_mgauss_per_a": c.interference,
                            "orient_phys": c.orient_phys, "in_force": c.params,
                            "ideal": c.ideal()} for i, c in enumerate(compasses)]}
    if truth_out:
        Path(truth_out).write_text(json.dumps(truth, indent=2) + "\n")
    return truth


def main(argv=None) -> int:
    """``python -m apmcal_sim.flight``: write one simulated flight log; the exit status."""
    ap = argparse.ArgumentParser(prog="python -m apmcal_sim.flight",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="output .bin")
    ap.add_argument("--truth-out", help="write the injected truth JSON here")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rate", type=float, default=25.0, help="ATT/MAG/IMU rate [Hz]")
    ap.add_argument("--orient-error", type=int, default=0,
                    help="rotation code compass 0 is really mounted with (COMPASS_ORIENT says 0)")
    ap.add_argument("--yaw-bias", type=float, default=8.0, help="logged yaw bias [deg]")
    ap.add_argument("--scale", type=float, default=1.0, help="stretch the legs (1: ~3 min)")
    args = ap.parse_args(argv)
    write_flight(args.out, args.truth_out, seed=args.seed, rate_hz=args.rate,
                 orient_error=args.orient_error, yaw_bias_deg=args.yaw_bias, scale=args.scale)
    return 0


if __name__ == "__main__":
    sys.exit(main())
