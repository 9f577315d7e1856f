"""The IMU and compass error model that apmcal's simulator (``apmcal_sim``) draws from and the gap
diagnosis twins a real board with: the library's own, so that it stands without the simulator.

- :mod:`~apmcal.sensor_model.truth` — :class:`Truth`, a board's error parameters (offsets,
  scales, misalignment, drifts, noise, filters, hard and soft iron ...) with their JSON file, and
  the effect catalogue: ``EFFECTS`` (the switches), ``DIAGNOSIS_EFFECTS`` (the gap diagnosis's
  names for them), ``NOMINAL_EFFECTS``, ``SIMULATOR_QUIRKS``;
- :mod:`~apmcal.sensor_model.imu` — :class:`ImuErrorModel`, true motion in, raw sensor samples out.
"""
