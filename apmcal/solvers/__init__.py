"""Calibration solvers. Each returns a :class:`~apmcal.solvers.result.Calibration`.

Except: compass_flight (yaw-free fit of COMPASS_OFS/DIA/ODI/MOT to a flight, and the orientation
search) and compass_heading (heading error in degrees of a compass calibration along a flight,
verdict good/usable/redo), which return their own small results.
"""
