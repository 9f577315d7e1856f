"""apmcal: IMU calibration for ArduPilot flight controllers from a ground station.

Data flow (one sub-package per stage):
    sources/        read logs, CSV files or a live vehicle into :class:`Recording` objects
    preprocessing/  undo the firmware's correction, find static periods, high-pass filter
    solvers/        Ferraris benchmark, one-position static method, ellipsoid fits
    vehicle/        turn a calibration into ArduPilot parameters, write .param files, upload
    diagnosis/      compare simulation with real data
    fleet/          calibration health across many logs of many vehicles, on Dask (apmcal fleet)
"""
from apmcal.core.errors import ApmcalError

__all__ = ["ApmcalError", "Recording", "LogContents"]
__version__ = "0.1.0"


def __getattr__(name: str):
    # Recording and LogContents import pandas: loaded when first asked for, so that the command
    # line starts light and a Ctrl-C during its imports falls inside its own handler (exit 130)
    if name in ("Recording", "LogContents"):
        from apmcal.core import recording

        return getattr(recording, name)
    raise AttributeError(f"module 'apmcal' has no attribute {name!r}")
