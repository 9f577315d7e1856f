"""apmcal: IMU calibration for ArduPilot flight controllers from a ground station.

The front door for Python users (each name imported when first used, so that ``import apmcal``
and the command line start light)::

    import apmcal
    result = apmcal.calibrate("logs/ferraris.tlog", lat_deg=5.6037, lon_deg=-0.187)
    result.verdict["overall"].grade         # "good" / "usable" / "redo"
    result.calibration.apply("acc", raw)    # calibrated samples; .save(path), Calibration.load
    result.proposal.values                  # the ArduPilot parameters proposed

- :func:`calibrate` — a log file (or a :class:`Recording`) to a :class:`SessionReport`: the
  calibration with its report, the parameters proposed and the verdict;
- :func:`read_log` — what a .tlog, .bin, .log or .csv file holds (:class:`LogContents`);
- :class:`Options`, :class:`Calibration`, :class:`Recording`, :class:`ApmcalError`.

The package, in the order the data flows (each subpackage's docstring maps its modules):

    core/           the shared vocabulary: Recording, Options, constants, errors, WMM field
    ardupilot/      ArduPilot's parameters and their meaning (correction formulas, limits, files)
    sources/        read logs, CSV files or a live vehicle into LogContents
    preprocessing/  undo the firmware's correction, find still periods, high-pass filter
    solvers/        Ferraris, one-position, ellipsoid, joint, compass, temperature fits
    calibration/    joins the stages: a log (or live session) to one Calibration
    report/         verdicts and the report a person reads
    link/           MAVLink to a vehicle: parameters, verified upload and restore
    sensor_model/   the IMU error model the gap diagnosis twins a board with
    diagnosis/      the gap between a real board and its simulation (apmcal gap)
    fleet/          calibration health across many logs of many vehicles, on Dask (apmcal fleet)
    cli/            the command line, one module per command
    ui/             apmcal ui: the whole tool in the browser, beside the command line
"""
from __future__ import annotations

from apmcal.core.errors import ApmcalError

__all__ = ["calibrate", "read_log", "Options", "Calibration", "SessionReport", "Recording",
           "LogContents", "ApmcalError"]
__version__ = "0.1.0"

# name → module it lives in; imported when first asked for (pandas, numpy and scipy are not
# needed by `apmcal --help`, and a Ctrl-C during their import falls inside the CLI's handler)
_LAZY = {"read_log": "apmcal.sources", "Options": "apmcal.core.options",
         "Calibration": "apmcal.solvers.result", "SessionReport": "apmcal.report.session",
         "Recording": "apmcal.core.recording", "LogContents": "apmcal.core.recording",
         "calibrate": "apmcal.report.session"}


def __getattr__(name: str):
    if name in _LAZY:
        from importlib import import_module

        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'apmcal' has no attribute {name!r}")
