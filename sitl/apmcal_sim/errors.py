"""The simulator's user-facing error: apmcal's own one-line error type, so that the simulator's
command line catches the mistakes of its own options and those the sensor model
(:mod:`apmcal.sensor_model`) finds in a truth file with one ``except``."""
from __future__ import annotations

from apmcal.core.errors import ApmcalError


class SitlError(ApmcalError):
    """Bad input to the simulator: ``path: where: why`` on one line (see ApmcalError)."""
