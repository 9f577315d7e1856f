"""Calibration solvers: numbers in, a result with σ out; they never read files.

Results: :mod:`~apmcal.solvers.result` (:class:`Calibration`, :class:`SensorCalibration`, which
apply, save and load themselves) and :mod:`~apmcal.solvers.report_types` (what a run found).
Methods: :mod:`~apmcal.solvers.ferraris` (six faces and three turns, [Ferraris], [Oppong] §4,
with :mod:`~apmcal.solvers.gyro_bias` and :mod:`~apmcal.solvers.misfit`),
:mod:`~apmcal.solvers.one_position` ([Oppong] §5), :mod:`~apmcal.solvers.holds` (methods on
still periods found beforehand), :mod:`~apmcal.solvers.ellipsoid` (subpackage),
:mod:`~apmcal.solvers.magnetometer` (the compass's own fit), :mod:`~apmcal.solvers.joint`
(subpackage, [Chow]), :mod:`~apmcal.solvers.tcal` (ArduPilot's temperature polynomial).
Shared: :mod:`~apmcal.solvers.coverage`, :mod:`~apmcal.solvers.identifiability`,
:mod:`~apmcal.solvers.uncertainty`, :mod:`~apmcal.solvers.resolution_floor`,
:mod:`~apmcal.solvers.strapdown`.
Flight compass: :mod:`~apmcal.solvers.compass_flight` (the yaw-free fit of COMPASS_OFS/DIA/
ODI/MOT to a flight, and the orientation search) and :mod:`~apmcal.solvers.compass_heading`
(the heading error in degrees of a compass calibration along a flight, with its verdict).
"""
