"""Helpers shared by the log readers: file loading, firmware strings, parameters, recordings."""
from __future__ import annotations

import math
import os
import re
import struct
from pathlib import Path

import numpy as np
import pandas as pd

from apmcal.ardupilot.names import CORRECTION_PARAM_PREFIXES
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import (
    ACC,
    GYR,
    MAG,
    LogContents,
    ParamChange,
    Recording,
)

#: numpy dtype per struct format character (little-endian, packed)
STRUCT_TO_NUMPY = {
    "b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4",
    "q": "<i8", "Q": "<u8", "f": "<f4", "d": "<f8", "e": "<f2", "c": "S1",
}

MAX_DAMAGE_OFFSETS = 1000     # damaged_at keeps at most this many offsets (the count is exact)

# "ArduCopter V3.2.1 (...)", "APM:Copter V3.3-dev (...)", "ArduSub V4.1.1 BETA5 (...)"
_FW_RE = re.compile(r"\b(Ardu[A-Za-z]+|APM:[A-Za-z]+|Rover|AntennaTracker|Blimp)\s+V(\d[\w.\-]*)")
_APM_NAMES = {"APM:Copter": "ArduCopter", "APM:Plane": "ArduPlane", "APM:Rover": "Rover",
              "ArduRover": "Rover", "APM:Sub": "ArduSub", "APM:Tracker": "AntennaTracker"}


def struct_dtype(names: list[str], fmt: str) -> np.dtype:
    """Packed numpy dtype equal to the ``struct`` format ``fmt`` with field ``names``.

    ``"50s"`` becomes a 50-byte string field, ``"8B"`` a (8,) subarray.
    """
    codes = re.findall(r"(\d*)([a-zA-Z?])", fmt.lstrip("<>=!@"))
    if len(codes) != len(names):
        raise ValueError(f"{len(names)} names for {len(codes)} fields in {fmt!r}")
    fields = []
    for name, (count, ch) in zip(names, codes):
        k = int(count) if count else 1
        if ch == "s":
            fields.append((name, f"S{k}"))
        elif k > 1:
            fields.append((name, STRUCT_TO_NUMPY[ch], (k,)))
        else:
            fields.append((name, STRUCT_TO_NUMPY[ch]))
    dt = np.dtype(fields)
    assert dt.itemsize == struct.calcsize("<" + fmt.lstrip("<>=!@"))
    return dt


def load_bytes(path) -> np.ndarray:
    """The file as a read-only uint8 array (memory-mapped), or ApmcalError when unreadable/empty.

    Returns
    -------
    numpy.ndarray of uint8, shape (file size,)

    Raises
    ------
    ApmcalError
        Missing, unreadable or empty file, or a directory.
    """
    p = Path(path)
    try:
        size = os.path.getsize(p)
    except OSError as e:
        raise ApmcalError(f"cannot open file: {e.strerror or e}", str(path)) from None
    if p.is_dir():
        raise ApmcalError("is a directory, not a log file", str(path))
    if size == 0:
        raise ApmcalError("empty file", str(path), "byte 0")
    try:
        mm = np.memmap(p, dtype=np.uint8, mode="r")
    except (OSError, ValueError) as e:
        raise ApmcalError(f"cannot read file: {e}", str(path)) from None
    return np.asarray(mm)


def parse_firmware(text: str) -> tuple[str, str] | None:
    """(vehicle, firmware) from a boot banner such as "ArduCopter V3.2.1 (abc)", else None."""
    m = _FW_RE.search(text)
    if not m:
        return None
    vehicle = _APM_NAMES.get(m.group(1), m.group(1))
    return vehicle, f"{vehicle} V{m.group(2)}"


def cstr(b: bytes) -> str:
    """NUL-terminated bytes to str (UTF-8, falling back to Latin-1 as pymavlink does)."""
    b = bytes(b).split(b"\0", 1)[0]
    try:
        return b.decode("utf-8")
    except UnicodeDecodeError:
        return b.decode("ISO-8859-1")


def add_param(out: LogContents, name: str, value: float, where: str) -> None:
    """Store a parameter; non-finite values are kept out and reported in ``out.messages``."""
    value = float(value)
    if not math.isfinite(value):
        out.messages.append(f"warning: parameter {name} is {value} at {where}; ignored")
        return
    out.params[name] = value


def _params(out: LogContents, names: np.ndarray, values: np.ndarray, what: str) -> None:
    """Last finite value of every parameter, vectorised (logs repeat the list many times).

    Non-finite values (NaN parameters exist in real logs, e.g. COMPASS_MOT_* on Copter 3.1.1)
    are kept out; one warning per parameter names the first such record.
    """
    values = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(values)
    if not ok.all():
        for i in _first_per_name(names, ~ok):
            add_param(out, _name(names[i]), values[i], f"{what} #{i}")
    idx = np.flatnonzero(ok)
    if len(idx):
        for i in _last_per_name(names[idx]):
            add_param(out, _name(names[idx[i]]), values[idx[i]], f"{what} #{idx[i]}")


def _name(v) -> str:
    return cstr(v) if isinstance(v, (bytes, np.bytes_)) else str(v)


def _first_per_name(names: np.ndarray, mask: np.ndarray) -> np.ndarray:
    idx = np.flatnonzero(mask)
    _, first = np.unique(names[idx], return_index=True)
    return idx[np.sort(first)]


def _last_per_name(names: np.ndarray) -> np.ndarray:
    """Indices of the last occurrence of each distinct name, in order of those occurrences."""
    _, rev_first = np.unique(names[::-1], return_index=True)
    return np.sort(len(names) - 1 - rev_first)


_PREFIXES_BYTES = tuple(p.encode() for p in CORRECTION_PARAM_PREFIXES)


def _is_calibration_name(names: np.ndarray) -> np.ndarray:
    """Boolean mask: which ``names`` start with a calibration prefix.

    Written by hand for fixed-width byte names (MAVLink param_id, PARM Name): each name is read
    as 64-bit words and each prefix compared under a byte mask, a few integer operations per
    name instead of a Python ``str.startswith`` call (which dominated reading a big .tlog).
    """
    if names.dtype.kind != "S":          # text logs: Python strings
        return np.fromiter((str(n).startswith(CORRECTION_PARAM_PREFIXES) for n in names),
                           dtype=np.bool_, count=len(names))
    width = -(-max(names.dtype.itemsize, 16) // 8) * 8          # whole 64-bit words
    words = np.ascontiguousarray(names.astype(f"S{width}")).view("<u8").reshape(len(names), -1)
    mask = np.zeros(len(names), dtype=np.bool_)
    for prefix in _PREFIXES_BYTES:
        padded = prefix.ljust(width, b"\0")
        care = (b"\xff" * len(prefix)).ljust(width, b"\0")
        want = np.frombuffer(padded, "<u8")
        keep = np.frombuffer(care, "<u8")
        hit = np.ones(len(names), dtype=np.bool_)
        for k in np.flatnonzero(keep):                    # only the words the prefix covers
            hit &= (words[:, k] & keep[k]) == want[k]
        mask |= hit
    return mask


def param_changes(names: np.ndarray, values: np.ndarray, positions: np.ndarray,
                  first_sample: int | None, describe) -> list[ParamChange]:
    """Calibration parameters that take a new value after the first sensor sample.

    The firmware corrects each IMU/MAG sample with the parameters in force when it is made
    (ardupilot-facts.md, "What the telemetry really carries"), so a log in which, say,
    INS_ACCOFFS_X changes once the samples have begun cannot be un-corrected with one parameter
    set. A change is a parameter record (PARM, PARAM_VALUE) of a calibration parameter
    (:data:`~apmcal.ardupilot.names.CORRECTION_PARAM_PREFIXES`) that comes after the first sensor
    sample and whose value differs, at float32 precision (the firmware's storage), from the
    previous record of that name. Identical repeats (logs write the whole list again, ground
    stations re-request it) are not changes; non-finite values are ignored (``_params`` warns).

    Parameters
    ----------
    names, values : numpy.ndarray, shape (m,)
        One entry per parameter record, in file order (names bytes or str).
    positions : numpy.ndarray of int, shape (m,)
        File position of each record (byte offset), non-decreasing.
    first_sample : int or None
        Position of the first IMU/MAG sample, None when there is none.
    describe : callable
        callable(record index) → (time_s or None, where).

    Returns
    -------
    list of ParamChange
        The changes in file order. Cost without changes: one pass over the names; the
        grouping work is done only when a calibration record follows the first sample.
    """
    if first_sample is None or len(names) == 0:
        return []
    names = np.asarray(names)
    cal = _is_calibration_name(names)
    values = np.asarray(values, dtype=np.float64)
    idx = np.flatnonzero(cal & np.isfinite(values))
    if len(idx) == 0 or positions[idx[-1]] <= first_sample:
        return []
    _, group = np.unique(names[idx], return_inverse=True)
    order = idx[np.argsort(group, kind="stable")]          # by name, then file order
    g = np.sort(group, kind="stable")
    v32 = values[order].astype(np.float32)
    hit = np.flatnonzero((g[1:] == g[:-1]) & (v32[1:] != v32[:-1])
                         & (positions[order[1:]] > first_sample)) + 1
    changes = []
    for k in hit[np.argsort(order[hit], kind="stable")]:    # file order
        i = int(order[k])
        time_s, where = describe(i)
        changes.append(ParamChange(_name(names[i]), float(values[order[k - 1]]),
                                   float(values[i]), time_s, where))
    return changes


def drop_zero_sensors(df: pd.DataFrame, label: str, out: LogContents) -> pd.DataFrame:
    """Remove sensor column triples (and temp) that are zero in every sample.

    Some firmware fills absent sensors with zeros (ArduSub's SCALED_IMU2 acc/gyro, an absent
    compass in old MAG messages). Zeros are not data, so the columns are dropped (the recording
    model says absent columns are absent, never zero-filled) and a note is added to messages.
    """
    for cols, what in ((ACC, "acc"), (GYR, "gyr"), (MAG, "mag"), (["temp"], "temp")):
        if (all(c in df.columns for c in cols) and len(df)
                and not any(df[c].to_numpy().any() for c in cols)):
            df = df.drop(columns=cols)
            out.messages.append(f"note: {label} {what} is all zero; column(s) dropped")
    return df


#: name of the optional battery current column [A] (see :mod:`apmcal.core.recording`)
CURRENT_COLUMN = "current"


def current_series(t_s, amps, what: str,
                   out: LogContents) -> tuple[np.ndarray, np.ndarray] | None:
    """Battery current records ready to be interpolated: (time [s], current [A]), or None.

    Records with a non-finite time or current are left out. None, with a note in
    ``out.messages``, when no record is non-zero (no current sensor fitted: ArduPilot then logs
    zeros, as for an absent compass, see :func:`drop_zero_sensors`), when the time goes back (a
    reboot restarts the clock: a time no longer says which boot a record is from) or when fewer
    than two distinct times remain (no span to interpolate over). Of records sharing one time
    the first is kept (``np.interp`` needs increasing times).

    Parameters
    ----------
    t_s : array_like, shape (m,)
        Record times [s] on the recordings' time axis, in file order.
    amps : array_like, shape (m,)
        Battery current of each record [A].
    what : str
        The records' name for the notes, e.g. "BAT Curr".
    out : LogContents
        Receives the notes.

    Returns
    -------
    (t_s, amps) : tuple of numpy.ndarray, shape (k,) each, or None
        Increasing record times [s] and their current [A], k ≥ 2.
    """
    t_s, amps = np.asarray(t_s, dtype=np.float64), np.asarray(amps, dtype=np.float64)
    ok = np.isfinite(t_s) & np.isfinite(amps)
    t_s, amps = t_s[ok], amps[ok]
    if not amps.any():
        out.messages.append(f"note: {what} is zero in every record (no current sensor?); "
                            "no current column")
        return None
    if np.any(np.diff(t_s) < 0):
        out.messages.append(f"note: {what}: the clock jumps back (a reboot?); no current column")
        return None
    keep = np.flatnonzero(np.diff(t_s, prepend=-np.inf) > 0)
    if len(keep) < 2:
        out.messages.append(f"note: {what} has fewer than two record times; no current column")
        return None
    return t_s[keep], amps[keep]


def attach_current(out: LogContents, df: pd.DataFrame, t_cur: np.ndarray, amps: np.ndarray,
                   label: str, what: str) -> bool:
    """Add the battery current [A] at the sample times to ``df`` as column ``current``.

    Linear interpolation between the records (``t_cur`` increasing, from :func:`current_series`),
    NaN outside their span. Nothing is added, with a note, when the samples' clock jumps back
    (a reboot) or no sample lies within the records' span. Returns True when the column was
    added.

    Parameters
    ----------
    out : LogContents
        Receives the notes.
    df : pandas.DataFrame
        A recording's samples with column ``t`` [s]; modified in place.
    t_cur, amps : numpy.ndarray, shape (k,)
        Record times [s] and current [A] from :func:`current_series`.
    label, what : str
        The recording's and the records' names for the notes.

    Returns
    -------
    bool
    """
    t = df["t"].to_numpy(dtype=np.float64)
    if np.any(np.diff(t) < 0):
        out.messages.append(f"note: {label}: the clock jumps back (a reboot?); no {what} "
                            "current attached")
        return False
    # t is sorted: the samples within [t_cur[0], t_cur[-1]] are one run, found by bisection
    if np.searchsorted(t, t_cur[-1], "right") <= np.searchsorted(t, t_cur[0], "left"):
        out.messages.append(f"note: {label} and {what} share no time span; no current attached")
        return False
    df[CURRENT_COLUMN] = np.interp(t, t_cur, amps, left=np.nan, right=np.nan)
    return True


def note_current(out: LogContents, what: str) -> None:
    """One note naming the source of the ``current`` column, when some recording has it."""
    n = sum(CURRENT_COLUMN in r.data.columns for r in out.recordings)
    if n:
        out.messages.append(f"note: battery current [A] from {what}, interpolated to the sample "
                            f"times of {n} recording(s) (column {CURRENT_COLUMN})")


def _default_index(df: pd.DataFrame) -> bool:
    ix = df.index
    return isinstance(ix, pd.RangeIndex) and ix.start == 0 and ix.step == 1


def add_recording(out: LogContents, df: pd.DataFrame, message: str, instance: int) -> None:
    """Append a body-frame, firmware-corrected Recording if any sensor columns survive.

    ArduPilot's RAW_IMU/SCALED_IMU*/IMU/MAG are corrected and in body frame
    (ardupilot-facts.md, "What the telemetry really carries").
    """
    label = f"{message}[{instance}]"
    df = drop_zero_sensors(df, label, out)
    if not any(c in df.columns for c in ACC + GYR + MAG):
        out.messages.append(f"note: {label} has no non-zero sensor data; not used")
        return
    if not _default_index(df):
        df = df.reset_index(drop=True)
    out.recordings.append(Recording(data=df, source=out.path, message=message, instance=instance,
                                    corrected=True, frame="body"))


def finish(out: LogContents, found: list[str]) -> LogContents:
    """Attach vehicle/firmware/params to each recording; ApmcalError when there is no IMU data.

    Raises
    ------
    ApmcalError
        When ``out`` has no recording; ``found`` (message names seen) goes into the message.
    """
    if not out.recordings:
        names = ", ".join(sorted(set(found))[:20]) or "nothing recognisable"
        raise ApmcalError(f"no IMU messages (found: {names})", out.path)
    for r in out.recordings:
        r.vehicle, r.firmware, r.params = out.vehicle, out.firmware, dict(out.params)
    return out
