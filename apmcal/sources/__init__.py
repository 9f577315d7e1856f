"""Sources: read logs and files into :class:`~apmcal.core.recording.LogContents`.

:func:`read_log` sniffs the content (and, as a tie-breaker, the extension) and dispatches to
:func:`apmcal.sources.tlog.read_tlog` (.tlog), :func:`apmcal.sources.dataflash.read_dataflash`
(dataflash .bin), :func:`apmcal.sources.dataflash_text.read_dataflash_text` (dataflash text
.log) or ``apmcal.sources.csv.read_csv`` (CSV and other text tables). Whatever the bytes, only
:class:`~apmcal.core.errors.ApmcalError` escapes.

Modules: :mod:`~apmcal.sources.tlog`, :mod:`~apmcal.sources.dataflash`,
:mod:`~apmcal.sources.dataflash_text`, :mod:`~apmcal.sources.csv` (the readers, over the private
framing and record helpers ``_framing``, ``_fastscan``, ``_tlogwalk`` (big or damaged .tlog:
lockstep walkers) and ``_common``);
:mod:`~apmcal.sources.tclr` (the firmware temperature learner's TCLR records);
:mod:`~apmcal.sources.gps_time` (a dataflash log's wall-clock time from its GPS records);
:mod:`~apmcal.sources.units` (is each sensor's magnitude one the Earth allows?);
:mod:`~apmcal.sources.live` (a live vehicle's IMU streamed and recorded over MAVLink).
:mod:`~apmcal.sources.flight` (what the flight compass check needs from a dataflash log: ATT,
GPS, MAG per instance, BAT/CURR, CTUN/RCOU, IMU gyro, PARM, as numpy arrays with their units).
"""
from __future__ import annotations

from pathlib import Path

from apmcal.core.errors import ApmcalError
from apmcal.core.recording import LogContents

__all__ = ["read_log", "sniff_format"]

_HEAD = 8192
_TEXT_EXT = {".csv", ".txt", ".mat", ".tsv", ".dat"}


def _head(path: Path) -> bytes:
    try:
        if path.is_dir():
            raise ApmcalError("is a directory, not a log file", str(path))
        with open(path, "rb") as f:
            return f.read(_HEAD)
    except OSError as e:
        raise ApmcalError(f"cannot open file: {e.strerror or e}", str(path)) from None


def _has_tlog_frame(head: bytes) -> bool:
    """True when a CRC-checked tlog frame of a known message starts within the first bytes.

    Plain Python on at most 512 positions (a few bytes: the vectorised framing would cost more
    to set up).
    """
    from apmcal.sources._fastscan import tlog_frame_at
    from apmcal.sources.tlog import _tables
    crc = _tables()[0]
    return any(tlog_frame_at(head, p, crc) >= 0 for p in range(min(len(head), 512)))


def _looks_text(head: bytes) -> bool:
    if b"\0" in head:
        return False
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as e:
        return e.start >= len(head) - 4    # a multi-byte character cut by the head limit
    return True


MIN_LOG_BYTES = 16      # shorter than one header line or one record: no log at all


def sniff_format(path) -> str:
    """"tlog", "bin", "log" or "csv" from the file's first bytes (extension breaks ties).

    Raises ApmcalError for a missing, empty or unrecognised file.
    """
    path = Path(path)
    head = _head(path)
    if not head:
        raise ApmcalError("empty file", str(path), "byte 0")
    ext = path.suffix.lower()
    if len(head) < MIN_LOG_BYTES:
        raise ApmcalError(f"not a recognised log format ({len(head)} bytes: too short for a "
                          "tlog, dataflash or CSV file)", str(path), "byte 0")
    if head.startswith(b"\xa3\x95"):
        return "bin"
    if _has_tlog_frame(head):
        return "tlog"
    if b"\xa3\x95\x80" in head:     # a FMT record after some leading garbage
        return "bin"
    if b"FMT," in head and _looks_text(head):
        return "log"
    if _looks_text(head):
        if ext in (".bin", ".tlog"):
            raise ApmcalError(f"not a recognised log format: text, but a {ext} file should be "
                              "binary (no dataflash or MAVLink record found)", str(path), "byte 0")
        return "csv"
    if ext == ".tlog":
        return "tlog"
    if ext == ".bin":
        return "bin"
    raise ApmcalError("unknown format: not a tlog, dataflash or CSV file", str(path), "byte 0")


def _reader(kind: str):
    if kind == "tlog":
        from apmcal.sources.tlog import read_tlog
        return read_tlog
    if kind == "bin":
        from apmcal.sources.dataflash import read_dataflash
        return read_dataflash
    if kind == "log":
        from apmcal.sources.dataflash_text import read_dataflash_text
        return read_dataflash_text
    try:
        from apmcal.sources.csv import read_csv
    except ImportError:
        raise ApmcalError("CSV reader (apmcal.sources.csv) is not available", None) from None
    return lambda p, progress=False: read_csv(p)


def read_log(path, *, progress: bool = False) -> LogContents:
    """Read any supported log file (.tlog, dataflash .bin/.log, CSV) into LogContents.

    Parameters
    ----------
    path : str or Path
    progress : bool
        Accepted for API compatibility; the vectorised readers are fast enough not to report.

    Raises
    ------
    ApmcalError
        Missing, empty, unknown or undecodable file, or no IMU data. No other exception escapes.
    """
    kind = sniff_format(path)
    try:
        contents = _reader(kind)(path, progress=progress)
    except ApmcalError as e:
        if e.path is None:
            e.path = str(path)
        raise
    except MemoryError:
        raise ApmcalError("not enough memory to read the file", str(path)) from None
    except Exception as e:  # noqa: BLE001 - the contract: only ApmcalError escapes
        raise ApmcalError(f"cannot read {kind} file ({type(e).__name__}: {e})".replace("\n", " "),
                          str(path)) from None
    return contents
