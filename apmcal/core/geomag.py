"""Earth's magnetic field from the World Magnetic Model (pygeomag), for any recording date.

pygeomag's default coefficients (WMM2025) refuse dates outside 2025-2030, yet APM 2.x logs date
from 2012 on. Each date is therefore evaluated with the model of its own five-year span (pygeomag
ships WMM2010, 2015v2, 2020 and 2025); a date outside every span is evaluated at the nearest end of
the covered years, and the returned note says so. pygeomag gives nT in north, east, down
components, i.e. NED; ArduPilot reports mGauss (1 mGauss = 100 nT).
"""
from __future__ import annotations

import datetime

import numpy as np

NT_PER_MGAUSS = 100.0
WMM_YEARS = (2010.0, 2030.0)        # first and last year the shipped models cover
LAST_EPOCH = 2025                   # WMM2025 covers 2025.0 to 2030.0 inclusive


def decimal_year(when: datetime.date | datetime.datetime) -> float:
    """A date, or a datetime (UTC; an aware one is converted to UTC), as a decimal year, the
    WMM's time argument.

    Parameters
    ----------
    when : datetime.date or datetime.datetime
        The date; a naive datetime is taken as UTC.

    Returns
    -------
    float
        Decimal year, e.g. 2026.41.
    """
    if isinstance(when, datetime.datetime) and when.tzinfo is not None:
        when = when.astimezone(datetime.timezone.utc)
    start = datetime.date(when.year, 1, 1)
    days = (datetime.date(when.year + 1, 1, 1) - start).days
    day = (when.date() if isinstance(when, datetime.datetime) else when) - start
    seconds = 0.0
    if isinstance(when, datetime.datetime):
        seconds = when.hour * 3600 + when.minute * 60 + when.second + when.microsecond * 1e-6
    return when.year + (day.days + seconds / 86400.0) / days


def earth_field_ned(lat_deg: float, lon_deg: float, alt_m: float,
                    year: float) -> tuple[np.ndarray, str | None]:
    """WMM main field [mGauss] in NED at a site and decimal year, and a note when the year lies
    outside the models' years (the field is then that of the nearest covered year).

    Parameters
    ----------
    lat_deg, lon_deg : geodetic latitude / longitude [deg]
    alt_m : height above the WGS-84 ellipsoid [m] (pygeomag takes km)
    year : decimal year, e.g. 2026.41

    Returns
    -------
    field : numpy.ndarray, shape (3,)
        Main field in north, east, down components [mGauss].
    note : str or None
        Why another year's field was used, or None when ``year`` lies inside the models'.
    """
    from pygeomag import GeoMag

    used = float(np.clip(year, *WMM_YEARS))
    note = None
    if used != year:
        note = (f"{year:.3f} lies outside the World Magnetic Model years "
                f"{WMM_YEARS[0]:.0f}-{WMM_YEARS[1]:.0f}: field of {used:.0f} used")
    res = GeoMag(base_year=min(int(used), LAST_EPOCH)).calculate(glat=float(lat_deg), glon=float(lon_deg),
                                                 alt=float(alt_m) / 1000.0, time=used)
    return np.array([res.x, res.y, res.z]) / NT_PER_MGAUSS, note


def field_uncertainty(lat_deg: float, lon_deg: float, alt_m: float,
                      year: float) -> tuple[float, float, float]:
    """One-σ uncertainty of the WMM at a site and decimal year: total intensity [mGauss],
    inclination and declination [deg].

    The error model of the WMM technical reports ([WMM], "uncertainty estimates", as [pygeomag]'s
    ``calculate_uncertainty`` carries it): global values that include the crustal field the
    model leaves out, so they are also the size of the local anomaly to expect. Years before
    2015 (no error model published with the older models) take the 2015 model's values; years
    after 2030 the 2025 model's.
    """
    from pygeomag import GeoMag

    used = float(np.clip(year, 2015.0, WMM_YEARS[1]))
    res = GeoMag(base_year=min(int(used), LAST_EPOCH)).calculate(
        glat=float(lat_deg), glon=float(lon_deg), alt=float(alt_m) / 1000.0, time=used)
    unc = res.calculate_uncertainty()
    return float(unc.f) / NT_PER_MGAUSS, float(unc.i), float(unc.d)


def field_magnitude(lat_deg: float, lon_deg: float,
                    when: datetime.date | None = None) -> tuple[float, str | None]:
    """|WMM main field| [mGauss] at ground level at a site on a date (today when None), and
    :func:`earth_field_ned`'s note when the date lies outside the models' years.

    Parameters
    ----------
    lat_deg, lon_deg : float
        Geodetic latitude / longitude [deg].
    when : datetime.date, optional
        Date of the field; today when None.

    Returns
    -------
    magnitude : float
        Field magnitude at the site [mGauss].
    note : str or None
        :func:`earth_field_ned`'s note, or None.
    """
    field, note = earth_field_ned(lat_deg, lon_deg, 0.0,
                                  decimal_year(when or datetime.date.today()))
    return float(np.linalg.norm(field)), note

