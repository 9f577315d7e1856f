"""What an in-flight compass fit needs from a dataflash log (.bin or text .log), as numpy arrays.

:func:`read_flight` decodes only the messages below with the fast dataflash scanners of
:mod:`apmcal.sources.dataflash` / :mod:`apmcal.sources.dataflash_text` (values as pymavlink's
DFReader gives them) and returns a :class:`FlightData`. Times are seconds on the log's boot
clock (TimeUS [µs] or TimeMS [ms]; the old GPS record's boot time is its ``T`` [ms]).

* ATT: roll, pitch, yaw [rad] of the body (FRD) relative to NED, Euler 321 (the EKF's: the yaw
  used the compass).
* GPS (first receiver, records with a 3D fix): lat, lon [deg], alt [m above mean sea level],
  ground speed [m/s], course over ground [rad], and the Unix time of boot when the log dates
  itself (:func:`apmcal.sources.gps_time.boot_to_unix_offset`).
* MAG / MAG2 / MAG3 or MAG with ``I``: per compass instance the logged CORRECTED body-frame
  field, the offsets in use (OfsX..Z) and the motor compensation in use (MOX..Z or MOfsX..Z),
  all mGauss (ardupilot-facts.md, "Dataflash logs (.bin)").
* BAT (first battery) or CURR: current [A] (the readers' own scaling,
  :func:`apmcal.sources.dataflash._current_amps`).
* Throttle 0..1: CTUN ThO / ThrOut (0..1 on 3.6+, 0..1000 on older logs), else the mean of
  RCOU C1..C4 (Ch1..4, Chan1..4) mapped by MOT_PWM_MIN/MAX (default 1000-2000 µs).
* IMU (first instance): gyro [rad/s, body] for the heading change between instants.
* PARM: the last value of every parameter; MSG: the firmware string.

A telemetry log (.tlog) gives the same from MAVLink (:func:`read_flight_tlog`): ATTITUDE;
GLOBAL_POSITION_INT for position, ground speed and course (its boot-clock time, not
GPS_RAW_INT's Unix one); SYSTEM_TIME for the boot clock's Unix time; RAW_IMU's corrected compass
(int16 mGauss, compass 0 only) and gyro [mrad/s]; SERVO_OUTPUT_RAW for the throttle;
PARAM_VALUE and STATUSTEXT. The offsets in use are the parameters' (the telemetry carries none of
its own), the motor compensation in use is not carried: taken as zero, with a note when
COMPASS_MOT is set; SYS_STATUS has no time stamp of its own, so no current.

Readers never fit: missing series are None and the caller decides.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.sources.gps_time import boot_to_unix_offset

FLIGHT_NAMES = ("ATT", "GPS", "MAG", "MAG2", "MAG3", "BAT", "CURR", "RCOU", "CTUN", "IMU",
                "PARM", "MSG")
MIN_FIX_STATUS = 3


@dataclass
class MagSeries:
    """One compass instance: t [s], field (n, 3) corrected body frame [mGauss] as logged,
    offsets (n, 3) and motor (n, 3) compensation in use [mGauss]."""

    instance: int
    t: np.ndarray
    field: np.ndarray
    offsets: np.ndarray
    motor: np.ndarray


@dataclass
class FlightData:
    """The series of one flight log (see the module docstring for units and frames)."""

    path: str
    params: dict[str, float] = field(default_factory=dict)
    firmware: str | None = None
    att_t: np.ndarray | None = None
    roll: np.ndarray | None = None          # [rad]
    pitch: np.ndarray | None = None         # [rad]
    yaw: np.ndarray | None = None           # [rad], the EKF's
    gps_t: np.ndarray | None = None
    lat: np.ndarray | None = None           # [deg]
    lon: np.ndarray | None = None           # [deg]
    alt: np.ndarray | None = None           # [m]
    speed: np.ndarray | None = None         # ground speed [m/s]
    course: np.ndarray | None = None        # course over ground [rad]
    boot_unix_s: float | None = None        # Unix time [s] of boot-clock 0
    mags: list[MagSeries] = field(default_factory=list)
    current_t: np.ndarray | None = None
    current: np.ndarray | None = None       # [A]
    throttle_t: np.ndarray | None = None
    throttle: np.ndarray | None = None      # 0..1
    gyr_t: np.ndarray | None = None
    gyr: np.ndarray | None = None           # (n, 3) [rad/s, body]
    notes: list[str] = field(default_factory=list)


def _time(cols: dict) -> np.ndarray | None:
    if "TimeUS" in cols:
        return np.asarray(cols["TimeUS"], np.float64) * 1e-6
    if "TimeMS" in cols:
        return np.asarray(cols["TimeMS"], np.float64) * 1e-3
    return None


def _first(cols: dict, *names):
    return next((np.asarray(cols[n]) for n in names if n in cols), None)


def _messages(path) -> dict:
    from apmcal.sources import sniff_format
    kind = sniff_format(path)
    want = FLIGHT_NAMES.__contains__
    if kind == "bin":
        from apmcal.sources.dataflash import read_bin_messages
        return read_bin_messages(path, want)[0]
    if kind == "log":
        from apmcal.sources._common import load_bytes
        from apmcal.sources.dataflash_text import parse_text
        return parse_text(load_bytes(path).tobytes(), want)[0]
    raise ApmcalError(f"a {kind} file: the flight compass fit reads dataflash logs", str(path))


def read_flight(path) -> FlightData:
    """Read the flight series of a dataflash .bin, text .log or telemetry .tlog (see the module
    docstring).

    Raises
    ------
    ApmcalError
        Unreadable file, or none of those formats.
    """
    from apmcal.sources import sniff_format

    if sniff_format(path) == "tlog":
        return read_flight_tlog(path)
    msgs = _messages(path)
    out = FlightData(path=str(path))
    parm = msgs.get("PARM", {})
    for name, value in zip(parm.get("Name", []), parm.get("Value", [])):
        out.params[str(name)] = float(value)
    for text in msgs.get("MSG", {}).get("Message", []):
        if out.firmware is None and ("Copter" in text or "Plane" in text or "Rover" in text
                                     or "Sub" in text) and " V" in text:
            out.firmware = str(text)
    _attitude(out, msgs.get("ATT", {}))
    _gps(out, msgs.get("GPS", {}))
    _mags(out, msgs)
    _current(out, msgs)
    _throttle(out, msgs)
    imu = msgs.get("IMU", {})
    t = _time(imu)
    if t is not None and all(c in imu for c in ("GyrX", "GyrY", "GyrZ")):
        sel = np.asarray(imu["I"]) == 0 if "I" in imu else np.ones(len(t), bool)
        out.gyr_t = t[sel]
        out.gyr = np.stack([np.asarray(imu[c], float)[sel] for c in ("GyrX", "GyrY", "GyrZ")], 1)
    return out


def _attitude(out: FlightData, att: dict) -> None:
    t = _time(att)
    if t is None or not {"Roll", "Pitch", "Yaw"} <= att.keys() or not len(t):
        return
    out.att_t = t
    out.roll, out.pitch, out.yaw = (np.radians(np.asarray(att[c], float))
                                    for c in ("Roll", "Pitch", "Yaw"))


def _gps(out: FlightData, gps: dict) -> None:
    if not gps or "Status" not in gps or "Lat" not in gps:
        return
    t = (np.asarray(gps["T"], float) * 1e-3 if "T" in gps and "TimeUS" not in gps
         else _time(gps))
    if t is None:
        return
    keep = np.asarray(gps["Status"]) >= MIN_FIX_STATUS
    if "I" in gps:
        keep &= np.asarray(gps["I"]) == 0
    lat = np.asarray(gps["Lat"], float)
    keep &= (lat != 0) | (np.asarray(gps["Lng"], float) != 0)
    if not keep.any():
        out.notes.append("GPS never had a 3D fix")
        return
    out.gps_t, out.lat, out.lon = t[keep], lat[keep], np.asarray(gps["Lng"], float)[keep]
    alt = _first(gps, "Alt")
    out.alt = alt.astype(float)[keep] if alt is not None else np.zeros(keep.sum())
    spd, crs = _first(gps, "Spd"), _first(gps, "GCrs")
    if spd is not None and crs is not None:
        out.speed, out.course = spd.astype(float)[keep], np.radians(crs.astype(float)[keep])
    out.boot_unix_s = boot_to_unix_offset(gps)


def _mags(out: FlightData, msgs: dict) -> None:
    for name in ("MAG", "MAG2", "MAG3"):
        cols = msgs.get(name)
        t = _time(cols or {})
        if t is None or not {"MagX", "MagY", "MagZ"} <= cols.keys():
            continue
        vec = {k: np.stack([np.asarray(cols[f"{k}{a}"], float) if f"{k}{a}" in cols
                            else np.zeros(len(t)) for a in "XYZ"], 1)
               for k in ("Mag", "Ofs")}
        mo = next((p for p in ("MO", "MOfs") if f"{p}X" in cols), None)
        motor = (np.stack([np.asarray(cols[f"{mo}{a}"], float) for a in "XYZ"], 1)
                 if mo else np.zeros((len(t), 3)))
        if "I" in cols:
            inst = np.asarray(cols["I"])
            for i in np.unique(inst):
                s = inst == i
                out.mags.append(MagSeries(int(i), t[s], vec["Mag"][s], vec["Ofs"][s], motor[s]))
        else:
            i = 0 if name == "MAG" else int(name[3]) - 1
            out.mags.append(MagSeries(i, t, vec["Mag"], vec["Ofs"], motor))
    out.mags.sort(key=lambda m: m.instance)


def _current(out: FlightData, msgs: dict) -> None:
    from apmcal.sources.dataflash import _battery_records
    rec = _battery_records(msgs)
    if rec is not None and np.any(rec[1] != 0) and np.all(np.diff(rec[0]) >= 0):
        out.current_t, out.current = rec[0], rec[1]


def _throttle(out: FlightData, msgs: dict) -> None:
    ctun = msgs.get("CTUN", {})
    thr, t = _first(ctun, "ThO", "ThrOut"), _time(ctun)
    if thr is not None and t is not None and len(t):
        thr = thr.astype(float)
        out.throttle_t = t
        out.throttle = thr / 1000.0 if np.nanmax(np.abs(thr)) > 1.5 else thr
        return
    rcou = msgs.get("RCOU", {})
    t = _time(rcou)
    chans = [next((rcou[f"{p}{k}"] for p in ("C", "Ch", "Chan") if f"{p}{k}" in rcou), None)
             for k in range(1, 5)]
    if t is None or any(c is None for c in chans):
        return
    lo = out.params.get("MOT_PWM_MIN", 0) or 1000.0
    hi = out.params.get("MOT_PWM_MAX", 0) or 2000.0
    pwm = np.mean(np.stack([np.asarray(c, float) for c in chans]), axis=0)
    out.throttle_t, out.throttle = t, np.clip((pwm - lo) / (hi - lo), 0.0, 1.0)


TLOG_NAMES = ("ATTITUDE", "GLOBAL_POSITION_INT", "SYSTEM_TIME", "RAW_IMU", "SERVO_OUTPUT_RAW",
              "PARAM_VALUE", "STATUSTEXT")


def _text(value) -> str:
    """A MAVLink char array as text (bytes up to the first NUL)."""
    if isinstance(value, bytes):
        value = value.split(b"\0", 1)[0].decode("ascii", "replace")
    return str(value)


def read_flight_tlog(path) -> FlightData:
    """Read the flight series of a telemetry log (.tlog; see the module docstring).

    Raises
    ------
    ApmcalError
        Unreadable or empty file.
    """
    from apmcal.sources.tlog import read_tlog_messages

    msgs = read_tlog_messages(path, TLOG_NAMES)[0]
    out = FlightData(path=str(path))
    pv = msgs.get("PARAM_VALUE")
    if pv is not None:
        for name, value in zip(pv["param_id"], pv["param_value"]):
            out.params[_text(name)] = float(value)
    st = msgs.get("STATUSTEXT")
    for text in ([] if st is None else (_text(t) for t in st["text"])):
        if out.firmware is None and " V" in text and any(
                v in text for v in ("Copter", "Plane", "Rover", "Sub")):
            out.firmware = text
    att = msgs.get("ATTITUDE")
    if att is not None and len(att):
        out.att_t = att["time_boot_ms"] * 1e-3
        out.roll, out.pitch, out.yaw = (att[c].astype(float) for c in ("roll", "pitch", "yaw"))
    _tlog_position(out, msgs.get("GLOBAL_POSITION_INT"), msgs.get("SYSTEM_TIME"))
    raw = msgs.get("RAW_IMU")
    if raw is not None and len(raw):
        t = raw["time_usec"] * 1e-6
        out.gyr_t = t
        out.gyr = np.stack([raw[c].astype(float) for c in ("xgyro", "ygyro", "zgyro")], 1) * 1e-3
        mag = np.stack([raw[c].astype(float) for c in ("xmag", "ymag", "zmag")], 1)
        if np.any(mag):
            ofs = np.array([out.params.get(f"COMPASS_OFS_{a}", 0.0) for a in "XYZ"])
            out.mags.append(MagSeries(0, t, mag, np.tile(ofs, (len(t), 1)), np.zeros((len(t), 3))))
            if any(out.params.get(f"COMPASS_MOT_{a}", 0.0) for a in "XYZ"):
                out.notes.append("the telemetry log does not carry the motor compensation in "
                                 "use: COMPASS_MOT is set, its effect is taken as zero")
    servo = msgs.get("SERVO_OUTPUT_RAW")
    if servo is not None and len(servo):
        lo = out.params.get("MOT_PWM_MIN", 0) or 1000.0
        hi = out.params.get("MOT_PWM_MAX", 0) or 2000.0
        pwm = np.mean(np.stack([servo[f"servo{k}_raw"].astype(float) for k in range(1, 5)]), 0)
        out.throttle_t = servo["time_usec"] * 1e-6
        out.throttle = np.clip((pwm - lo) / (hi - lo), 0.0, 1.0)
    return out


def _tlog_position(out: FlightData, pos, system_time) -> None:
    """Position, ground speed and course from GLOBAL_POSITION_INT (lat/lon 1e-7 deg, alt mm
    above mean sea level, vx/vy cm/s north/east), and the boot clock's Unix time from
    SYSTEM_TIME."""
    if pos is None or not len(pos):
        return
    keep = (pos["lat"] != 0) | (pos["lon"] != 0)
    if not keep.any():
        out.notes.append("no position in the telemetry log")
        return
    p = pos[keep]
    out.gps_t = p["time_boot_ms"] * 1e-3
    out.lat, out.lon = p["lat"] * 1e-7, p["lon"] * 1e-7
    out.alt = p["alt"] * 1e-3
    vn, ve = p["vx"] * 1e-2, p["vy"] * 1e-2
    out.speed, out.course = np.hypot(vn, ve), np.arctan2(ve, vn)
    if system_time is not None and len(system_time):
        st = system_time[system_time["time_unix_usec"] > 0]
        if len(st):
            out.boot_unix_s = float(np.median(st["time_unix_usec"] * 1e-6
                                              - st["time_boot_ms"] * 1e-3))
