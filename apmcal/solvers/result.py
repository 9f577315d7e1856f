"""Calibration results that apply themselves to samples and save/load themselves.

Convention (the same for every sensor, every solver, the CLI's JSON and sitl's --truth file)::

    calibrated = matrix @ (measured - offset - drift * (t - t_ref))

in SI units after conversion (accelerometer m/s², gyroscope rad/s, magnetometer mGauss), in the
frame of the measured samples. ``drift`` is only non-zero for a gyroscope with a bias linear in
time (seed 002 eq. 5).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apmcal.errors import ApmcalError


@dataclass
class SensorCalibration:
    """Offset, matrix (and gyro drift) of one sensor, with one-sigma uncertainties.

    Attributes
    ----------
    offset : (3,) array, sensor units
    matrix : (3, 3) array, dimensionless
    drift : (3,) array, sensor units per second (gyro bias drift), zeros otherwise
    t_ref : float, time [s] at which ``offset`` holds
    sigma : dict of name -> array, one-sigma uncertainties ("offset", "matrix", "drift")
    """

    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    drift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t_ref: float = 0.0
    sigma: dict = field(default_factory=dict)

    def __post_init__(self):
        self.offset = np.asarray(self.offset, dtype=float).reshape(3)
        self.matrix = np.asarray(self.matrix, dtype=float).reshape(3, 3)
        self.drift = np.asarray(self.drift, dtype=float).reshape(3)
        self.sigma = {k: np.asarray(v, dtype=float) for k, v in self.sigma.items()}

    def apply(self, samples: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """Calibrate (n, 3) ``samples`` (times ``t`` [s] needed only when drift is non-zero)."""
        x = np.asarray(samples, dtype=float) - self.offset
        if np.any(self.drift):
            if t is None:
                raise ValueError("this calibration has a bias drift: pass the sample times t")
            x = x - np.outer(np.asarray(t, dtype=float) - self.t_ref, self.drift)
        return x @ self.matrix.T

    def invert(self, calibrated: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """The measured samples that :meth:`apply` maps to ``calibrated`` (used by the simulator)."""
        x = np.linalg.solve(self.matrix, np.asarray(calibrated, dtype=float).T).T + self.offset
        if np.any(self.drift):
            if t is None:
                raise ValueError("this calibration has a bias drift: pass the sample times t")
            x = x + np.outer(np.asarray(t, dtype=float) - self.t_ref, self.drift)
        return x

    def to_dict(self) -> dict:
        d = {"offset": self.offset.tolist(), "matrix": self.matrix.tolist(),
             "sigma": {k: np.asarray(v).tolist() for k, v in self.sigma.items()}}
        if np.any(self.drift):
            d["drift"] = self.drift.tolist()
            d["t_ref"] = self.t_ref
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SensorCalibration":
        return cls(offset=d["offset"], matrix=d["matrix"], drift=d.get("drift", np.zeros(3)),
                   t_ref=d.get("t_ref", 0.0), sigma=d.get("sigma", {}))


@dataclass
class Calibration:
    """The result of one calibration run: per-sensor corrections plus what produced them.

    ``sensors`` maps "acc", "gyr", "mag" to :class:`SensorCalibration`. ``params`` holds the
    ArduPilot parameters proposed for this result (filled by :mod:`apmcal.vehicle.params`),
    ``report`` free-form diagnostics (residuals, identifiability, warnings).
    """

    method: str
    sensors: dict[str, SensorCalibration] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    report: dict = field(default_factory=dict)

    def apply(self, sensor: str, samples: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        return self.sensors[sensor].apply(samples, t)

    def to_dict(self) -> dict:
        d = {"method": self.method}
        d.update({name: cal.to_dict() for name, cal in self.sensors.items()})
        d["params"] = dict(self.params)
        d["report"] = jsonable(self.report)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Calibration":
        sensors = {k: SensorCalibration.from_dict(d[k]) for k in ("acc", "gyr", "mag") if k in d}
        return cls(method=d.get("method", ""), sensors=sensors, params=d.get("params", {}),
                   report=d.get("report", {}))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "Calibration":
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ApmcalError(f"not a calibration file ({exc})", path) from None


def jsonable(obj, nan_as_null: bool = False):
    """numpy arrays and scalars → plain lists and numbers, recursively; with ``nan_as_null``
    NaN and infinity → None (strict JSON has neither)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v, nan_as_null) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist(), nan_as_null)
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, nan_as_null) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if nan_as_null and isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj
