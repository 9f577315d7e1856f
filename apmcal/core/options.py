"""What the user chose: the calibration options the command line passes to the pipeline.

A module of its own, without numpy or pandas, so that ``apmcal gap`` can hand the options to
the worker that reads the log before the main process has imported anything heavy
(:mod:`apmcal.cli.gap`).
"""
from __future__ import annotations

import datetime
from dataclasses import dataclass

from apmcal.core.constants import STANDARD_GRAVITY, normal_gravity


@dataclass
class Options:
    """What the user chose (the CLI's calibration options).

    Attributes
    ----------
    method : {"auto", "ferraris", "static", "ellipsoid", "joint"}
    lat_deg, lon_deg : float or None
        Site [deg]: Earth rate, normal gravity, WMM field.
    min_still_s : float
        Shortest still period counted as a hold [s].
    instance : int or None
        IMU instance (None: the first).
    generation : str or None
        "3.2" / "3.3+" (None: from the log).
    date : datetime.date or None
        Recording date, for the WMM field (None: today).
    """

    method: str = "auto"
    lat_deg: float | None = None          # site: Earth rate, normal gravity, WMM field
    lon_deg: float | None = None
    min_still_s: float = 2.0              # shortest still period counted as a hold [s]
    instance: int | None = None           # IMU instance (None: the first)
    generation: str | None = None         # "3.2" / "3.3+" (None: from the log)
    date: datetime.date | None = None     # recording date, for the WMM field (None: today)

    @property
    def gravity(self) -> float:
        """WGS-84 normal gravity at the latitude, or standard gravity when unknown [m/s²]."""
        return STANDARD_GRAVITY if self.lat_deg is None else normal_gravity(self.lat_deg)
