"""One log → one flat record: identity, calibration in force, health figures, date, duration.

:func:`extract` never raises: a damaged file, or one that is no log, becomes a record with
``status`` "error" and the ``reason``, so one bad file never stops a fleet run. The record's
values are plain str/float/int/bool/None (JSON strings for the parameter sets), small enough for
a Dask scheduler to hold thousands of them.
"""
from __future__ import annotations

import datetime
import json
from pathlib import Path

import numpy as np

from apmcal.core.blas_threads import single_threaded_blas
from apmcal.core.errors import ApmcalError

#: bump when a record's meaning changes: the cache key includes it, so old records are redone
EXTRACT_VERSION = 5


def base_record(path: Path) -> dict:
    """The fields every record has, whatever happens to the file."""
    try:
        size = path.stat().st_size
    except OSError:
        size = None
    return {"path": str(path), "file_bytes": size, "status": "error", "reason": None,
            "format": None, "vehicle_id": None, "notes": ""}


def _year(unix_s: float | None) -> tuple[float, str | None]:
    """Decimal year of the log for the WMM, and a note when undated (today's field is used, as
    the single-log commands do; the field changes about 0.1 % a year)."""
    from apmcal.core.geomag import decimal_year

    if unix_s is None:
        return (decimal_year(datetime.datetime.now(datetime.timezone.utc)),
                "no date in the log: the WMM field of today used")
    return decimal_year(datetime.datetime.fromtimestamp(unix_s, tz=datetime.timezone.utc)), None


def _extra_messages(contents) -> dict:
    """GPS and VIBE records of a dataflash .bin (the reader keeps only the GPS time)."""
    if contents.format != "bin":
        return {}
    from apmcal.sources.dataflash import read_bin_messages

    try:
        msgs, _, _ = read_bin_messages(contents.path, want=lambda n: n in ("GPS", "VIBE"))
    except (ApmcalError, ValueError, TypeError):
        return {}
    return msgs


def _header_sysid(contents) -> int | None:
    """The autopilot's system id from a .tlog's frame headers; None for other formats."""
    if contents.format != "tlog":
        return None
    from apmcal.sources.tlog import autopilot_system_id

    return autopilot_system_id(contents.path)


def _compass(contents, mag, site, user_site, year, notes) -> dict:
    """Compass figures: the flight compass check on a flight (what ``apmcal log`` reports),
    else the sphere residual of a session that turns the compass; notes say what was not done."""
    from apmcal.calibration import health
    from apmcal.preprocessing.prepare import has_live_magnetometer

    if contents.format in ("bin", "log", "tlog"):
        try:
            checked = health.flight_compass(contents.path, user_site and user_site[:2])
        except ApmcalError as err:
            notes.append(f"compass in flight not checked: {err.why}")
        except Exception as exc:    # a bug of ours costs this figure, not the log's others
            notes.append(f"compass in flight not checked: internal error: "
                         f"{type(exc).__name__}: {exc}")
        else:
            if checked.result is not None:
                return checked.figures(health.compasses_in_use(contents.params))
            if checked.lacking:
                notes.append(f"compass in flight not checked: {checked.lacking}")
    if mag is None or not has_live_magnetometer(mag):
        notes.append("no live compass")
        return {}
    figures, mag_notes = health.compass_health(mag, site, year[0])
    notes += mag_notes + ([year[1]] if year[1] and "heading_error_deg" in figures else [])
    if "heading_error_deg" in figures:
        figures["heading_error_method"] = "sphere"
    return figures


def describe(contents, site: tuple[float, float, float] | None = None) -> dict:
    """The record's fields of a read log: identity, calibration, health, date and duration.

    Parameters
    ----------
    contents : LogContents
    site : (lat [deg], lon [deg], alt [m]), optional
        Used when the log has no GPS fix.

    Raises
    ------
    ApmcalError
        When the log has no accelerometer recording, or is a CSV table (no ArduPilot log).
    """
    from apmcal.calibration import health
    from apmcal.fleet.identity import calibration_in_force, dev_ids, identity
    from apmcal.preprocessing.prepare import drop_non_finite, pick_recording
    from apmcal.preprocessing.timebase import monotonic

    if contents.format == "csv":
        raise ApmcalError("not an ArduPilot log (a text or CSV table)", contents.path)
    rec = {"format": contents.format, **identity(contents, _header_sysid(contents))}
    recording, mag_recording = pick_recording(contents, None)
    recording, notes = drop_non_finite(recording)
    recording, more = monotonic(recording)
    notes += more
    msgs = _extra_messages(contents)
    user_site = site
    site = health.gps_site(msgs) or site
    rec["site_lat_deg"], rec["site_lon_deg"] = (site[0], site[1]) if site else (None, None)
    rec["start_unix_s"] = contents.start_unix_s
    rec["duration_s"] = recording.duration
    rec["imu"] = f"{recording.message}[{recording.instance}]"
    rec["imu_rate_hz"] = recording.rate_hz
    cal = calibration_in_force(contents.params)
    rec["calibration_json"] = json.dumps(cal, sort_keys=True)
    rec["dev_ids_json"] = json.dumps(dev_ids(contents.params), sort_keys=True)
    rec["calibration_changes_in_log"] = len(contents.param_changes)
    segments = health.still_segments(recording)
    if not segments:
        notes.append("no still period: no gyro bias, accelerometer level or noise")
    rec.update(health.gyro_health(recording, segments, contents.params, contents.firmware))
    rec.update(health.acc_health(segments, health.gravity_at(site)))
    mag = mag_recording if mag_recording is not None else (
        recording if recording.has("mag") else None)
    rec.update(_compass(contents, mag, site, user_site, _year(contents.start_unix_s), notes))
    rec.update(health.vibration(msgs))
    rec["notes"] = "; ".join(notes)
    return rec


@single_threaded_blas
def extract(path, site: tuple[float, float, float] | None = None) -> dict:
    """Read and measure one log; a record with ``status`` "ok", or "error" and the ``reason``.

    Parameters
    ----------
    path : str or Path
    site : (lat [deg], lon [deg], alt [m]), optional
        The site for logs without a GPS fix.

    Returns
    -------
    dict

    BLAS runs on one thread (:mod:`apmcal.core.blas_threads`): faster on these small products,
    and the same summation order in every process, so a Dask worker's record is bit for bit
    the one this process would make.
    """
    from apmcal.sources import read_log

    path = Path(path)
    rec = base_record(path)
    try:
        with np.errstate(all="ignore"):
            rec.update(describe(read_log(path), site))
        rec["status"] = "ok"
        if rec.get("start_unix_s") is None:
            rec["notes"] = "; ".join(filter(None, [rec["notes"], "no wall-clock date (no GPS "
                                                   "fix): ordered by file name"]))
    except ApmcalError as err:
        rec["reason"] = str(err)
    except Exception as exc:    # a bug of ours on one file must not stop the fleet run
        rec["reason"] = f"internal error: {type(exc).__name__}: {exc}"
    return rec
