"""Reader for ArduPilot dataflash text logs (.log): lines "FMT, 128, 89, FMT, BBnNZ, ..." and
"IMU, 95892, 0.00033, ...".

Parsing follows pymavlink's DFReader_text: the delimiter is ", " unless the file only has "FMT,"
lines; a line is used when its first field names a message defined by an earlier FMT line and it
has at least as many fields as the format; values are converted with Python's ``int``/``float``
exactly as DFReader_text does (no multipliers in text logs). Lines that cannot be converted are
counted as damaged bytes. Recordings, parameters, parameter changes and the battery current
column are then found as for .bin logs (:func:`apmcal.sources.dataflash.build_contents`,
``find_param_changes``); an integer CURR.Curr parsed from text is centi-amps there too.
"""
from __future__ import annotations

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.core.recording import LogContents
from apmcal.sources._common import MAX_DAMAGE_OFFSETS, load_bytes
from apmcal.sources.dataflash import (
    IMU_RE,
    OFFSET_COLUMN,
    build_contents,
    find_param_changes,
    wanted_name,
)

_INT_CHARS = set("bBhHiIMqQ")
_FLOAT_CHARS = set("fdgcCeEL")


def _converter(ch: str):
    if ch in _INT_CHARS:
        return int
    if ch in _FLOAT_CHARS:
        return float
    if ch == "a":
        return str
    return lambda s: s.split("\0", 1)[0]


class _Fmt:
    """One FMT line: name, format characters, column names and per-column converters."""

    def __init__(self, name: str, fmt: str, columns: str):
        self.name, self.fmt = name, fmt
        self.columns = [c.strip() for c in columns.split(",")] if columns else []
        self.conv = [_converter(c) for c in fmt]


def _lines(data: bytes):
    """(byte offset, line text, byte count, complete) for every line, decoded as UTF-8.

    The last line is incomplete when the file does not end with a newline (a truncated log):
    its last number may be cut short, so it must not be trusted.
    """
    pos = 0
    pieces = data.split(b"\n")
    for i, raw in enumerate(pieces):
        complete = i < len(pieces) - 1
        yield pos, raw.rstrip().decode("utf-8", errors="replace"), len(raw) + complete, complete
        pos += len(raw) + 1


def _column(vals: list, conv) -> np.ndarray:
    """Array of converted values: float64, int64 (object if out of range) or object strings."""
    if conv is float:
        return np.array(vals, dtype=np.float64)
    if conv is int:
        try:
            return np.array(vals, dtype=np.int64)
        except OverflowError:
            return np.array(vals, dtype=object)
    return np.array(vals, dtype=object)


def parse_text(data: bytes, want=wanted_name, *, offsets=(), first=None, formats_out=None):
    """Parse text dataflash bytes: (name → column → array, bytes_skipped, damaged_at).

    Messages named in ``offsets`` get an extra column ``OFFSET_COLUMN``, the byte offset of
    each line; a dict ``first`` receives name → byte offset of the first line of every parsed
    message; a dict ``formats_out`` receives the FMT definitions (name → :class:`_Fmt`).
    """
    delim = ", " if data.find(b"FMT, ") != -1 else ","
    formats = {"FMT": _Fmt("FMT", "BBnNZ", "Type,Length,Name,Format,Columns")}
    rows: dict[str, list] = {}
    skipped, damaged = 0, []
    first_fmt = data.find(b"FMT,")
    for pos, line, nbytes, complete in _lines(data):
        if not line.strip() or pos < first_fmt:
            continue  # blank lines, banner before the first FMT (e.g. "ArduCopter V3.1")
        if not complete:
            skipped += nbytes
            damaged.append(pos)
            continue
        el = line.split(delim)
        fmt = formats.get(el[0])
        if fmt is None or len(el) < len(fmt.fmt) + 1:
            if fmt is None or (fmt.fmt and fmt.name != "FMT"):  # unknown/short line: damage
                skipped += nbytes
                if len(damaged) < MAX_DAMAGE_OFFSETS:
                    damaged.append(pos)
            continue
        vals = el[1:]
        try:
            if fmt.name == "FMT":
                if delim == ",":
                    vals = vals[0:4] + [",".join(vals[4:])]
                cols = vals[4] if len(vals) > 4 else ""
                if vals[2] == "FMT" and cols == "Type,Length,Name,Format":
                    cols = "Type,Length,Name,Format,Columns"
                int(vals[0]), int(vals[1])
                formats[vals[2]] = _Fmt(vals[2], vals[3], cols)
            elif want(fmt.name):
                r = rows.get(fmt.name)
                if r is None:
                    r = rows[fmt.name] = []
                    if first is not None:
                        first[fmt.name] = pos
                row = [cv(v) for cv, v in zip(fmt.conv, vals[:len(fmt.fmt)])]
                if fmt.name in offsets:
                    row.append(pos)
                r.append(row)
        except (ValueError, IndexError):
            skipped += nbytes
            if len(damaged) < MAX_DAMAGE_OFFSETS:
                damaged.append(pos)
    msgs = {}
    for name, rs in rows.items():
        fmt = formats[name]
        cols = {}
        for j, c in enumerate(fmt.columns[:len(fmt.fmt)]):
            vals = [r[j] for r in rs]
            cols[c] = _column(vals, fmt.conv[j])
        if name in offsets:
            cols[OFFSET_COLUMN] = np.array([r[-1] for r in rs], dtype=np.int64)
        msgs[name] = cols
    if formats_out is not None:
        formats_out.update(formats)
    return msgs, skipped, damaged


def _sensor_time_before(data: bytes, delim: str, formats: dict, names, pos: int) -> float | None:
    """Time [s] of the last IMU/ACC/GYR/MAG line before byte ``pos`` (None if there is none or it
    has no TimeUS/TimeMS). Used only for PARM lines without a time of their own (older logs)."""
    best = (-1, None)
    for name in names:
        fmt = formats.get(name)
        if fmt is None or not IMU_RE.match(name):
            continue
        k = data.rfind(b"\n" + (name + delim).encode(), 0, pos)
        if k <= best[0]:
            continue
        line = data[k + 1:data.find(b"\n", k + 1)].decode("utf-8", "replace").split(delim)
        for col, scale in (("TimeUS", 1e-6), ("TimeMS", 1e-3)):
            if col in fmt.columns:
                try:
                    best = (k, float(line[1 + fmt.columns.index(col)]) * scale)
                except (ValueError, IndexError):
                    pass
                break
    return best[1]


def _line_number(data: bytes, pos: int) -> int:
    return data.count(b"\n", 0, pos) + 1


def read_dataflash_text(path, *, progress: bool = False) -> LogContents:
    """Read a text dataflash log into a :class:`LogContents`.

    Raises
    ------
    ApmcalError
        Unreadable/empty file, no FMT line, or no IMU message.
    """
    data = load_bytes(path).tobytes()
    if b"FMT," not in data:
        raise ApmcalError("no FMT line: not a dataflash text log", str(path), "byte 0")
    first: dict[str, int] = {}
    formats: dict = {}
    msgs, skipped, damaged = parse_text(data, offsets=("PARM",), first=first,
                                        formats_out=formats)
    out = LogContents(path=str(path), format="log", bytes_skipped=skipped, damaged_at=damaged)
    delim = ", " if data.find(b"FMT, ") != -1 else ","
    find_param_changes(out, msgs, first, lambda p: f"PARM at line {_line_number(data, p)}",
                       lambda p: _sensor_time_before(data, delim, formats, list(first), p))
    return build_contents(out, msgs)
