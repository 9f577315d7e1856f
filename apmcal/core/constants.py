"""Physical constants, unit conversions and ArduPilot frame conventions.

Frames: body = FRD (x forward, y right, z down); navigation = NED. Accelerometers measure specific
force, so a level vehicle at rest reads (0, 0, -g) m/s² (docs/ardupilot-facts.md, "Frames and signs").
"""
from __future__ import annotations

import math  # not numpy: `apmcal --help` reads DEFAULT_BAUD from here (numpy: ~0.15 s)

STANDARD_GRAVITY = 9.80665          # m/s², the constant ArduPilot uses for mG <-> m/s² (RAW_IMU)
EARTH_RATE = 7.292115e-5            # rad/s, [Oppong] §5.2 (WGS-84 value)
MG_TO_MS2 = STANDARD_GRAVITY / 1000.0   # RAW_IMU acc is in milli-g
MRAD_TO_RAD = 1e-3                  # RAW_IMU gyro is in mrad/s
GAUSS_TO_MGAUSS = 1000.0
UT_TO_MGAUSS = 10.0                 # 1 mGauss = 0.1 µT
# serial links (USB: any rate works; 3DR/SiK telemetry radios: 57600 unless reconfigured;
# MAVProxy's default is 115200 as well)
DEFAULT_BAUD = 115200


def normal_gravity(lat_deg: float, height_m: float = 0.0) -> float:
    """WGS-84 normal gravity [m/s²] at geodetic latitude [deg] and height [m].

    Somigliana's formula with the free-air correction of about 3.086e-6 s⁻² per metre
    (ardupilot-facts.md, "Frames and signs").

    Parameters
    ----------
    lat_deg : float
        Geodetic latitude [deg].
    height_m : float, optional
        Height above the WGS-84 ellipsoid [m].

    Returns
    -------
    float
        Normal gravity [m/s²].
    """
    s2 = math.sin(math.radians(lat_deg)) ** 2
    g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / math.sqrt(1 - 0.00669437999013 * s2)
    return float(g0 - 3.086e-6 * height_m)


def earth_rate_ned(lat_deg: float):
    """Earth rotation rate [rad/s] in the local NED frame: Ω·(cos φ, 0, −sin φ), (3,) array.

    Parameters
    ----------
    lat_deg : float
        Geodetic latitude φ [deg].

    Returns
    -------
    numpy.ndarray, shape (3,)
        Earth rotation rate in north, east, down components [rad/s].
    """
    import numpy as np

    phi = np.radians(lat_deg)
    return EARTH_RATE * np.array([np.cos(phi), 0.0, -np.sin(phi)])
