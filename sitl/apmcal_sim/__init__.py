"""apmcal_sim — apmcal's simulator: a simulated APM 2.8 vehicle (ArduCopter 3.2 / 3.3) speaking
MAVLink, with a truthful, switchable IMU error model (apmcal's own, :mod:`apmcal.sensor_model`).

It imports apmcal and apmcal never imports it. Its name carries the distribution's: installed at
the top level of site-packages beside apmcal, a generic name such as ``sitl`` could clash with
another package; ``apmcal_sim`` cannot.

- ``python -m apmcal_sim [CONNECTION]`` serves a vehicle (``--help``); ``python -m
  apmcal_sim.makelog`` writes .tlog / .bin logs without real time (see logs/README.md). Both
  take ``--truth FILE`` or ``--twin TWIN.json`` (a twin written by ``apmcal gap --write-twin``)
  instead of a seeded draw.
- In process: ``SimVehicle(truth, script, generation).run_for(seconds)``; ``record=True`` keeps the
  true attitude / rates and every raw and reported sample (``history()``); messages come from
  ``pop_messages()`` and MAVLink input goes to ``handle(msg)``. A twin of a real session drives
  ``apmcal.sensor_model.imu.ImuErrorModel`` directly at the log's rate, with its timestamps,
  attitudes and (``temperature=``) board temperatures.
- ``EFFECTS``: the sitl effect switches; ``Truth``: the injected errors (JSON load/save).
  ``uniform_noise`` and ``triangle_drift`` (``SIMULATOR_QUIRKS``) reproduce ArduPilot's own SITL
  sensors (uniform noise, triangle-wave gyro drift) and are off by default.
- ``DIAGNOSIS_EFFECTS``: the ``apmcal gap`` diagnosis names → sitl switches (bias_drift →
  gyro_bias_drift, bias_random_walk → gyro_bias_random_walk, cross_axis → acc_cross_axis,
  gyro_scale → gyro_scale + gyro_misalignment, the rest by the same name); ``Truth.with_effects``
  and ``--enable/--disable`` accept both vocabularies. ``NOMINAL_EFFECTS``: the switches of the
  nominal model the diagnosis always fits.
- Per-axis parameters: ``acc_noise``, ``gyro_noise``, ``mag_noise``, ``gyro_bias_random_walk``
  take a float or a 3-list; ``lowpass_hz`` a float or ``{"acc": hz, "gyro": hz}``.
- ``FULL_THROTTLE_CURRENT_A``: the simulated battery current is 20 A × throttle, so
  ``mag_interference`` [mGauss per unit throttle] = 20 × [mGauss per A].

Modules: motion (scripts, ``diagnosis`` = Ferraris + motors), firmware (INS_*/COMPASS_*/
AHRS_ORIENTATION per generation), params_store, vehicle, mavlink_vehicle (network endpoint),
logwriter, makelog, geomag (WMM field), cli_common (the options of both commands), errors, and
gap_benchmark (``python -m apmcal_sim.gap_benchmark``: does ``apmcal gap`` find an effect the twin
was not told about?). The error model itself — ``Truth`` (errors, defaults, name mapping) and
``ImuErrorModel`` (the sensor pipeline) — is :mod:`apmcal.sensor_model`'s.
The flight: ``python -m apmcal_sim.flight`` (a scripted multicopter flight written as a 4.x
dataflash log with known compass errors and a biased logged yaw).
The fleet: ``python -m apmcal_sim.fleet`` (logs of several vehicles over weeks with injected
compass drift, compass swap, recalibration, temperature-sensitive gyro, and their truth).
"""
from apmcal.sensor_model.truth import (
    DIAGNOSIS_EFFECTS,
    EFFECTS,
    FULL_THROTTLE_CURRENT_A,
    NOMINAL_EFFECTS,
    SIMULATOR_QUIRKS,
    Truth,
)

__all__ = ["EFFECTS", "DIAGNOSIS_EFFECTS", "NOMINAL_EFFECTS", "SIMULATOR_QUIRKS",
           "FULL_THROTTLE_CURRENT_A", "Truth", "SimVehicle"]


def __getattr__(name):
    if name == "SimVehicle":     # lazy: importing sitl must not pull pymavlink / pygeomag
        from apmcal_sim.vehicle import SimVehicle
        return SimVehicle
    raise AttributeError(name)
