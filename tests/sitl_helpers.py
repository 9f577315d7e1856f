"""Shared builders for the sitl tests (not a test module)."""
from __future__ import annotations

import numpy as np

from sitl.errors_model import ImuErrorModel
from sitl.truth import Truth
from sitl.vehicle import SimVehicle

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

