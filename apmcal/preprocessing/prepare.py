"""A recording made ready for the solvers: the preparation every calibration, the gap diagnosis
and the temperature calibration share.

Preparation, in order: finite samples; strictly increasing time; integer telemetry moved off its
truncation bias; the firmware's correction and board orientation undone
(:func:`apmcal.ardupilot.firmware.uncorrect`), so that every solver sees raw sensor-frame samples.
Also here: which recording of a log to calibrate (:func:`pick_recording`), when it was recorded
(:func:`recording_date`), whether its compass is live, and a separate compass record brought onto
the IMU's times (:func:`compass_on_imu_times`).
"""
from __future__ import annotations

import datetime
from dataclasses import dataclass, field, replace

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.core.recording import SENSOR_COLUMNS, Recording
from apmcal.preprocessing.resolution import (
    INT16_TELEMETRY,
    integer_valued_steps,
    resolution_limited,
    telemetry_steps,
    undo_truncation,
)
from apmcal.preprocessing.timebase import monotonic


@dataclass
class Prepared:
    """A recording made ready for the solvers (:func:`prepare`).

    Attributes
    ----------
    raw : Recording
        Raw sensor-frame samples.
    steps : dict
        Telemetry resolution per sensor [m/s², rad/s, mGauss].
    floor_steps : dict
        Of those, the sensors whose noise is below a step.
    warnings : list of str
    """

    raw: Recording                                           # raw sensor-frame samples
    steps: dict[str, float] = field(default_factory=dict)    # telemetry resolution per sensor
    floor_steps: dict[str, float] = field(default_factory=dict)  # of those, noise below a step
    warnings: list[str] = field(default_factory=list)


def prepare(recording: Recording, generation: str | None = None) -> Prepared:
    """Finite samples, monotonic time, truncation undone, firmware correction undone.

    ardupilot-facts.md "What the telemetry really carries": RAW_IMU and dataflash IMU/MAG are
    corrected with the parameters in force, so a fit on them must first undo that correction,
    the way ``generation`` ("3.2" / "3.3+"; None: from the log) applied it.

    Parameters
    ----------
    recording : Recording
    generation : str, optional

    Returns
    -------
    Prepared
    """
    recording, warnings = drop_non_finite(recording)
    recording, time_warnings = monotonic(recording)
    warnings += time_warnings
    steps = telemetry_steps(recording) or integer_valued_steps(recording)
    floor_steps = resolution_limited(recording, steps)
    recording = undo_truncation(recording)
    if recording.corrected or recording.frame == "body":
        from apmcal.ardupilot.firmware import uncorrect

        recording = uncorrect(recording, generation=generation)
    return Prepared(recording, steps, floor_steps, warnings)


ABSURD_FACTOR = 1e4     # a sample this many times the sensor's 95th-percentile magnitude is
                        # no reading (no sensor's range spans four decades above its typical
                        # signal); unit-free, so it holds for m/s², rad/s, mGauss and raw counts


def drop_non_finite(recording: Recording) -> tuple[Recording, list[str]]:
    """Rows whose time or sensor values are NaN/inf, or absurd (a sensor's magnitude above
    ABSURD_FACTOR × its 95th percentile, e.g. one 1e308), removed with a counted warning, so
    that a stray value never changes the stillness detection or the method.

    Parameters
    ----------
    recording : Recording

    Returns
    -------
    Recording
        The same object when every row is finite, else a copy without the others.
    list of str
        The warning (empty when nothing was dropped).
    """
    cols = ["t"] + [c for s in recording.sensors for c in SENSOR_COLUMNS[s]]
    values = recording.data[cols].to_numpy(dtype=float)
    finite = np.isfinite(values).all(axis=1)
    absurd = np.zeros(len(values), dtype=bool)
    for sensor in recording.sensors:
        xyz = recording.data[SENSOR_COLUMNS[sensor]].to_numpy(dtype=float)
        norm = np.max(np.abs(xyz), axis=1)          # the largest axis: no overflow at 1e308
        ok = np.isfinite(norm)
        if ok.sum() < 2:
            continue
        typical = np.percentile(norm[ok], 95)
        if typical > 0:
            absurd |= ok & (norm > ABSURD_FACTOR * typical)
    keep = finite & ~absurd
    bad = int(np.count_nonzero(~keep))
    if bad == 0:
        return recording, []
    kept = recording.data.loc[keep].reset_index(drop=True)
    why = [f"{int(np.count_nonzero(~finite))} with NaN/inf values"] if not finite.all() else []
    if absurd.any():
        why.append(f"{int(np.count_nonzero(absurd & finite))} absurd (over "
                   f"{ABSURD_FACTOR:.0e} × the sensor's typical magnitude)")
    return (replace(recording, data=kept),
            [f"{bad} of {len(keep)} samples dropped: " + ", ".join(why)])

def recording_date(contents) -> datetime.date | None:
    """UTC date the source was recorded, when the source carries a wall-clock time.

    Parameters
    ----------
    contents : LogContents

    Returns
    -------
    datetime.date or None
    """
    if contents.start_unix_s is None:
        return None
    return datetime.datetime.fromtimestamp(contents.start_unix_s, tz=datetime.timezone.utc).date()


def pick_recording(contents, instance: int | None):
    """(IMU recording, separate magnetometer recording of the same instance or None).

    Parameters
    ----------
    contents : LogContents
    instance : int or None
        IMU instance (None: the lowest).

    Returns
    -------
    Recording
    Recording or None

    Raises
    ------
    ApmcalError
        When no accelerometer recording (of that instance) exists.
    """
    candidates = [r for r in contents.recordings if r.has("acc")]
    if instance is not None:
        candidates = [r for r in candidates if r.instance == instance]
    if not candidates:
        which = "" if instance is None else f" for instance {instance}"
        raise ApmcalError(f"no accelerometer recording{which}", contents.path)
    # accelerometer with gyro (IMU) before accelerometer alone (dataflash ACC1), then
    # floating-point samples (HIGHRES_IMU, dataflash) before int16 telemetry of the same IMU
    recording = min(candidates, key=lambda r: (r.instance, not r.has("gyr"),
                                               r.message in INT16_TELEMETRY))
    mags = [r for r in contents.recordings if r.has("mag") and r.instance == recording.instance]
    return recording, (mags[0] if mags and mags[0] is not recording else None)

def has_live_magnetometer(recording: Recording) -> bool:
    """True when mag columns exist and are not all zero (an absent compass logs zeros)."""
    return recording.has("mag") and bool(np.any(recording.xyz("mag")))

def compass_on_imu_times(t: np.ndarray, prepared, mag_prepared) -> np.ndarray | None:
    """Raw compass samples [mGauss] at the IMU times ``t`` (n, 3), NaN outside the compass's
    own time span; None when neither recording has a live compass.

    A compass in the IMU's own message (RAW_IMU, HIGHRES_IMU) is used as it is; a separate
    one (dataflash MAG) is interpolated linearly onto the IMU times.

    Parameters
    ----------
    t : (n,) array
        IMU sample times [s].
    prepared : Prepared
        The IMU recording.
    mag_prepared : Prepared or None
        A separate compass recording.

    Returns
    -------
    (n, 3) array or None
        Compass samples [mGauss].
    """
    if has_live_magnetometer(prepared.raw):
        return prepared.raw.xyz("mag")
    if mag_prepared is None or not has_live_magnetometer(mag_prepared.raw):
        return None
    tm, m = mag_prepared.raw.t, mag_prepared.raw.xyz("mag")
    out = np.column_stack([np.interp(t, tm, m[:, i]) for i in range(3)])
    out[(t < tm[0]) | (t > tm[-1])] = np.nan
    return out
