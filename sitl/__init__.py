"""sitl — a simulated APM 2.8 vehicle (ArduCopter 3.2 / 3.3) speaking MAVLink, with a truthful,
switchable IMU error model.

- ``python -m sitl [CONNECTION]`` serves a vehicle (``--help``); ``python -m sitl.makelog`` writes
  .tlog / .bin logs without real time (see logs/README.md).
- In process: ``SimVehicle(truth, script, generation).run_for(seconds)``; ``record=True`` keeps the
  true attitude / rates and every raw and reported sample (``history()``); messages come from
  ``pop_messages()`` and MAVLink input goes to ``handle(msg)``.
- ``EFFECTS``: the canonical effect names; ``Truth``: the injected errors (JSON load/save).

Modules: truth (errors + defaults), errors_model (sensor pipeline), motion (scripts),
firmware (INS_*/COMPASS_*/AHRS_ORIENTATION per generation), params_store, vehicle, mavlink_vehicle
(network endpoint), logwriter, makelog, geomag (WMM field).
"""
from sitl.truth import EFFECTS, Truth

__all__ = ["EFFECTS", "Truth", "SimVehicle"]


def __getattr__(name):
    if name == "SimVehicle":     # lazy: importing sitl must not pull pymavlink / pygeomag
        from sitl.vehicle import SimVehicle
        return SimVehicle
    raise AttributeError(name)
