"""Earth magnetic field at the home position from the World Magnetic Model (pygeomag).

pygeomag returns the field in nT as north (x), east (y), down (z) components, i.e. already in
NED; ArduPilot reports the magnetometer in mGauss (1 mGauss = 100 nT, so nT × 0.01).
"""
from __future__ import annotations

import datetime

import numpy as np
from pygeomag import GeoMag

NT_TO_MGAUSS = 0.01


def earth_field_ned(lat_deg: float, lon_deg: float, alt_m: float = 0.0,
                    year: float = 2026.0) -> np.ndarray:
    """WMM main field at a site [mGauss], NED frame.

    Parameters
    ----------
    lat_deg, lon_deg : float
        Geodetic latitude / longitude [deg].
    alt_m : float
        Height above the WGS-84 ellipsoid [m] (pygeomag takes km).
    year : float
        Decimal year; must lie within the coefficient file's validity (WMM2025: 2025-2030).
    """
    res = GeoMag().calculate(glat=float(lat_deg), glon=float(lon_deg), alt=float(alt_m) / 1000.0,
                             time=float(year))
    return np.array([res.x, res.y, res.z]) * NT_TO_MGAUSS


def decimal_year(unix_s: float) -> float:
    """Unix time [s] → decimal year (UTC), the time argument of the WMM."""
    when = datetime.datetime.fromtimestamp(unix_s, tz=datetime.timezone.utc)
    start = datetime.datetime(when.year, 1, 1, tzinfo=datetime.timezone.utc)
    end = datetime.datetime(when.year + 1, 1, 1, tzinfo=datetime.timezone.utc)
    return when.year + (when - start) / (end - start)
