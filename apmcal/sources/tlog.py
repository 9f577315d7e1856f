"""Fast reader for MAVLink telemetry logs (.tlog).

A .tlog is a sequence of frames: an 8-byte big-endian timestamp [µs since 1970] followed by one
MAVLink v1 (0xFE) or v2 (0xFD) packet. Framing and the CRC check (with the dialect's CRC_EXTRA)
run with numpy (an undamaged log up to 2 MB in one pass, :mod:`apmcal.sources._fastscan`, else
the resynchronising walkers of :mod:`apmcal.sources._tlogwalk`, which fall back on the chunked
``_framing`` scan only across damage); the wanted messages are then gathered into a
zero-padded (n, wire_length) byte array and decoded all at once through a numpy structured dtype
built from pymavlink's own message definition (same field order and types as pymavlink), so the
values are bit-identical to pymavlink's.

Damage: the messages read here (IMU, PARAM_VALUE, STATUSTEXT, HEARTBEAT, AUTOPILOT_VERSION,
SCALED_PRESSURE, SYS_STATUS) must pass the MAVLink CRC. Other messages are only framed (known
msgid, plausible length, next frame where expected; else their CRC decides), which saves the CRC
on most of the file. Bytes in no
valid frame are skipped one at a time until framing resumes and are counted in
``LogContents.bytes_skipped``. Signed MAVLink 2 packets are framed (13-byte signature) but the
signature is not verified (the key is unknown to a log reader).

Units (ardupilot-facts.md, "What the telemetry really carries"):
RAW_IMU / SCALED_IMU / SCALED_IMU2 / SCALED_IMU3: acc [mG] → m/s² (× 9.80665/1000), gyro
[mrad/s] → rad/s, mag [mGauss] as is, temperature [cdegC] → °C. HIGHRES_IMU: SI floats, mag
[Gauss] → mGauss. Time comes from the message (time_usec [µs] or time_boot_ms [ms]) in s.

Temperature: an integer IMU message without its own (RAW_IMU on APM 2.x firmware carries none)
gets the barometer's SCALED_PRESSURE temperature [cdegC → °C], linearly interpolated to its sample
times on the common boot clock (NaN outside the barometer's samples), with a note saying so: on
an APM 2.8 the barometer sits on the same board and is its only temperature sensor.

Battery current: the autopilot's SYS_STATUS.current_battery [cA → A; -1 = not measured, MAVLink
common.xml SYS_STATUS] becomes the optional column ``current`` [A], linearly interpolated to the
sample times (NaN outside the SYS_STATUS span). SYS_STATUS carries no vehicle time, so its
frames' ground-station timestamps are mapped onto each recording's boot clock with the
recording's own messages: the offset is the median of (tlog timestamp − boot time) over them
(over every k-th of them when there are more than :data:`CLOCK_SAMPLES`, which keeps the cost
small on big files).
Nothing is attached, with a note, when that offset is unstable (its 5th..95th percentile spread
exceeds :data:`MAX_CLOCK_SPREAD_S`: a ground station that buffers telemetry stamps it late by
varying amounts), when a clock jumps back (a reboot), when the spans do not overlap, or when the
current is -1 or 0 throughout (no current sensor).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pandas as pd
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from apmcal.core.constants import GAUSS_TO_MGAUSS, MG_TO_MS2, MRAD_TO_RAD
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import LogContents
from apmcal.sources import _fastscan, _tlogwalk
from apmcal.sources._common import (
    MAX_DAMAGE_OFFSETS,
    _params,
    add_recording,
    attach_current,
    cstr,
    current_series,
    finish,
    load_bytes,
    note_current,
    param_changes,
    parse_firmware,
    struct_dtype,
)

IMU_MESSAGES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
META_MESSAGES = ("PARAM_VALUE", "STATUSTEXT", "HEARTBEAT", "AUTOPILOT_VERSION",
                 "SCALED_PRESSURE", "SYS_STATUS")
_SCALED_INSTANCE = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
_CHUNK = 1 << 20          # index entries per scan call (bounds index memory)

# MAV_TYPE → ArduPilot vehicle, used only when no boot banner names the firmware
_MAV_TYPE_VEHICLE = {1: "ArduPlane", 2: "ArduCopter", 3: "ArduCopter", 4: "ArduCopter",
                     7: "Blimp", 10: "Rover", 11: "Rover", 12: "ArduSub", 13: "ArduCopter",
                     14: "ArduCopter", 15: "ArduCopter", 16: "ArduPlane", 19: "ArduPlane",
                     20: "ArduPlane", 21: "ArduPlane", 22: "ArduPlane", 23: "ArduPlane",
                     24: "ArduPlane", 25: "ArduPlane", 29: "ArduCopter", 5: "AntennaTracker"}
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_INVALID = 8          # ground stations, gimbals, companion computers

# SYS_STATUS.current_battery: int16 [cA], -1 when "current not sent by autopilot" (MAVLink
# common.xml, message SYS_STATUS, field current_battery, units="cA" invalid="-1")
CURRENT_NOT_MEASURED = -1
CA_TO_A = 0.01
# largest 5th..95th percentile spread of (tlog timestamp − boot time) [s] accepted for mapping
# SYS_STATUS onto the boot clock; a real USB session (ardusub_small.tlog) spreads 0.02 s
MAX_CLOCK_SPREAD_S = 0.5
CLOCK_PERCENTILES = (5.0, 50.0, 95.0)        # spread from the outer two, offset the median
CLOCK_SAMPLES = 1 << 16      # at most this many evenly spaced messages estimate the offset


@lru_cache(maxsize=1)
def _tables():
    """(crc_extra int16[65536], full payload length int16[65536], name → (msgid, class)).

    From pymavlink's ardupilotmega dialect; msgids ≥ 65536 are treated as unknown.
    """
    crc = np.full(1 << 16, -1, dtype=np.int16)
    max_len = np.zeros(1 << 16, dtype=np.int16)
    by_name = {}
    for msgid, cls in mavlink.mavlink_map.items():
        if msgid < crc.shape[0]:
            crc[msgid] = cls.crc_extra
            max_len[msgid] = cls.unpacker.size
        by_name[cls.msgname] = (msgid, cls)
    return crc, max_len, by_name


def message_dtype(name: str) -> tuple[int, np.dtype]:
    """(msgid, packed dtype of the full MAVLink 2 wire payload) of message ``name``."""
    msgid, cls = _tables()[2][name]
    return msgid, struct_dtype(list(cls.ordered_fieldnames), cls.unpacker.format)


# undamaged .tlog files up to this size are framed in one pass (_fastscan), bigger ones by the
# walkers, which are faster from a few MB on (``python benchmarks/readers.py --framing FILE``)
ONE_PASS_MAX_BYTES = 2 << 20


def _index(buf: np.ndarray, wanted: np.ndarray):
    """Frame offsets, payload lengths and msgids of wanted frames; bytes skipped; damage."""
    crc, max_len, _ = _tables()
    if buf.shape[0] <= ONE_PASS_MAX_BYTES:
        fast = _fastscan.scan_tlog(buf, crc, max_len, wanted)
        if fast is not None:        # undamaged: one vectorised pass
            return (*fast, 0, [])
    (off, ln, mid), skipped, damage = _tlogwalk.scan_tlog(buf, crc, max_len, wanted,
                                                          MAX_DAMAGE_OFFSETS)
    return off, ln, mid, skipped, damage


def _header_len(buf: np.ndarray, off: np.ndarray) -> np.ndarray:
    """MAVLink header length (6 for v1, 10 for v2) of the frames starting at ``off``."""
    return np.where(buf[off + 8] == _fastscan.MAV1_MAGIC, 6, 10)


def frame_spans(buf: np.ndarray, names=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(start, end, msgid) of every valid frame (of messages ``names``, or all), file order.

    ``start`` is the offset of the 8-byte timestamp, ``end`` one past the last packet byte
    (CRC and, for signed MAVLink 2 packets, the 13-byte signature).

    Parameters
    ----------
    buf : numpy.ndarray of uint8
        The whole file (may be a memmap).
    names : iterable of str, optional
        MAVLink message names; all messages when None.

    Returns
    -------
    start, end : numpy.ndarray of int64, shape (k,)
        Byte offsets, half-open.
    msgid : numpy.ndarray of int32, shape (k,)
    """
    wanted = np.zeros(1 << 16, dtype=np.bool_)
    if names is None:
        wanted[:] = True
    else:
        for nm in names:
            wanted[message_dtype(nm)[0]] = True
    off, ln, mid, _, _ = _index(buf, wanted)
    hlen = _header_len(buf, off)
    signed = (hlen == 10) & ((buf[np.minimum(off + 10, buf.shape[0] - 1)] & 1) == 1)
    end = off + 8 + hlen + ln + 2 + np.where(signed, 13, 0)
    return off, end, mid


def scan(buf: np.ndarray, names) -> tuple[dict[str, np.ndarray], int, list[int]]:
    """Frame the whole buffer; decode every message of ``names``.

    Returns
    -------
    decoded : dict of str to numpy.ndarray
        name → structured array of that message's fields (pymavlink field names), one row per
        frame.
    bytes_skipped : int
        Bytes that were not part of a valid frame.
    damaged_at : list of int
        Byte offsets where skipped runs begin (at most MAX_DAMAGE_OFFSETS).
    """
    decoded, skipped, damaged, _ = _scan(buf, names)
    return decoded, skipped, damaged


def _scan(buf: np.ndarray, names):
    """:func:`scan` plus name → byte offset of each decoded frame (same order as its rows)."""
    wanted = np.zeros(1 << 16, dtype=np.bool_)
    ids = {}
    for nm in names:
        msgid, dt = message_dtype(nm)
        wanted[msgid] = True
        ids[msgid] = (nm, dt)
    off, ln, mid, skipped, damaged = _index(buf, wanted)
    payload = off + 8 + _header_len(buf, off)
    order = np.argsort(mid.astype(np.uint16), kind="stable")   # a radix sort; file order kept
    ids_sorted = mid[order]
    decoded, offsets = {}, {}
    for msgid, (nm, dt) in ids.items():
        lo, hi = np.searchsorted(ids_sorted, [msgid, msgid + 1])
        sel = order[lo:hi]
        rows = _fastscan.gather(buf, payload[sel], ln[sel], dt.itemsize)
        decoded[nm] = rows.view(dt).reshape(-1)
        offsets[nm] = off[sel]
    return decoded, skipped, damaged, offsets


def _int_imu_frame(a: np.ndarray, time_field: str, time_scale: float) -> pd.DataFrame:
    """RAW_IMU / SCALED_IMU* integer fields to SI columns."""
    df = pd.DataFrame({
        "t": a[time_field].astype(np.float64) * time_scale,
        "acc_x": a["xacc"] * MG_TO_MS2, "acc_y": a["yacc"] * MG_TO_MS2,
        "acc_z": a["zacc"] * MG_TO_MS2,
        "gyr_x": a["xgyro"] * MRAD_TO_RAD, "gyr_y": a["ygyro"] * MRAD_TO_RAD,
        "gyr_z": a["zgyro"] * MRAD_TO_RAD,
        "mag_x": a["xmag"].astype(np.float64), "mag_y": a["ymag"].astype(np.float64),
        "mag_z": a["zmag"].astype(np.float64),
    })
    temp = a["temperature"]
    if temp.any():  # extension field absent (zero-padded) or not filled → no temp column
        df["temp"] = np.where(temp != 0, temp * 0.01, np.nan)
    return df


def _highres_frame(a: np.ndarray) -> pd.DataFrame:
    """HIGHRES_IMU float fields (already SI; mag Gauss → mGauss)."""
    f64 = lambda k: a[k].astype(np.float64)  # noqa: E731
    return pd.DataFrame({
        "t": a["time_usec"].astype(np.float64) * 1e-6,
        "acc_x": f64("xacc"), "acc_y": f64("yacc"), "acc_z": f64("zacc"),
        "gyr_x": f64("xgyro"), "gyr_y": f64("ygyro"), "gyr_z": f64("zgyro"),
        "mag_x": f64("xmag") * GAUSS_TO_MGAUSS, "mag_y": f64("ymag") * GAUSS_TO_MGAUSS,
        "mag_z": f64("zmag") * GAUSS_TO_MGAUSS, "temp": f64("temperature"),
    })


def _imu_recordings(out: LogContents, dec: dict[str, np.ndarray], buf: np.ndarray,
                    offsets: dict[str, np.ndarray], current) -> None:
    """One Recording per (message, instance) from the decoded IMU messages.

    ``current``: (ground-station time [s since 1970], current [A]) of SYS_STATUS from
    :func:`_sys_status_current`, or None; ``offsets`` (frame offsets of each IMU message) is
    read only when it is not None.
    """
    for name in IMU_MESSAGES:
        a = dec.get(name)
        if a is None or len(a) == 0:
            continue
        if name in _SCALED_INSTANCE:
            groups = {_SCALED_INSTANCE[name]: slice(None)}
        else:  # RAW_IMU / HIGHRES_IMU carry an instance "id" (extension, 0 when absent)
            ids = np.unique(a["id"])
            groups = ({int(ids[0]): slice(None)} if len(ids) == 1
                      else {int(i): a["id"] == i for i in ids})
        for inst, sel in groups.items():
            g = a[sel]
            if name == "HIGHRES_IMU":
                df = _highres_frame(g)
            elif name == "RAW_IMU":
                df = _int_imu_frame(g, "time_usec", 1e-6)
            else:
                df = _int_imu_frame(g, "time_boot_ms", 1e-3)
            if "temp" not in df.columns and name != "HIGHRES_IMU":
                _attach_baro_temperature(out, df, dec.get("SCALED_PRESSURE"), f"{name}[{inst}]")
            if current is not None:
                pick = _clock_sample(len(df))
                _attach_sys_status_current(out, df, pick,
                                           _frame_unix_s(buf, offsets[name][sel][pick]),
                                           current, f"{name}[{inst}]")
            add_recording(out, df, name, inst)


def _attach_baro_temperature(out: LogContents, df: pd.DataFrame, baro, label: str) -> None:
    """Add SCALED_PRESSURE's temperature [°C] to ``df`` as ``temp`` (see the module docstring)."""
    if baro is None or len(baro) < 2 or not baro["temperature"].any():
        return
    t_baro = baro["time_boot_ms"].astype(np.float64) * 1e-3
    t = df["t"].to_numpy()
    if np.any(np.diff(t_baro) < 0) or np.any(np.diff(t) < 0):
        # a reboot restarts both clocks: a time no longer says which boot a sample is from
        out.messages.append(f"note: {label}: the clock jumps back (a reboot?); no barometer "
                            "temperature attached")
        return
    keep = np.flatnonzero(np.diff(t_baro, prepend=-np.inf) > 0)   # np.interp: no repeats
    t_baro, temp = t_baro[keep], baro["temperature"][keep].astype(np.float64) * 0.01
    inside = (t >= t_baro[0]) & (t <= t_baro[-1])
    if not inside.any():     # another clock (a log spliced after a reboot): no common time
        out.messages.append(f"note: {label} and SCALED_PRESSURE share no time span; "
                            "no temperature attached")
        return
    df["temp"] = np.where(inside, np.interp(t, t_baro, temp), np.nan)
    out.messages.append(f"note: {label} temp is the barometer's (SCALED_PRESSURE), interpolated "
                        "to the sample times")


def _clock_sample(n: int) -> slice:
    """Every k-th of ``n`` messages, k the smallest step leaving at most CLOCK_SAMPLES."""
    return slice(None, None, max(-(-n // CLOCK_SAMPLES), 1))


def _frame_unix_s(buf: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Ground-station time [s since 1970] of the frames starting at ``off``: their 8-byte
    big-endian µs timestamp (pymavlink mavlogfile: ``tusec * 1.0e-6``, the same float).

    Read through a view of the buffer as a big-endian uint64 starting at every byte (stride
    1), so one vectorised gather fetches them all (twice as fast as copying 8-byte rows).
    """
    every_byte = np.ndarray(shape=(max(buf.shape[0] - 7, 0),), dtype=">u8", buffer=buf,
                            strides=(1,))
    return every_byte[off].astype(np.float64) * 1e-6


def _sys_status_current(out: LogContents, buf: np.ndarray, dec: dict[str, np.ndarray],
                        offsets: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """The autopilot's battery current: (ground-station time [s since 1970], current [A]).

    From the SYS_STATUS of the autopilot (:func:`_autopilot_source`; all of them when the log
    has no autopilot HEARTBEAT), without the records whose ``current_battery`` is -1 (not
    measured), cA → A. None when there is no usable record: a note says why, except for a log
    without SYS_STATUS (see :func:`apmcal.sources._common.current_series` for the other cases).
    """
    ss, off = dec["SYS_STATUS"], offsets["SYS_STATUS"]
    source = _autopilot_source(buf, dec, offsets)
    if source is not None and len(ss):
        mine = _frame_sources(buf, off) == source
        if not mine.all():
            out.messages.append(f"note: {int(np.sum(~mine))} SYS_STATUS from components other "
                                f"than the autopilot ({source >> 8}/{source & 255}) ignored")
            ss, off = ss[mine], off[mine]
    if len(ss) == 0:
        return None
    measured = ss["current_battery"] != CURRENT_NOT_MEASURED
    if not measured.any():
        out.messages.append("note: SYS_STATUS current_battery is -1 (not measured) in every "
                            "record; no current column")
        return None
    amps = ss["current_battery"][measured].astype(np.float64) * CA_TO_A
    return current_series(_frame_unix_s(buf, off[measured]), amps,
                          "SYS_STATUS current_battery", out)


def _boot_clock_offset(out: LogContents, t: np.ndarray, unix_s: np.ndarray,
                       label: str) -> float | None:
    """Ground-station time minus boot time [s] for one recording, or None with a note.

    Parameters
    ----------
    t : sample times of the recording's messages on the vehicle's boot clock [s] (all of them,
        or the :func:`_clock_sample` of them).
    unix_s : the ground-station timestamps of the same messages [s since 1970].

    The offset is the median of ``unix_s - t`` (telemetry latency only delays the stamps, so
    the median is robust to late bursts). None when either clock jumps back (a reboot, or a
    ground-station clock set back) or when the 5th..95th percentile spread of the differences
    exceeds :data:`MAX_CLOCK_SPREAD_S` (buffered telemetry: a SYS_STATUS stamp no longer tells
    its boot time).
    """
    if np.any(np.diff(t) < 0) or np.any(np.diff(unix_s) < 0):
        out.messages.append(f"note: {label}: a clock jumps back (a reboot?); no SYS_STATUS "
                            "current attached")
        return None
    d = unix_s - t
    lo, median, hi = np.percentile(d, CLOCK_PERCENTILES)     # one partition for all three
    if hi - lo > MAX_CLOCK_SPREAD_S:
        out.messages.append(f"note: {label}: tlog time minus boot time varies by {hi - lo:.2f} s "
                            f"(5th..95th percentile; more than {MAX_CLOCK_SPREAD_S} s: buffered "
                            "telemetry?); no SYS_STATUS current attached")
        return None
    return float(median)


def _attach_sys_status_current(out: LogContents, df: pd.DataFrame, pick: slice,
                               unix_s: np.ndarray, current: tuple[np.ndarray, np.ndarray],
                               label: str) -> None:
    """Add the SYS_STATUS current [A] to ``df`` as ``current`` (see the module docstring).

    ``unix_s``: ground-station timestamps [s since 1970] of the messages of ``df``'s rows
    ``pick`` (:func:`_clock_sample`).
    """
    offset = _boot_clock_offset(out, df["t"].to_numpy()[pick], unix_s, label)
    if offset is not None:
        attach_current(out, df, current[0] - offset, current[1], label, "SYS_STATUS")


def _frame_sources(buf: np.ndarray, off: np.ndarray) -> np.ndarray:
    """(system id << 8 | component id) of the frames starting at ``off`` (the timestamp).

    One 64-bit read per frame (the 8 bytes after the stamp, inside every complete frame):
    system and component id are its bytes 3-4 (MAVLink 1) or 5-6 (MAVLink 2).
    """
    words = np.ndarray(shape=(max(buf.shape[0] - 7, 0),), dtype="<u8", buffer=buf, strides=(1,))
    w = words[off + 8]
    pair = np.where((w & 0xFF) == _fastscan.MAV1_MAGIC, w >> 24, w >> 40) & 0xFFFF
    return (((pair & 0xFF) << 8) | (pair >> 8)).astype(np.int32)


def _autopilot_source(buf: np.ndarray, dec: dict[str, np.ndarray],
                      offsets: dict[str, np.ndarray]) -> int | None:
    """(system id << 8 | component id) of the first HEARTBEAT whose autopilot is not
    MAV_AUTOPILOT_INVALID, or None when there is no such HEARTBEAT."""
    autopilots = np.flatnonzero(dec["HEARTBEAT"]["autopilot"] != MAV_AUTOPILOT_INVALID)
    if len(autopilots) == 0:
        return None
    return int(_frame_sources(buf, offsets["HEARTBEAT"][autopilots[:1]])[0])


def _keep_autopilot_params(out: LogContents, buf: np.ndarray, dec: dict[str, np.ndarray],
                           offsets: dict[str, np.ndarray]) -> None:
    """Keep only the autopilot's PARAM_VALUEs (:func:`_autopilot_source`); a gimbal's or
    companion computer's own parameter list is not the vehicle's. Without an autopilot
    HEARTBEAT every PARAM_VALUE is kept."""
    pv = dec["PARAM_VALUE"]
    source = _autopilot_source(buf, dec, offsets)
    if source is None or len(pv) == 0:
        return
    mine = _frame_sources(buf, offsets["PARAM_VALUE"]) == source
    if not mine.all():
        out.messages.append(f"note: {int(np.sum(~mine))} PARAM_VALUE from components other than "
                            f"the autopilot ({source >> 8}/{source & 255}) ignored")
        dec["PARAM_VALUE"], offsets["PARAM_VALUE"] = pv[mine], offsets["PARAM_VALUE"][mine]


_MIX = np.uint64(0x9E3779B97F4A7C15)       # odd 64-bit constant (Fibonacci hashing)


def _last_per_name(names: np.ndarray) -> np.ndarray:
    """Sorted indices of the last row of each distinct 16-byte ``param_id``.

    What ``_common._params`` keeps of a parameter list repeated many times, found faster:
    each name's two 64-bit words are mixed into one key and the keys sorted as integers
    (``np.unique`` on the names themselves sorts 16-byte strings, the slower part of reading
    a big .tlog). A key shared by two different names (a hash collision) is detected and the
    names are then compared as strings.
    """
    if names.dtype.itemsize != 16 or len(names) == 0:
        _, first = np.unique(names[::-1], return_index=True)
        return np.sort(len(names) - 1 - first)
    words = np.ascontiguousarray(names).view("<u8").reshape(-1, 2)
    key = words[:, 0] ^ (words[:, 1] * _MIX)
    _, first, inverse = np.unique(key[::-1], return_index=True, return_inverse=True)
    rep = len(names) - 1 - first
    if not np.array_equal(names[rep[inverse]][::-1], names):     # a collision
        _, first = np.unique(names[::-1], return_index=True)
        rep = len(names) - 1 - first
    return np.sort(rep)


def _metadata(out: LogContents, dec: dict[str, np.ndarray]) -> None:
    """Parameters, STATUSTEXT messages, vehicle and firmware."""
    pv = dec["PARAM_VALUE"]
    names, values = pv["param_id"], pv["param_value"]
    if np.isfinite(values).all():       # the same params, in the same order, from fewer rows
        last = _last_per_name(names)
        names, values = names[last], values[last]
    _params(out, names, values, "PARAM_VALUE")
    for s in dec["STATUSTEXT"]:
        text = cstr(s["text"])
        out.messages.append(text)
        fw = parse_firmware(text)
        if fw and out.firmware is None:
            out.vehicle, out.firmware = fw
    if out.vehicle is None:
        hb = dec["HEARTBEAT"]
        hb = hb[hb["autopilot"] == MAV_AUTOPILOT_ARDUPILOTMEGA]
        if len(hb):
            types, counts = np.unique(hb["type"], return_counts=True)
            out.vehicle = _MAV_TYPE_VEHICLE.get(int(types[np.argmax(counts)]))
    av = dec["AUTOPILOT_VERSION"]
    if out.firmware is None and len(av) and out.vehicle:
        v = int(av["flight_sw_version"][-1])  # major<<24 | minor<<16 | patch<<8 | type
        out.firmware = f"{out.vehicle} V{(v >> 24) & 255}.{(v >> 16) & 255}.{(v >> 8) & 255}"


def _imu_time_s(name: str, row) -> float:
    """Time [s] of one decoded IMU message, as in its recording's ``t`` column."""
    if name in ("RAW_IMU", "HIGHRES_IMU"):
        return float(row["time_usec"]) * 1e-6
    return float(row["time_boot_ms"]) * 1e-3


def _param_changes(out: LogContents, dec: dict[str, np.ndarray],
                   offsets: dict[str, np.ndarray]) -> None:
    """Calibration PARAM_VALUEs that change value after the first IMU message.

    PARAM_VALUE carries no vehicle time; ``time_s`` is that of the last IMU message before it
    (the new value applies from the next sample on), on the recordings' time axis.
    """
    firsts = [int(offsets[n][0]) for n in IMU_MESSAGES if len(offsets.get(n, ()))]
    pv = dec["PARAM_VALUE"]
    pos = offsets["PARAM_VALUE"]

    def describe(i):
        p, best = int(pos[i]), (-1, None)
        for n in IMU_MESSAGES:
            o = offsets.get(n)
            j = int(np.searchsorted(o, p)) - 1 if o is not None and len(o) else -1
            if j >= 0 and o[j] > best[0]:
                best = (int(o[j]), _imu_time_s(n, dec[n][j]))
        return best[1], f"PARAM_VALUE at byte {p}"

    out.param_changes = param_changes(pv["param_id"], pv["param_value"], pos,
                                      min(firsts) if firsts else None, describe)


# a .tlog timestamp outside these years is a clock never set (or damage), not a date
PLAUSIBLE_UNIX_S = (946684800.0, 4102444800.0)      # 2000-01-01 .. 2100-01-01 UTC


def _wall_clock_start(buf: np.ndarray, offsets: dict[str, np.ndarray]) -> float | None:
    """The ground station's clock [s since 1970] at the first decoded frame, if plausible.

    Every .tlog frame is preceded by the 8-byte big-endian time [µs since 1970] at which the
    ground station logged it (pymavlink mavlogfile); ``offsets`` point at those 8 bytes.
    """
    starts = [int(o[0]) for o in offsets.values() if len(o)]
    if not starts:
        return None
    first = min(starts)
    unix_s = int.from_bytes(buf[first:first + 8].tobytes(), "big") * 1e-6
    return unix_s if PLAUSIBLE_UNIX_S[0] <= unix_s < PLAUSIBLE_UNIX_S[1] else None


def read_tlog_messages(path, names=IMU_MESSAGES) -> tuple[dict[str, np.ndarray], int, list[int]]:
    """Decode all messages ``names`` of a .tlog into structured arrays (raw MAVLink fields).

    Field values are exactly pymavlink's (same wire layout). See :func:`scan` for the return.

    Raises
    ------
    ApmcalError
        Unreadable or empty file.
    """
    buf = load_bytes(path)
    return scan(buf, names)


def autopilot_system_id(path) -> int | None:
    """The autopilot's MAVLink system id in a .tlog: the frame header of its first HEARTBEAT
    whose autopilot is not MAV_AUTOPILOT_INVALID (:func:`_autopilot_source`, the source whose
    parameters :func:`read_tlog` keeps); None without such a HEARTBEAT.

    Every frame carries its sender's system id, so this names the vehicle even when the log
    holds none of its parameters. Reads only the HEARTBEAT frames (a second, cheap pass).

    Raises
    ------
    ApmcalError
        Unreadable or empty file.
    """
    buf = load_bytes(path)
    dec, _, _, offsets = _scan(buf, ("HEARTBEAT",))
    source = _autopilot_source(buf, dec, offsets)
    return None if source is None else source >> 8


def read_tlog(path, *, progress: bool = False) -> LogContents:
    """Read a .tlog into a :class:`LogContents` (IMU recordings, params, firmware, messages).

    Raises
    ------
    ApmcalError
        Unreadable or empty file, no valid MAVLink frame, or no IMU message.
    """
    buf = load_bytes(path)
    dec, skipped, damaged, offsets = _scan(buf, IMU_MESSAGES + META_MESSAGES)
    out = LogContents(path=str(path), format="tlog", bytes_skipped=skipped, damaged_at=damaged)
    if skipped == buf.shape[0]:
        raise ApmcalError("no valid MAVLink frame in the file", str(path), "byte 0")
    _keep_autopilot_params(out, buf, dec, offsets)
    _metadata(out, dec)
    _param_changes(out, dec, offsets)
    out.start_unix_s = _wall_clock_start(buf, offsets)
    current = _sys_status_current(out, buf, dec, offsets)
    imu_offsets = {n: offsets[n] for n in IMU_MESSAGES} if current is not None else {}
    del offsets
    _imu_recordings(out, dec, buf, imu_offsets, current)
    if current is not None:
        note_current(out, "SYS_STATUS current_battery (its tlog timestamps mapped onto the "
                          "boot clock)")
    found = [k for k, v in dec.items() if len(v)]
    return finish(out, found)
