"""The simulated vehicle's parameter table: defaults per firmware generation, PARAM_SET rules,
persistence across restarts (the EEPROM of a real board) in a JSON file.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from apmcal_sim.errors import SitlError

ROTATION_PARAMS = ("AHRS_ORIENTATION", "COMPASS_ORIENT")
# ArduPilot's AP_Stats (Copter 3.5 and newer, here on the "3.3" table that stands for 3.3 and
# newer): counters the firmware keeps itself, read-only on newer firmware
STAT_PARAMS = ("STAT_BOOTCNT", "STAT_FLTTIME", "STAT_RUNTIME", "STAT_RESET")
# A real vehicle's table: ArduCopter 4.7.0-dev SITL sent 1,349 parameters (observed;
# ardupilot-facts.md "Writing parameters"). The full-size table fills up to this count with
# parameters standing for the rest (flight control, EKF, servos ...) that no calibration uses.
FULL_SIZE_PARAM_COUNT = 1349
_FILLER_GROUPS = ("ATC_", "PSC_", "WPNAV_", "LOIT_", "EK3_", "EK2_", "GPS_", "BATT_", "SERIAL",
                  "FENCE_", "MNT1_", "LOG_", "BRD_", "ARMING_", "FS_", "PILOT_", "RTL_", "LAND_",
                  "TERRAIN_", "AVOID_", "PRX1_", "RNGFND1_", "OSD1_", "NTF_", "CAN_P1_", "SCR_",
                  "MOT_", "SERVO", "RC", "FLOW_")


def rotation_is_simulated(value: float) -> bool:
    """True for an integer rotation code the simulator has a matrix for."""
    from apmcal_sim.firmware import ROTATIONS

    return float(value).is_integer() and int(value) in ROTATIONS


def _xyz(prefix: str, value: float) -> dict:
    return {f"{prefix}_{a}": value for a in "XYZ"}


def filler_params(count: int, taken) -> dict[str, float]:
    """``count`` parameters (value 0) named like the rest of a real table ("EK3_P07"), none
    in ``taken``."""
    out: dict[str, float] = {}
    k = 0
    while len(out) < count:
        name = f"{_FILLER_GROUPS[k % len(_FILLER_GROUPS)]}P{k // len(_FILLER_GROUPS):02d}"
        if name not in taken:
            out[name] = 0.0
        k += 1
    return out


def default_params(generation: str, full_size: bool = False) -> dict[str, float]:
    """Parameter names and defaults of the simulated firmware (neutral corrections); with
    ``full_size``, filled up to FULL_SIZE_PARAM_COUNT names (:func:`filler_params`)."""
    p: dict[str, float] = {"SYSID_THISMAV": 1, "SYSID_SW_TYPE": 10, "AHRS_ORIENTATION": 0,
                           "INS_GYR_CAL": 1, "INS_PRODUCT_ID": 88}
    p.update(_xyz("INS_ACCOFFS", 0.0))
    p.update(_xyz("INS_ACCSCAL", 1.0))
    p.update(_xyz("INS_GYROFFS", 0.0))
    p.update(_xyz("COMPASS_OFS", 0.0))
    p.update(_xyz("COMPASS_MOT", 0.0))
    p.update({"COMPASS_MOTCT": 0, "COMPASS_DEC": 0.0, "COMPASS_ORIENT": 0,
              "COMPASS_EXTERNAL": 0, "COMPASS_USE": 1, "COMPASS_LEARN": 0, "COMPASS_AUTODEC": 1})
    for sr in ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1", "EXTRA2",
               "EXTRA3", "PARAMS"):
        for port in (0, 1):
            p[f"SR{port}_{sr}"] = 0.0 if sr != "PARAMS" else 10.0
    if generation != "3.2":
        # ardupilot-facts.md: DIA/ODI and second/third IMU parameters exist on 3.3+ only
        p.update(_xyz("COMPASS_DIA", 1.0))
        p.update(_xyz("COMPASS_ODI", 0.0))
        p.update(_xyz("INS_ACC2OFFS", 0.0))
        p.update(_xyz("INS_ACC2SCAL", 1.0))
        p.update(_xyz("INS_GYR2OFFS", 0.0))
        p.update(_xyz("INS_ACC3OFFS", 0.0))
        p.update(_xyz("INS_ACC3SCAL", 1.0))
        p.update(_xyz("INS_GYR3OFFS", 0.0))
        p.update({"INS_ACCEL_FILTER": 20.0, "INS_GYRO_FILTER": 20.0, "COMPASS_OFFS_MAX": 1800})
        # per-instance compass scale, default 0 = none (ardupilot-facts.md "How the firmware
        # applies the parameters"); the "3.3" table stands for 3.3 and newer
        p.update({"COMPASS_SCALE": 0.0, "COMPASS_SCALE2": 0.0, "COMPASS_SCALE3": 0.0})
        p.update({name: 0 for name in STAT_PARAMS})
        p.update(tcal_defaults())
    else:
        p["INS_MPU6K_FILTER"] = 20.0
    if full_size:
        p.update(filler_params(FULL_SIZE_PARAM_COUNT - len(p), p))
    return {k: float(np.float32(v)) for k, v in p.items()}


def tcal_defaults() -> dict[str, float]:
    """IMU 1's temperature calibration parameters (ArduPilot 4.1+, stood in for by the "3.3"
    generation) with the firmware's defaults: INS_TCAL1_ENABLE 0, TMIN 0, TMAX 70 [degC],
    ACC1..3 / GYR1..3 _X.._Z 0, INS_ACC1_CALTEMP / INS_GYR1_CALTEMP −300 [degC]
    (AP_InertialSensor_tempcal.cpp and AP_InertialSensor.cpp var_info)."""
    p = {"INS_TCAL1_ENABLE": 0.0, "INS_TCAL1_TMIN": 0.0, "INS_TCAL1_TMAX": 70.0,
         "INS_ACC1_CALTEMP": -300.0, "INS_GYR1_CALTEMP": -300.0}
    for kind in ("ACC", "GYR"):
        for order in (1, 2, 3):
            p.update(_xyz(f"INS_TCAL1_{kind}{order}", 0.0))
    return p


class ParamStore:
    """Ordered parameter table with firmware-like PARAM_SET semantics and optional persistence.

    Parameters
    ----------
    generation : "3.2" or "3.3"
    path : str or Path, optional
        JSON file {name: value}; loaded at start when present, rewritten on every accepted set.
    full_size : bool
        A real vehicle's number of parameters (FULL_SIZE_PARAM_COUNT), not just those the
        simulation uses.
    """

    def __init__(self, generation: str, path: str | Path | None = None,
                 full_size: bool = False):
        self.generation = generation
        self._values = default_params(generation, full_size)
        self.names = sorted(self._values)
        self.path = None if path is None else Path(path)
        if self.path is not None and self.path.exists():
            self._load()

    def _is_parm(self) -> bool:
        return self.path.suffix.lower() in (".parm", ".param", ".params")

    def _load(self) -> None:
        try:
            text = self.path.read_text()
            stored = _parse_parm(text) if self._is_parm() else json.loads(text)
        except (OSError, ValueError) as exc:
            raise SitlError(f"not a parameter file ({exc})", self.path) from None
        if not isinstance(stored, dict):
            raise SitlError("not a parameter file (expected a JSON object)", self.path)
        for name, value in stored.items():
            self.set(name, value, save=False)

    def save(self) -> None:
        """Write every parameter: JSON, or MAVProxy-style ``NAME VALUE`` lines for .parm."""
        if self.path is None:
            return
        if self._is_parm():
            self.path.write_text("".join(f"{k} {v!r}\n" for k, v in sorted(self._values.items())))
        else:
            self.path.write_text(json.dumps(self._values, indent=1, sort_keys=True) + "\n")

    def set(self, name: str, value, save: bool = True) -> float | None:
        """Store ``value`` as float32 like the firmware; returns the stored value, or None when
        the set is dropped silently (unknown name, NaN or inf — ardupilot-facts.md)."""
        if name not in self._values:
            return None
        try:
            v = float(value)
        except (TypeError, ValueError):
            return None
        if not math.isfinite(v):
            return None
        if name in ROTATION_PARAMS and not rotation_is_simulated(v):
            # the real firmware knows more rotations than the simulator models: refuse the set
            # (the ground station sees the old value read back) rather than stop the vehicle
            return None
        self._values[name] = float(np.float32(v))
        if save:
            self.save()
        return self._values[name]

    def declare(self, name: str, value: float) -> None:
        """Add a parameter the default table lacks (e.g. a fleet vehicle's COMPASS_DEV_ID) with
        ``value`` (float32), or overwrite it; not saved."""
        if name not in self._values:
            self.names = sorted([*self._values, name])
        self._values[name] = float(np.float32(value))

    def answered_set_with(self, name: str) -> list[str]:
        """The names whose PARAM_VALUE answers a PARAM_SET of ``name``.

        ArduPilot's AP_Param::send_parameter: a set of a Vector3f's first element is answered
        with all three elements, _X, _Y, _Z (its save cannot tell the vector from its first
        element); a set of _Y or _Z with that element alone. Seen on
        ArduCopter 4.7.0-dev SITL (INS_ACCOFFS_X set: PARAM_VALUE INS_ACCOFFS_X, _Y, _Z); not
        in ardupilot-facts.md. Every X/Y/Z triple of this table is a Vector3f in ArduPilot.
        """
        if name.endswith("_X"):
            vector = [name[:-1] + axis for axis in "XYZ"]
            if all(n in self._values for n in vector):
                return vector
        return [name]

    def get(self, name: str, default: float | None = None) -> float | None:
        """The value of ``name``, or ``default`` when there is no such parameter."""
        return self._values.get(name, default)

    def index(self, name: str) -> int:
        """``name``'s param_index (its position in :attr:`names`)."""
        return self.names.index(name)

    def __contains__(self, name: str) -> bool:
        return name in self._values

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __len__(self) -> int:
        return len(self._values)

    def as_dict(self) -> dict[str, float]:
        """A copy of all parameters, name → value."""
        return dict(self._values)


def _parse_parm(text: str) -> dict[str, str]:
    """``NAME VALUE`` or ``NAME,VALUE`` lines, ``#`` comments (ardupilot-facts.md)."""
    out = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        if len(parts) < 2:
            raise ValueError(f"line {n}: expected NAME VALUE")
        out[parts[0]] = parts[1]
    return out
