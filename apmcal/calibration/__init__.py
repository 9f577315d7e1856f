"""From a log (or a guided live session) to a calibration: the one layer that joins reading,
preparation and the solvers, and builds each result once.

- :mod:`~apmcal.calibration.log` — :func:`calibrate` (one recording) and :func:`calibrate_log`
  (one IMU instance of a log and its compass, with the ArduPilot parameters proposed): the
  method chosen from the still periods, the compass fitted on its own;
- :mod:`~apmcal.calibration.joint` — the joint 42-parameter method ([Chow]) on a prepared
  session;
- :mod:`~apmcal.calibration.tcal` — ArduPilot's temperature calibration (``apmcal tcal``);
- :mod:`~apmcal.calibration.guided` — the six accelerometer-calibration poses recorded live,
  prompted and checked one by one;
- :mod:`~apmcal.calibration.validation` and :mod:`~apmcal.calibration.orientation_check` —
  methods scored out of sample by the orientation change between still poses ([Chow] §5).
- :mod:`~apmcal.calibration.flight` — the compass from an ordinary flight log: health check in
  heading degrees, COMPASS_* proposal with σ, orientation search (``apmcal log FLIGHT``);
- :mod:`~apmcal.calibration.health` — the health of the calibration in force on one log as
  logged, shared by ``apmcal log`` and ``apmcal fleet``: the flight compass check's figures per
  compass on a flight, the compass's sphere residual on a session that turns it, gyro bias and
  temperature, |specific force| − g, vibration.
- :mod:`~apmcal.calibration.flight_proposal` — what of a flight's compass proposal may be
  written, and the flight log's firmware it is judged for.
"""
