"""Calibration solvers. Each returns a :class:`~apmcal.solvers.result.Calibration`."""
