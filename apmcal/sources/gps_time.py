"""Wall-clock time of a dataflash log from its GPS records.

A dataflash log's own clock counts from boot; only a GPS record with a fix ties it to a date.
Two layouts exist: newer logs write ``GPS`` with TimeUS (boot, µs), GWk (GPS week) and GMS (ms of
the week); older ones (Copter 3.1/3.2, APM 2.x) write TimeMS as the ms of the GPS week, Week, and
T as the boot time in ms.
"""
from __future__ import annotations

import numpy as np

GPS_EPOCH_UNIX_S = 315964800.0     # 1980-01-06 00:00:00 UTC, the start of GPS week 0
SECONDS_PER_WEEK = 604800.0
# GPS time runs ahead of UTC by the leap seconds since 1980: 18 s since 2017. Older logs are off
# by 1-2 s more; the time only dates the magnetic field model, where seconds do not matter.
GPS_MINUS_UTC_S = 18.0
MIN_FIX_STATUS = 3                 # GPS Status: 3 = 3D fix (ArduPilot AP_GPS::GPS_Status)

#: columns of the GPS record this module reads (both layouts)
GPS_TIME_COLUMNS = {"Status", "TimeUS", "GWk", "GMS", "TimeMS", "Week", "T"}


def boot_to_unix_offset(gps: dict[str, np.ndarray]) -> float | None:
    """Unix time [s] of the log's boot (time 0 of its clock), from the first GPS record with a
    3D fix and a week number; None when the log has none (no GPS, or never a fix).

    Parameters
    ----------
    gps : dict of str to numpy.ndarray
        The GPS record's columns (:data:`GPS_TIME_COLUMNS`), one entry per record.

    Returns
    -------
    float or None
        Unix time [s] at boot time 0.
    """
    layout = _layout(gps)
    if layout is None:
        return None
    week_col, ms_col, boot_col, boot_scale = layout
    fix = (np.asarray(gps["Status"]) >= MIN_FIX_STATUS) & (np.asarray(gps[week_col]) > 0)
    if not fix.any():
        return None
    i = int(np.argmax(fix))
    gps_s = float(gps[week_col][i]) * SECONDS_PER_WEEK + float(gps[ms_col][i]) * 1e-3
    unix_s = GPS_EPOCH_UNIX_S + gps_s - GPS_MINUS_UTC_S
    return unix_s - float(gps[boot_col][i]) * boot_scale


def _layout(gps: dict) -> tuple[str, str, str, float] | None:
    """(week column, ms-of-week column, boot-time column, its scale to s), or None."""
    if "Status" not in gps:
        return None
    if {"GWk", "GMS", "TimeUS"} <= gps.keys():
        return "GWk", "GMS", "TimeUS", 1e-6
    if {"Week", "TimeMS", "T"} <= gps.keys():
        return "Week", "TimeMS", "T", 1e-3
    return None
