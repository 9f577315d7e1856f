"""The simulated twin of a real session, made by apmcal's sensor error model
(:mod:`apmcal.sensor_model`) with the fitted parameters.

- :mod:`~apmcal.diagnosis.twin.simulate` — the twin's samples;
- :mod:`~apmcal.diagnosis.twin.draws` — its random draws, made once and replayed;
- :mod:`~apmcal.diagnosis.twin.file` — the selected model as a simulator configuration
  (``apmcal gap --write-twin``);
- :mod:`~apmcal.diagnosis.twin.sitl_params` — the same as ArduPilot SITL parameters (SIM_*).
"""
