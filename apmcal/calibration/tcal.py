"""From a log to ArduPilot temperature-calibration parameters (``apmcal tcal``).

The one place joining the temperature-calibration stages, as :mod:`apmcal.calibration.log` does for
the other calibrations: sources (IMU samples with temperature, or the learner's TCLR records)
→ preprocessing (the firmware's offsets, scales and AHRS_ORIENTATION undone by
:func:`apmcal.preprocessing.prepare.prepare`; a temperature calibration in force added back; still periods;
block means) → solver (:func:`apmcal.solvers.tcal.fit_tcal`) → parameters
(:mod:`apmcal.ardupilot.tcal_params`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from apmcal.ardupilot.tcal_params import TEMP_RANGE_MIN_C, tcal_from_params, tcal_param_values
from apmcal.core.errors import ApmcalError
from apmcal.core.json_file import write_json
from apmcal.preprocessing.resolution import INT16_TELEMETRY
from apmcal.solvers.tcal import TcalFit, fit_tcal

RECORDS = ("auto", "imu", "tclr")
SIGNIFICANT_SIGMAS = 2.0    # a linear drift coefficient c1 beyond 2σ of zero: a drift was seen


@dataclass
class TcalResult:
    """The temperature calibration of one IMU instance.

    ``fits``: "acc" / "gyr" → :class:`TcalFit`; ``source``: the records fitted ("IMU", "IMU2",
    "RAW_IMU", ..., or "TCLR"); ``tmin_c`` / ``tmax_c``: the temperature range of the data
    [°C] (written as INS_TCALn_TMIN / TMAX, as the firmware's learner does).

    Attributes
    ----------
    instance : int
        IMU instance, 0-based.
    source : str
    fits : dict of str to TcalFit
    tmin_c, tmax_c : float
        Temperature range [°C].
    still_s : float or None
        Total still time fitted [s]; None for TCLR records.
    notes : list of str
        What was undone, and caveats of the fit.
    blocks : dict or None
        The data fitted, for figures (not saved): "acc" / "gyr" → (temp_c (m,) [°C],
        values (m, 3) [m/s² or rad/s], group (m,) int: one constant per group).
    """

    instance: int
    source: str
    fits: dict[str, TcalFit]
    tmin_c: float
    tmax_c: float
    still_s: float | None = None
    notes: list[str] = field(default_factory=list)
    blocks: dict | None = field(default=None, repr=False, compare=False)

    @property
    def significant(self) -> bool:
        """True when some linear coefficient c1 (any sensor, any axis) lies beyond
        SIGNIFICANT_SIGMAS σ of zero: the data show a drift. Without one, the fit is noise and
        enabling it would apply noise as a calibration."""
        for fit in self.fits.values():
            c1, s1 = np.asarray(fit.coeffs)[0], np.asarray(fit.sigma)[0]
            if np.any(np.abs(c1) > SIGNIFICANT_SIGMAS * s1):
                return True
        return False

    @property
    def withheld(self) -> str:
        """Why this result's parameters are not proposed ("" when they are)."""
        if self.significant:
            return ""
        return (f"INS_TCAL{self.instance + 1}_* not proposed: no drift coefficient is "
                f"significant (every c1 within {SIGNIFICANT_SIGMAS:g}σ of zero), so over "
                f"{self.tmin_c:.1f}-{self.tmax_c:.1f} °C the drift is below the noise; "
                "enabling it would apply noise as a calibration")

    def params(self) -> dict[str, float]:
        """The INS_TCALn_* parameter values of this result
        (:func:`apmcal.ardupilot.tcal_params.tcal_param_values`); empty when no coefficient is
        significant (:attr:`withheld` says so)."""
        if not self.significant:
            return {}
        return tcal_param_values(self.instance, {s: f.coeffs for s, f in self.fits.items()},
                                 self.tmin_c, self.tmax_c)

    def to_dict(self) -> dict:
        """The result as plain data (JSON report)."""
        return {"instance": self.instance, "source": self.source, "tmin_c": self.tmin_c,
                "tmax_c": self.tmax_c, "still_s": self.still_s, "notes": self.notes,
                "significant": self.significant, "withheld": self.withheld,
                **{s: f.to_dict() for s, f in self.fits.items()}}


def calibrate_temperature(contents, records: str = "auto", instance: int | None = None,
                          min_still_s: float = 2.0, block_s: float = 2.0) -> list[TcalResult]:
    """Fit every IMU instance of ``contents`` (or only ``instance``).

    ``records``: "tclr" the learner's TCLR records, "imu" the IMU samples with temperature,
    "auto" TCLR when the log has them, else IMU samples.

    Parameters
    ----------
    contents : LogContents
        What :func:`apmcal.sources.read_log` read.
    records : str, optional
        "auto", "imu" or "tclr".
    instance : int, optional
        Only this IMU instance (0-based); all when None.
    min_still_s : float, optional
        Shortest still period used [s].
    block_s : float, optional
        Block length of the block means [s].

    Returns
    -------
    list of TcalResult
        One per IMU instance, by instance.

    Raises
    ------
    ApmcalError
        One line naming the file: no usable data, or a temperature range under 10 °C (the
        firmware's learner needs TEMP_RANGE_MIN = 10 °C too).
    """
    if records not in RECORDS:
        raise ApmcalError(f"unknown records {records!r}; choose one of {', '.join(RECORDS)}")
    tclr = {}
    if records in ("auto", "tclr"):
        from apmcal.sources.tclr import read_tclr

        tclr = read_tclr(contents.path, contents.format)
        if records == "tclr" and not tclr:
            raise ApmcalError("no TCLR records (the firmware logs them only while learning, "
                              "INS_TCALn_ENABLE = 2)", contents.path)
    if tclr:
        wanted = sorted(i for i in tclr if instance is None or i == instance)
        results = [_from_tclr(i, tclr[i], contents.path) for i in wanted]
    else:
        results = [_from_samples(rec, contents, min_still_s, block_s)
                   for rec in _temperature_recordings(contents, instance)]
    if not results:
        which = "" if instance is None else f" of IMU instance {instance}"
        raise ApmcalError(f"no accelerometer and gyro samples with a temperature{which}",
                          contents.path)
    return results


def _temperature_recordings(contents, instance):
    """One recording per IMU instance with acc, gyro and a temperature column: floating-point
    messages (dataflash IMU, HIGHRES_IMU) before int16 telemetry, as the other calibrations."""
    best = {}
    for r in contents.recordings:
        if not (r.has("acc") and r.has("gyr") and "temp" in r.data.columns):
            continue
        if instance is not None and r.instance != instance:
            continue
        key = r.message in INT16_TELEMETRY
        if r.instance not in best or key < (best[r.instance].message in INT16_TELEMETRY):
            best[r.instance] = r
    return [best[i] for i in sorted(best)]


def _check_range(tmin_c: float, tmax_c: float, instance: int, path: str) -> None:
    # AP_InertialSensor_tempcal.cpp TEMP_RANGE_MIN: the learner does not save a
    # calibration before the temperature has risen 10 °C
    span = tmax_c - tmin_c
    if not span >= TEMP_RANGE_MIN_C:
        raise ApmcalError(f"IMU instance {instance}: the still samples span {span:.1f} °C "
                          f"({tmin_c:.1f} to {tmax_c:.1f} °C), under the {TEMP_RANGE_MIN_C:g} °C "
                          f"ArduPilot's learner needs: record a longer warm-up", path)


def _from_tclr(instance: int, data: dict, path: str) -> TcalResult:
    """Fit the learner's averages (sensor frame, uncorrected: nothing to undo)."""
    missing = [s for s in ("acc", "gyr") if s not in data]
    if missing:
        raise ApmcalError(f"TCLR records of IMU instance {instance} lack the "
                          f"{' and '.join(missing)} (SType)", path)
    temps = np.concatenate([data[s]["temp_c"] for s in ("acc", "gyr")])
    tmin, tmax = float(temps.min()), float(temps.max())
    _check_range(tmin, tmax, instance, path)
    fits = {}
    for s in ("acc", "gyr"):
        try:
            fits[s] = fit_tcal(data[s]["temp_c"], data[s]["values"], data[s]["n"],
                               t_s=data[s]["t_s"])
        except ApmcalError as err:
            raise ApmcalError(f"IMU instance {instance} {s}: {err.why}", path) from None
    blocks = {s: (np.asarray(data[s]["temp_c"]), np.asarray(data[s]["values"]),
                  np.zeros(len(data[s]["temp_c"]), dtype=int)) for s in ("acc", "gyr")}
    return TcalResult(instance, "TCLR", fits, tmin, tmax, blocks=blocks)


def _from_samples(recording, contents, min_still_s: float, block_s: float) -> TcalResult:
    """Fit the still IMU samples, after undoing the firmware's corrections."""
    from apmcal.ardupilot.firmware import firmware_generation
    from apmcal.preprocessing.param_changes import split_at_param_changes
    from apmcal.preprocessing.prepare import prepare
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.preprocessing.tcal_blocks import still_blocks

    path, inst = contents.path, recording.instance
    recording, _, notes = split_at_param_changes(recording, None, contents.param_changes, path)
    data = recording.data
    recording = replace(recording, data=data[np.isfinite(data["temp"].to_numpy(dtype=float))]
                        .reset_index(drop=True))
    if len(recording) < 10:
        raise ApmcalError(f"IMU instance {inst}: too few samples with a temperature", path)
    old = _tcal_in_force(contents.params, inst, path)
    # a log with INS_TCAL parameters comes from 4.1+: the sensor-frame ("3.3+") correction
    generation = "3.3+" if old is not None else firmware_generation(contents.params,
                                                                    contents.firmware)
    try:
        prepared = prepare(recording, generation)   # offsets, scales, AHRS_ORIENTATION undone
    except ApmcalError as err:
        raise ApmcalError(err.why, path, err.where) from None
    raw = prepared.raw
    for sensor, step in prepared.floor_steps.items():
        if sensor in ("acc", "gyr"):
            # apmcal.preprocessing.resolution: int16 telemetry truncated toward zero, noise
            # below one step: each block mean keeps up to half a step of error, a sawtooth in
            # the drifting value that no σ here accounts for
            unit = "m/s²" if sensor == "acc" else "rad/s"
            notes.append(f"{sensor}: noise below the {recording.message} step ({step:.3g} "
                         f"{unit}, truncated toward zero): the fit carries up to half a step of "
                         f"error per block that its σ does not include; prefer a dataflash log")
    t, temp = raw.t, raw.data["temp"].to_numpy(dtype=float)
    acc, gyr = raw.xyz("acc"), raw.xyz("gyr")
    if old is not None and old.enable == 1:
        # the logged samples are already corrected: add the old polynomial back
        acc = acc + old.correction("acc", temp)
        gyr = gyr + old.correction("gyr", temp)
        notes.append(f"undid the temperature calibration in force (INS_TCAL{inst + 1}_ENABLE "
                     f"= 1, TMIN {old.tmin_c:g}, TMAX {old.tmax_c:g} °C)")
    code = recording.params.get("AHRS_ORIENTATION", 0)
    if recording.frame == "body" and code:
        notes.append(f"undid AHRS_ORIENTATION {code:g}: coefficients are in the sensor frame")
    segments = find_static_segments(t, acc, gyr, min_duration=min_still_s)
    blocks = still_blocks(t, temp, acc, gyr, segments, block_s)
    if len(blocks) == 0:
        raise ApmcalError(f"IMU instance {inst}: no still period of {min_still_s:g} s or more",
                          path)
    _check_range(blocks.temp_min_c, blocks.temp_max_c, inst, path)
    fits = {}
    for s, values in (("acc", blocks.acc), ("gyr", blocks.gyr)):
        try:
            fits[s] = fit_tcal(blocks.temp_c, values, blocks.n, blocks.group, blocks.t_s)
        except ApmcalError as err:
            raise ApmcalError(f"IMU instance {inst} {s}: {err.why}", path) from None
    still_s = float(sum(seg.duration for seg in segments))
    if len(set(blocks.group.tolist())) > 1:
        notes.append(f"{len(set(blocks.group.tolist()))} orientations, one constant each")
    return TcalResult(inst, recording.message, fits, blocks.temp_min_c, blocks.temp_max_c,
                      still_s, notes, {s: (blocks.temp_c, v, blocks.group)
                                       for s, v in (("acc", blocks.acc), ("gyr", blocks.gyr))})


def _tcal_in_force(params, instance, path):
    try:
        return tcal_from_params(params, instance)
    except ApmcalError as err:
        raise ApmcalError(err.why, path, err.where) from None


def tcal_params(results: list[TcalResult]) -> dict[str, float]:
    """Every result's INS_TCALn_* values, one dict."""
    values: dict[str, float] = {}
    for r in results:
        values.update(r.params())
    return values


@dataclass
class TemperatureCalibration:
    """The temperature calibration of every IMU instance of one log (``apmcal tcal``): its
    parameters, and its JSON file ({"tcal": per instance, "params": INS_TCALn_* values}).

    Attributes
    ----------
    results : list of TcalResult
        One per IMU instance (:func:`calibrate_temperature`).
    """

    results: list[TcalResult]

    def params(self) -> dict[str, float]:
        """Every instance's INS_TCALn_* values (:func:`tcal_params`)."""
        return tcal_params(self.results)

    def to_dict(self) -> dict:
        """The fits and parameters as plain data."""
        return {"tcal": [r.to_dict() for r in self.results], "params": self.params()}

    def save(self, path) -> None:
        """Write :meth:`to_dict` as JSON; one-line ApmcalError when it cannot be written."""
        write_json(path, self.to_dict())
