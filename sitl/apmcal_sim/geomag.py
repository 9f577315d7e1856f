"""Earth magnetic field at the home position from the World Magnetic Model.

The model and its date handling are apmcal's (:mod:`apmcal.core.geomag`: the WMM of the date's own
five-year span, the nearest covered year outside them), so the simulated vehicle and the
calibration agree on the field for any date. Units: mGauss, NED frame.
"""
from __future__ import annotations

import datetime

import numpy as np

from apmcal.core import geomag


def earth_field_ned(lat_deg: float, lon_deg: float, alt_m: float = 0.0,
                    year: float = 2026.0) -> np.ndarray:
    """WMM main field at a site [mGauss], NED frame.

    Parameters
    ----------
    lat_deg, lon_deg : float
        Geodetic latitude / longitude [deg].
    alt_m : float
        Height above the WGS-84 ellipsoid [m].
    year : float
        Decimal year (outside 2010-2030 the nearest covered year is used).
    """
    return geomag.earth_field_ned(lat_deg, lon_deg, alt_m, year)[0]


def decimal_year(unix_s: float) -> float:
    """Unix time [s] → decimal year (UTC), the time argument of the WMM."""
    when = datetime.datetime.fromtimestamp(unix_s, tz=datetime.timezone.utc)
    return geomag.decimal_year(when)
