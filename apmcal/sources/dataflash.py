"""Fast reader for ArduPilot dataflash binary logs (.bin).

A dataflash log is a stream of records ``0xA3 0x95 type body``; FMT records (type 0x80) give each
type its name, length, field formats and column names. The record boundaries are found in one pass
(numpy throughout: ``_fastscan`` for an undamaged log, else the resynchronising
``_framing.scan_dataflash``), then all records of
one type are gathered and decoded at once with a numpy structured dtype. Format-character
multipliers (c, C, e, E: 0.01; L: 1e-7) are applied the way pymavlink's DFReader does (division by
``1/mul``), so values are identical to DFReader's.

Recordings built (shared with the text reader, :func:`build_contents`):
IMU / IMU2 / IMU3 (instance 0/1/2, or per ``I`` column) → acc, gyr, temp (T or Temp) columns;
ACC / ACCn and GYR / GYRn (per-sample sensor messages, time from TimeUS) → their own
acc-only / gyr-only recordings; MAG / MAG2 / MAG3 (or per ``I``) → separate recordings with message "MAG",
"MAG2"... holding only mag columns [mGauss]. Time: TimeUS [µs] or TimeMS [ms] → s.
All are corrected and body frame (ardupilot-facts.md, "Dataflash logs").

Battery current: the first battery's current (BAT, or CURR on Copter 3.x; see
:func:`_battery_records`) is linearly interpolated to every recording's sample times as the
optional column ``current`` [A] (NaN outside the records' span); no column, with a note, when it
is zero in every record (no current sensor fitted) or the clock jumps back.

PARM records give ``params`` (last value) and ``param_changes``: calibration parameters whose
value changes after the first sensor record (normally all PARM records come at the start).
"""
from __future__ import annotations

import re
from functools import partial

import numpy as np
import pandas as pd

from apmcal.core.errors import ApmcalError
from apmcal.core.recording import ACC, GYR, MAG, LogContents
from apmcal.sources import _fastscan, _framing
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
)
from apmcal.sources.gps_time import GPS_TIME_COLUMNS, boot_to_unix_offset

# DFReader's FORMAT_TO_STRUCT: format char → (numpy dtype, multiplier)
DF_FORMATS = {
    "a": ("(32,)<i2", None), "b": ("i1", None), "B": ("u1", None), "g": ("<f2", None),
    "h": ("<i2", None), "H": ("<u2", None), "i": ("<i4", None), "I": ("<u4", None),
    "f": ("<f4", None), "n": ("S4", None), "N": ("S16", None), "Z": ("S64", None),
    "c": ("<i2", 0.01), "C": ("<u2", 0.01), "e": ("<i4", 0.01), "E": ("<u4", 0.01),
    "L": ("<i4", 1.0e-7), "d": ("<f8", None), "M": ("i1", None), "q": ("<i8", None),
    "Q": ("<u8", None),
}

IMU_RE = re.compile(r"^(IMU|ACC|GYR|MAG)(\d?)$")
CURRENT_NAMES = ("BAT", "CURR")      # battery monitor messages, newer first (_battery_records)
META_NAMES = ("PARM", "MSG", "GPS") + CURRENT_NAMES
_CHUNK = 1 << 20
_FMT_DTYPE = np.dtype([("Type", "u1"), ("Length", "u1"), ("Name", "S4"), ("Format", "S16"),
                       ("Columns", "S64")])


def fmt_dtype(fmt: str, columns: list[str]) -> np.dtype:
    """Packed numpy dtype of a record body with dataflash format string ``fmt``."""
    if len(fmt) != len(columns):
        raise ValueError(f"format {fmt!r} has {len(fmt)} fields but {len(columns)} columns")
    fields = []
    for c, name in zip(fmt, columns):
        dt = DF_FORMATS[c][0]
        fields.append((name, dt[5:], (32,)) if dt.startswith("(32,)") else (name, dt))
    return np.dtype(fields)


def convert_column(values: np.ndarray, fmt_char: str) -> np.ndarray:
    """Apply DFReader's value conversion to one decoded column.

    Multipliers below 1 are applied as a division by ``1/mul`` (DFReader does the same for
    floating-point accuracy); floats become float64 (Python floats), strings str.

    Parameters
    ----------
    values : numpy.ndarray, shape (m,)
        One column as stored (the record's struct type).
    fmt_char : str
        Its dataflash format character (a key of ``DF_FORMATS``).

    Returns
    -------
    numpy.ndarray, shape (m,)
        The values DFReader would return (scaled float64, int, or str objects).
    """
    mul = DF_FORMATS[fmt_char][1]
    if mul is not None:
        return values.astype(np.float64) / (1 / mul)
    if values.dtype.kind == "f":
        return values.astype(np.float64)
    if values.dtype.kind == "S":
        return np.array([cstr(v) for v in values], dtype=object)
    return values


def scan(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, list[int]]:
    """Record offsets and types of a whole .bin buffer, bytes skipped, damage offsets.

    An undamaged log up to 32 MB is framed in one vectorised pass (:mod:`apmcal.sources._fastscan`);
    a bigger one or one that needs resynchronising by the chunked scan of
    :mod:`apmcal.sources._framing` (numpy too, bounded memory).

    Parameters
    ----------
    buf : numpy.ndarray of uint8
        The whole file (may be a memmap).

    Returns
    -------
    off : numpy.ndarray of int64, shape (k,)
        Byte offset of each accepted record.
    typ : numpy.ndarray of uint8, shape (k,)
        Its type.
    bytes_skipped : int
    damaged_at : list of int
        Byte offsets where skipped runs begin (at most ``MAX_DAMAGE_OFFSETS``).
    """
    fast = _fastscan.scan_dataflash(buf)
    if fast is not None:
        return fast[0], fast[1], 0, []
    return _framing.scan_dataflash(buf, MAX_DAMAGE_OFFSETS)


def record_spans(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(start, end, name) of every record the scan accepts, in file order.

    Returns
    -------
    start, end : numpy.ndarray of int64, shape (k,)
        Byte offsets, half-open.
    name : numpy.ndarray of object, shape (k,)
        Record name ("FMT", "IMU", ...; "" for a type without FMT record).
    """
    off, typ, _, _ = scan(buf)
    length = np.zeros(256, np.int64)
    names = np.full(256, "", dtype=object)
    length[_fastscan.DF_FMT_TYPE], names[_fastscan.DF_FMT_TYPE] = _fastscan.DF_FMT_LEN, "FMT"
    for _, t, ln, name, _, _ in _format_segments(buf, off, typ):
        length[t], names[t] = ln, name
    return off, off + length[typ], names[typ]


def _format_segments(buf, off, typ):
    """FMT definitions in file order: list of (record index, type, length, name, fmt, columns)."""
    idx = np.flatnonzero(typ == _fastscan.DF_FMT_TYPE)
    rows = _fastscan.gather_fixed(buf, off[idx], 3, _FMT_DTYPE.itemsize).view(_FMT_DTYPE)
    segs = []
    for i, r in zip(idx, rows.reshape(-1)):
        name, fmt = cstr(r["Name"]), cstr(r["Format"])
        cols = [c for c in cstr(r["Columns"]).split(",")] if fmt else []
        segs.append((int(i), int(r["Type"]), int(r["Length"]), name, fmt, cols))
    return segs


def _decode_segment(buf, offs, length, fmt, cols, keep) -> dict[str, np.ndarray] | None:
    """Columns (those in ``keep``, or all if None) of the records at ``offs`` with one format,
    or None if the format is unusable."""
    try:
        dt = fmt_dtype(fmt, cols)
    except (KeyError, ValueError):
        return None
    if dt.itemsize != length - 3:
        return None
    rows = _fastscan.gather_fixed(buf, offs, 3, dt.itemsize).view(dt).reshape(-1)
    return {c: convert_column(rows[c], f) for c, f in zip(cols, fmt) if keep is None or c in keep}


OFFSET_COLUMN = "_offset"    # pseudo-column: byte offset (.bin) or line start (.log) of a record


def decode_messages(buf, off, typ, want, columns=None, *, offsets=(), first=None,
                    segs=None) -> dict[str, dict[str, np.ndarray]]:
    """Decode every record whose name satisfies ``want(name)``: name → column → array.

    ``columns(name)`` may return the set of columns to convert (None: all); skipping unused
    columns keeps memory low on big logs. Messages named in ``offsets`` get an extra column
    ``OFFSET_COLUMN``, the byte offset of each record; a dict ``first`` receives name → byte
    offset of the first decoded record of every name. ``segs``: :func:`_format_segments`, if
    already computed.
    """
    if segs is None:
        segs = _format_segments(buf, off, typ)
    # a type's definition holds from its FMT record until the next FMT for the same type
    bounds: dict[int, list] = {}
    for seg in segs:
        defs = bounds.setdefault(seg[1], [])
        if not defs or defs[-1][2:] != seg[2:]:   # an identical re-definition changes nothing
            defs.append(seg)
    out: dict[str, list] = {}
    for t, defs in bounds.items():
        if t == _fastscan.DF_FMT_TYPE or not want(defs[-1][3]):
            continue
        sel_t = np.flatnonzero(typ == t)
        for j, (start, _, length, name, fmt, cols) in enumerate(defs):
            stop = defs[j + 1][0] if j + 1 < len(defs) else len(typ)
            sel = sel_t[(sel_t > start) & (sel_t < stop)]
            if len(sel) and want(name):
                keep = columns(name) if columns else None
                cols_data = _decode_segment(buf, off[sel], length, fmt, cols, keep)
                if cols_data is not None:
                    if name in offsets:
                        cols_data[OFFSET_COLUMN] = off[sel]
                    if first is not None:
                        first[name] = min(first.get(name, int(off[sel[0]])), int(off[sel[0]]))
                    out.setdefault(name, []).append(cols_data)
    merged = {}
    for name, parts in out.items():
        if len(parts) == 1:
            merged[name] = parts[0]
            continue
        common = [c for c in parts[0] if all(c in p for p in parts)]
        merged[name] = {c: np.concatenate([p[c] for p in parts]) for c in common}
    return merged


def _time_s(cols: dict[str, np.ndarray]) -> np.ndarray | None:
    """Record time [s] from TimeUS [µs] or TimeMS [ms]."""
    if "TimeUS" in cols:
        return cols["TimeUS"].astype(np.float64) * 1e-6
    if "TimeMS" in cols:
        return cols["TimeMS"].astype(np.float64) * 1e-3
    return None


_FAMILY_COLUMNS = {  # family → [(recording columns, log columns)]
    "IMU": [(ACC, ("AccX", "AccY", "AccZ")), (GYR, ("GyrX", "GyrY", "GyrZ"))],
    "ACC": [(ACC, ("AccX", "AccY", "AccZ"))],
    "GYR": [(GYR, ("GyrX", "GyrY", "GyrZ"))],
    "MAG": [(MAG, ("MagX", "MagY", "MagZ"))],
}


def _sensor_frame(family: str, cols: dict[str, np.ndarray], t: np.ndarray) -> pd.DataFrame:
    """SI columns of one IMU/ACC/GYR/MAG message family (already SI / mGauss in the log)."""
    df = {"t": t}
    for ours, theirs in _FAMILY_COLUMNS[family]:
        df.update({k: np.asarray(cols[s], np.float64) for k, s in zip(ours, theirs)})
    for tc in ("T", "Temp"):          # IMU temperature [°C]: "T" on newer, "Temp" on older logs
        if family == "IMU" and tc in cols:
            df["temp"] = np.asarray(cols[tc], np.float64)
            break
    return pd.DataFrame(df, copy=False)


def _sensor_recordings(out: LogContents, msgs: dict[str, dict[str, np.ndarray]]) -> None:
    """Recordings from the IMU/ACC/GYR/MAG messages (removed from ``msgs`` as they are used)."""
    for name in sorted(msgs):
        m = IMU_RE.match(name)
        if not m:
            continue
        family, num = m.group(1), m.group(2)
        cols = msgs.pop(name)
        t = _time_s(cols)
        if t is None:
            out.messages.append(f"note: {name} has no TimeUS/TimeMS column; not used")
            continue
        try:
            df = _sensor_frame(family, cols, t)
        except KeyError as e:
            out.messages.append(f"note: {name} lacks column {e}; not used")
            continue
        # ACC1/GYR1 are the first IMU in old logs; IMU2/MAG2 the second
        inst = int(num) - 1 if num else 0    # IMU2/MAG2/ACC2/GYR2 are instance 1, ACC1 is 0
        if "I" in cols:   # instance-numbered messages (ArduPilot 4.x)
            for i in np.unique(cols["I"]):
                add_recording(out, df[cols["I"] == i], name, int(i))
        else:
            add_recording(out, df, name, inst)


# columns read from BAT/CURR: time, current, and the battery instance of newer BAT records
# ("Instance" on 4.0/4.1 as in ardusub_small.BIN, "Inst" later)
CURRENT_COLUMNS = {"TimeUS", "TimeMS", "Curr", "Instance", "Inst"}
_INT_KINDS = "iu"


def _current_amps(curr: np.ndarray) -> np.ndarray:
    """A BAT/CURR ``Curr`` column in A.

    Copter 3.x logs CURR.Curr as an int16 in centi-amps: ArduCopter/Log.pde (3.2) defines CURR
    "IhIhhhf" and writes ``current_amps : (int16_t) (battery.current_amps() * 100.0f)``;
    libraries/DataFlash/DataFlash.h (3.3) keeps ``int16_t current_amps`` in CURR "QhhhHfh". The
    real logs in shared/data/ardupilot agree: copter311_nan.log "IhIhhhf",
    pixhawk_3imu_log171.bin "IhhhHfh", pxf_copter_mag.BIN "QhhhHfh", in flight values such as
    1464 (14.64 A) next to Volt 1549 (15.49 V, also ×100). Later, libraries/DataFlash/LogFile.cpp
    writes CURR's ``current_amps : battery.current_amps(0)`` as a float in A, and BAT
    (libraries/AP_BattMonitor/LogStructure.h, "QBfffffcfB", unit "A", no multiplier for Curr;
    pixhawk1_copter368.bin "Qfffffcf", ardusub_small.BIN "QBfffffcfB") is a float in A too. So
    an integer column (format h/H/i/I in a .bin, parsed with ``int`` from a text log) is
    centi-amps (× 0.01), a float column (f, or c already scaled by its 0.01 multiplier) is A.
    """
    if curr.dtype.kind in _INT_KINDS:
        return curr.astype(np.float64) * 0.01
    return np.asarray(curr, dtype=np.float64)


def _battery_records(msgs) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(time [s], current [A], source name) of the first battery's records, or None.

    BAT (newer firmware) is preferred to CURR (Copter 3.x); BAT2 (a second battery on 3.6) is
    not read. Instance-numbered BAT records (an ``Instance``/``Inst`` column) are those of every
    battery: only the lowest instance, the first battery, is kept.
    """
    for name in CURRENT_NAMES:
        cols = msgs.get(name, {})
        t = _time_s(cols)
        if t is None or "Curr" not in cols or len(t) == 0:
            continue
        curr = cols["Curr"]
        inst = next((c for c in ("Instance", "Inst") if c in cols), None)
        if inst is not None:
            first = cols[inst] == np.min(cols[inst])
            t, curr = t[first], curr[first]
        return t, _current_amps(curr), f"{name}.Curr"
    return None


def _attach_battery_current(out: LogContents, msgs) -> None:
    """Add the ``current`` column [A] to every recording (see the module docstring)."""
    try:
        records = _battery_records(msgs)
    except (TypeError, ValueError):     # a text log whose FMT makes Curr or the time a string
        out.messages.append("note: battery time or current is not numeric; no current column")
        return
    if records is None:
        return
    t, amps, what = records
    series = current_series(t, amps, what, out)
    if series is None:
        return
    for r in out.recordings:
        attach_current(out, r.data, *series, f"{r.message}[{r.instance}]", what)
    note_current(out, what)


def find_param_changes(out: LogContents, msgs, first: dict[str, int], where,
                       time_before) -> None:
    """Set ``out.param_changes`` from the PARM records (see
    :func:`apmcal.sources._common.param_changes`).

    PARM must carry ``OFFSET_COLUMN``; ``first`` gives the position of each message's first
    record, ``where(position)`` describes a position. Time: the record's own TimeUS/TimeMS,
    else ``time_before(position)``, the time of the last sensor record before it (or None).
    """
    parm = msgs.get("PARM", {})
    if not all(c in parm for c in ("Name", "Value", OFFSET_COLUMN)):
        return
    pos = parm[OFFSET_COLUMN]
    starts = [p for name, p in first.items() if IMU_RE.match(name)]
    own_t = _time_s(parm)

    def describe(i):
        p = int(pos[i])
        t = float(own_t[i]) if own_t is not None else time_before(p)
        return t, where(p)

    out.param_changes = param_changes(parm["Name"], parm["Value"], pos,
                                      min(starts) if starts else None, describe)


def build_contents(out: LogContents, msgs: dict[str, dict[str, np.ndarray]]) -> LogContents:
    """Fill ``out`` from decoded dataflash messages (binary or text) and check for IMU data."""
    parm = msgs.get("PARM", {})
    if "Name" in parm and "Value" in parm:
        _params(out, parm["Name"], parm["Value"], "PARM")
    for text in msgs.get("MSG", {}).get("Message", []):
        out.messages.append(text)
        fw = parse_firmware(text)
        if fw and out.firmware is None:
            out.vehicle, out.firmware = fw
    found = [k for k, v in msgs.items() if any(len(a) for a in v.values())]
    _sensor_recordings(out, msgs)
    _attach_battery_current(out, msgs)
    boot_unix = boot_to_unix_offset(msgs.get("GPS", {}))
    if boot_unix is not None and out.recordings:
        out.start_unix_s = boot_unix + min(float(r.data["t"].iloc[0]) for r in out.recordings)
    return finish(out, found)


SENSOR_COLUMNS = {"TimeUS", "TimeMS", "I", "AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ",
                  "MagX", "MagY", "MagZ", "T", "Temp"}


def wanted_columns(name: str):
    """Columns the reader converts: the sensor columns of IMU-family messages, the time columns
    of GPS, time, current and instance of BAT/CURR, all of the others."""
    if name == "GPS":
        return GPS_TIME_COLUMNS
    if name in CURRENT_NAMES:
        return CURRENT_COLUMNS
    return SENSOR_COLUMNS if IMU_RE.match(name) else None


def wanted_name(name: str) -> bool:
    """Messages the reader decodes: IMU/ACC/GYR/MAG families, PARM, MSG, GPS (for the date),
    BAT/CURR (battery current)."""
    return bool(IMU_RE.match(name)) or name in META_NAMES


def read_bin_messages(path, want=wanted_name):
    """Decode the messages selected by ``want`` of a .bin file.

    Returns (name → column → array (DFReader values), bytes_skipped, damaged_at).

    Parameters
    ----------
    path : str or Path
    want : callable, optional
        ``want(name)`` → bool selects the messages decoded.

    Raises
    ------
    ApmcalError
        Unreadable or empty file.
    """
    buf = load_bytes(path)
    off, typ, skipped, damaged = scan(buf)
    return decode_messages(buf, off, typ, want), skipped, damaged


def read_dataflash(path, *, progress: bool = False) -> LogContents:
    """Read a dataflash binary log into a :class:`LogContents`.

    Raises
    ------
    ApmcalError
        Unreadable/empty file, no dataflash record, or no IMU message.
    """
    buf = load_bytes(path)
    off, typ, skipped, damaged = scan(buf)
    if len(off) == 0:
        raise ApmcalError("no dataflash record in the file", str(path), "byte 0")
    segs = _format_segments(buf, off, typ)
    first: dict[str, int] = {}
    msgs = decode_messages(buf, off, typ, wanted_name, wanted_columns, offsets=("PARM",),
                           first=first, segs=segs)
    out = LogContents(path=str(path), format="bin", bytes_skipped=skipped, damaged_at=damaged)
    find_param_changes(out, msgs, first, "PARM record at byte {}".format,
                       partial(_sensor_time_before, buf, off, typ, segs))
    del off, typ
    return build_contents(out, msgs)


def _sensor_time_before(buf, off, typ, segs, pos: int) -> float | None:
    """Time [s] of the last IMU/ACC/GYR/MAG record before byte ``pos`` (None if none or no
    time column). Used only for PARM records without a time of their own (older logs)."""
    sensor = np.zeros(256, dtype=np.bool_)
    for _, t, _, name, _, _ in segs:
        sensor[t] = bool(IMU_RE.match(name))
    end = int(np.searchsorted(off, pos))
    step = 4096
    while end > 0:
        lo = max(0, end - step)
        hits = np.flatnonzero(sensor[typ[lo:end]])
        if len(hits):
            j = lo + int(hits[-1])
            seg = [s for s in segs if s[1] == typ[j] and s[0] < j]
            if not seg:
                return None
            _, _, length, name, fmt, cols = seg[-1]
            data = _decode_segment(buf, off[j:j + 1], length, fmt, cols, {"TimeUS", "TimeMS"})
            t = _time_s(data) if data is not None else None
            return float(t[0]) if t is not None else None
        end, step = lo, step * 2
    return None
