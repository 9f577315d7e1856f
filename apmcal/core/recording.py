"""The one recording model every source produces and every later stage consumes.

A :class:`Recording` is one sensor instance (IMU 0, IMU 1, ...) from one source. Its samples are a
:class:`pandas.DataFrame` with SI columns:

    t                      [s]       time since the source's own epoch (boot or log start)
    acc_x, acc_y, acc_z    [m/s²]    specific force
    gyr_x, gyr_y, gyr_z    [rad/s]
    mag_x, mag_y, mag_z    [mGauss]  (only when the source has a magnetometer on this instance)
    temp                   [°C]      (only when present)
    current                [A]       battery current, linearly interpolated at the sample times,
                                     NaN outside the span of the current records (only when the
                                     log carries a usable one: dataflash BAT/CURR, tlog
                                     SYS_STATUS; see the readers). Not a sensor: ``sensors``
                                     never lists it.

Columns that the source does not carry are absent, never filled with zeros. ``corrected`` says
whether the firmware already applied its INS_*/COMPASS_* parameters (ArduPilot's RAW_IMU, IMU and
MAG log messages are corrected: docs/ardupilot-facts.md, "What the telemetry really carries").
``frame`` is "body" when AHRS_ORIENTATION was applied (ArduPilot's outputs), "sensor" otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

ACC = ["acc_x", "acc_y", "acc_z"]
GYR = ["gyr_x", "gyr_y", "gyr_z"]
MAG = ["mag_x", "mag_y", "mag_z"]
SENSOR_COLUMNS = {"acc": ACC, "gyr": GYR, "mag": MAG}


@dataclass
class Recording:
    """Samples of one sensor instance plus what is known about how they were made.

    Attributes
    ----------
    data : pandas.DataFrame
        The samples, one row each, in the SI columns listed in the module docstring
        (t [s], acc_* [m/s²], gyr_* [rad/s], mag_* [mGauss], temp [°C], current [A]).
    source : str
        File path or connection string.
    message : str
        The message the samples came from, e.g. "RAW_IMU", "IMU", "IMU2", "ACC1", "csv".
    instance : int
        Sensor instance (IMU 0, IMU 1, ...).
    vehicle, firmware : str or None
        E.g. "ArduCopter" and "ArduCopter V3.2.1", when the source names them.
    params : dict of str to float
        Parameters in force while recording.
    corrected : bool
        True when the firmware already applied its offsets and scales to the samples.
    frame : str
        "sensor", or "body" when AHRS_ORIENTATION was applied.
    """

    data: pd.DataFrame
    source: str = ""                     # file path or connection string
    message: str = ""                    # e.g. "RAW_IMU", "IMU", "IMU2", "ACC1", "csv"
    instance: int = 0
    vehicle: str | None = None           # e.g. "ArduCopter"
    firmware: str | None = None          # e.g. "ArduCopter V3.2.1"
    params: dict[str, float] = field(default_factory=dict)   # in force while recording
    corrected: bool = False              # firmware offsets/scales already applied
    frame: str = "sensor"                # "sensor" or "body"

    def has(self, sensor: str) -> bool:
        """True if all three columns of ``sensor`` ("acc", "gyr", "mag") are present."""
        return all(c in self.data.columns for c in SENSOR_COLUMNS[sensor])

    @property
    def sensors(self) -> list[str]:
        """The sensors ("acc", "gyr", "mag") whose three columns are all present."""
        return [s for s in SENSOR_COLUMNS if self.has(s)]

    @property
    def t(self) -> np.ndarray:
        """Time [s] as a float64 array, shape (n,)."""
        return self.data["t"].to_numpy(dtype=float)

    def xyz(self, sensor: str) -> np.ndarray:
        """(n, 3) float64 array of ``sensor`` ("acc" m/s², "gyr" rad/s, "mag" mGauss).

        Parameters
        ----------
        sensor : str
            "acc", "gyr" or "mag".

        Returns
        -------
        numpy.ndarray, shape (n, 3)
            x, y, z columns of the sensor in its SI unit.
        """
        return self.data[SENSOR_COLUMNS[sensor]].to_numpy(dtype=float)

    @property
    def duration(self) -> float:
        """Time [s] from the first to the last sample (0 when fewer than two samples)."""
        t = self.t
        return float(t[-1] - t[0]) if len(t) > 1 else 0.0

    @property
    def rate_hz(self) -> float:
        """Median sample rate [Hz] (0 when fewer than two samples)."""
        t = self.t
        if len(t) < 2:
            return 0.0
        dt = np.median(np.diff(t))
        return float(1.0 / dt) if dt > 0 else 0.0

    def __len__(self) -> int:
        return len(self.data)


@dataclass(frozen=True)
class ParamChange:
    """A calibration parameter that took a new value after the log's IMU samples had begun.

    The firmware corrects every sample with the parameters in force at that moment, so samples
    before and after the change cannot be un-corrected with one parameter set.
    """

    name: str
    old: float                 # value before (the last one seen, possibly before the samples)
    new: float
    time_s: float | None       # on the recordings' time axis [s]; None when the log cannot tell
    where: str                 # e.g. "PARM record at byte 12345", "PARAM_VALUE at byte 678"

    def __str__(self) -> str:
        when = f" at t={self.time_s:.3f} s" if self.time_s is not None else ""
        return f"{self.name} changed from {self.old:g} to {self.new:g}{when} ({self.where})"


@dataclass
class LogContents:
    """Everything a reader found in one file."""

    path: str
    format: str                                    # "tlog", "bin", "log", "csv"
    recordings: list[Recording] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)   # last value of each parameter
    vehicle: str | None = None
    firmware: str | None = None
    messages: list[str] = field(default_factory=list)        # STATUSTEXT / MSG texts
    bytes_skipped: int = 0                         # garbage or damaged bytes passed over
    damaged_at: list[int] = field(default_factory=list)      # byte offsets where damage began
    # correction parameters (apmcal.ardupilot.names.CORRECTION_PARAM_PREFIXES) that changed value
    # after the first IMU/MAG sample, in file order; ``params`` keeps the last value of each
    param_changes: list[ParamChange] = field(default_factory=list)
    # wall-clock time of the first sample [s since 1970, UTC] when the file carries one (a
    # .tlog's per-frame timestamps, a dataflash GPS fix); None otherwise. Dates the WMM field.
    start_unix_s: float | None = None
