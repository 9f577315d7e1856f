"""Shared builders for the sitl tests (not a test module)."""
from __future__ import annotations

import numpy as np

from apmcal.sensor_model.imu import ImuErrorModel
from apmcal.sensor_model.truth import Truth
from apmcal_sim.vehicle import SimVehicle

G0 = 9.80665


def only(*effects, seed=3, lat=None, alt=None, **truth_fields) -> Truth:
    """A random truth with every effect off except ``effects``."""
    site = None
    if lat is not None:
        site = {"lat": lat, "lon": 10.0, "alt": alt or 0.0, "year": 2026.0}
    t = Truth.random(seed, site).with_effects(disable=["all"], enable=list(effects))
    for k, v in truth_fields.items():
        setattr(t, k, v)
    return t


def run(truth: Truth, seconds: float, script="onepos", generation="3.2", **kw) -> tuple:
    """Recorded in-process vehicle after ``seconds`` (boot gyro calibration off)."""
    v = SimVehicle(truth, script, generation, record=True, seed=kw.pop("seed", 5),
                   duration=kw.pop("duration", None), **kw)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    v.run_for(seconds)
    return v, v.history()


def still(truth: Truth, seconds: float, fs: float = 1000.0, seed: int = 5, temperature=None,
          t0: float = 0.0) -> dict:
    """ImuErrorModel driven directly (as the diagnosis twin does) at rate ``fs``: board level and
    still, throttle 0, no Earth rate; raw acc / gyro / mag samples and their times."""
    n = int(round(seconds * fs))
    t = t0 + np.arange(n) / fs
    f = np.tile([0.0, 0.0, -G0], (n, 1))
    m = ImuErrorModel(truth, fs, seed)
    return {"t": t, "model": m, "acc": m.accel(t, f, temperature=temperature),
            "gyr": m.gyro(t, np.zeros((n, 3)), f, temperature=temperature),
            "mag": m.mag(np.tile([300.0, 0.0, 200.0], (n, 1)), np.zeros(n))}


def messages(v: SimVehicle, kind: str) -> list:
    return [m for _, m in v.pop_messages() if m.get_type() == kind]



def session_recording(seed: int, disable=(), enable=(), script: str = "ferraris",
                      fs: float = 50.0, mag: bool = False):
    """A whole sitl session's raw acc/gyr samples in one pass of the error model, at ``fs``.

    The vehicle's script, tremor, Earth rate, gravity and every enabled effect as in
    ``python -m apmcal_sim.makelog``, but without the telemetry (no RAW_IMU int16 rounding, no
    firmware correction to undo): a ferraris session in about 0.3 s instead of 40.
    ``mag``: also the compass samples. Returns (Truth, apmcal Recording, SimVehicle).
    """
    import pandas as pd

    from apmcal.core.recording import Recording
    from apmcal_sim.cli_common import DEFAULT_SITE

    truth = Truth.random(seed, dict(DEFAULT_SITE)).with_effects(disable=list(disable))
    truth = truth.with_effects(enable=list(enable))
    v = SimVehicle(truth, script, "3.2", None, fs=fs, seed=seed)
    t = np.arange(int((v.motion.duration + 1.0) * fs)) / fs
    s = v._sense(t)         # one block: the model's filters and noise see one long series
    cols = {"t": t}
    for key in ("acc", "gyr", "mag") if mag else ("acc", "gyr"):
        cols.update({f"{key}_{a}": s["raw_" + key][:, i] for i, a in enumerate("xyz")})
    return truth, Recording(pd.DataFrame(cols), source=f"sitl seed {seed}", message="sim"), v


def sigma_z(truth: Truth, cal, vehicle) -> dict:
    """(estimate − truth)/σ per parameter of acc and gyr ("acc.offset" → (3,) array, ...).

    The gyro offset is the bias at t_ref, the session's mean hold time, and is compared with
    the bias the simulated gyro had then: b + drift·t_ref + its temperature term at the board
    temperature of t_ref. A static session cannot tell a bias at 31 °C from one at 25 °C.
    """
    true = truth.sensor_calibrations()
    z = {}
    for name in ("acc", "gyr"):
        est, tru = cal.sensors[name], true[name]
        offset = tru.offset + tru.drift * (est.t_ref - tru.t_ref)
        if name == "gyr" and truth.on("temperature_drift"):
            warm = vehicle.model.temperature(np.array([est.t_ref]))[0]
            offset = offset + np.asarray(truth.temperature["gyro_coef"]) * (
                warm - truth.temperature["ambient_c"])
        z[f"{name}.offset"] = (est.offset - offset) / est.sigma["offset"]
        z[f"{name}.matrix"] = ((est.matrix - tru.matrix) / est.sigma["matrix"]).ravel()
    return z
