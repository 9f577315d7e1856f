"""apmcal: IMU calibration for ArduPilot flight controllers from a ground station.

Data flow (one sub-package per stage):
    sources/        read logs, CSV files or a live vehicle into :class:`Recording` objects
    preprocessing/  undo the firmware's correction, find static periods, high-pass filter
    solvers/        Ferraris benchmark, one-position static method, ellipsoid fits
    vehicle/        turn a calibration into ArduPilot parameters, write .param files, upload
    diagnosis/      compare simulation with real data
"""
from apmcal.errors import ApmcalError
from apmcal.recording import Recording, LogContents

__all__ = ["ApmcalError", "Recording", "LogContents"]
__version__ = "0.1.0"
