"""Keep only the samples recorded under one set of correction parameters.

ardupilot-facts.md "What the telemetry really carries": the firmware corrects every RAW_IMU /
dataflash sample with the parameters in force when it is made. The readers report the last value
of each parameter, and preprocessing undoes the correction with those values, so samples made
before a parameter of *their own* correction changed (an accelerometer calibration, a compass
upload during the log) would be un-corrected with the wrong values. Those samples are dropped,
per sensor, with a warning that says why; a change to another sensor's parameters drops nothing.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from apmcal.ardupilot.names import is_correction_param
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import MAG, ParamChange, Recording


def split_at_param_changes(imu: Recording, mag: Recording | None, changes: list[ParamChange],
                           path: str) -> tuple[Recording, Recording | None, list[str]]:
    """(IMU recording, magnetometer recording or None, warnings), each cut after the last
    change of its own correction parameters.

    The compass is cut on its own: when the IMU's message also carries it (RAW_IMU), its columns
    become a recording of their own (the one calibrated, as without changes), and a separate
    compass recording keeps only its compass columns. So a compass upload does not cost the
    accelerometer its samples, nor an accelerometer calibration the compass. A compass that
    cannot be kept loses only itself (a warning); an IMU that cannot be kept is an
    :class:`ApmcalError`.

    Parameters
    ----------
    imu : Recording
        The IMU recording (acc, gyr, and the compass when its message carries one).
    mag : Recording or None
        A separate compass recording of the same IMU.
    changes : list of ParamChange
        The log's calibration-parameter changes (``LogContents.param_changes``).
    path : str
        The log, for error messages.

    Raises
    ------
    ApmcalError
        When the IMU's samples cannot be kept (see :func:`after_param_changes`).
    """
    if not _relevant(changes, imu, ("acc", "gyr", "mag")) and (
            mag is None or not _relevant(changes, mag, ("mag",))):
        return imu, mag, []
    if imu.has("mag"):
        mag = imu
        imu = replace(imu, data=imu.data.drop(columns=MAG))
    if mag is not None:
        mag = replace(mag, data=mag.data[["t", *MAG]].copy())
    imu, warnings = after_param_changes(imu, changes, path)
    if mag is not None:
        try:
            mag, mag_warnings = after_param_changes(mag, changes, path)
            warnings += mag_warnings
        except ApmcalError as err:
            warnings.append(f"magnetometer not calibrated: {err.why}")
            mag = None
    return imu, mag, warnings


def after_param_changes(recording: Recording, changes: list[ParamChange],
                        path: str) -> tuple[Recording, list[str]]:
    """The samples of ``recording`` after the last change of a parameter its correction uses
    (:func:`enters_correction_of`), and warnings.

    Parameters
    ----------
    recording : Recording
    changes : list of ParamChange
    path : str
        The log, for error messages.

    Returns
    -------
    recording : Recording
        The samples after the last relevant change (``recording`` itself when none is).
    warnings : list of str

    Raises
    ------
    ApmcalError
        A relevant change whose time the log does not tell, a log whose clock also jumps back (a
        reboot: a time no longer says which side of the change a sample is on), or no sample left
        after the last change.
    """
    relevant = _relevant(changes, recording, recording.sensors)
    if not relevant:
        return recording, []
    untimed = next((c for c in relevant if c.time_s is None), None)
    if untimed is not None:
        raise ApmcalError(f"{untimed.name} changed from {untimed.old:g} to {untimed.new:g} "
                          "while recording, at a time the log does not tell: the samples "
                          "cannot be un-corrected with one parameter set", path, untimed.where)
    last = max(relevant, key=lambda c: c.time_s)
    t = recording.t
    if np.any(np.diff(t) < 0):
        raise ApmcalError(f"{last.name} changed while recording and the log's clock jumps back "
                          "(a reboot): split the log at the reboot and calibrate each part",
                          path, last.where)
    kept = recording.data.loc[t > last.time_s].reset_index(drop=True)
    if len(kept) < 2:
        raise ApmcalError(f"{last.name} changed from {last.old:g} to {last.new:g} at "
                          f"t={last.time_s:.3f} s and no samples follow: record again with the "
                          "parameters settled", path, last.where)
    names = sorted({c.name for c in relevant})
    label = "/".join(recording.sensors)
    warning = (f"{label}: correction parameters changed while recording ({', '.join(names)}; "
               f"last: {last}): only the {len(kept)} of {len(recording.data)} samples after "
               f"t={last.time_s:.3f} s are used")
    return replace(recording, data=kept), [warning]


def enters_correction_of(sensors, instance: int):
    """Predicate on a parameter name: does it enter the firmware correction of these sensors?"""
    from apmcal.ardupilot.firmware import correction_param_names

    try:
        names = set().union(*(correction_param_names(s, instance) for s in sensors))
    except ApmcalError:          # an instance ArduPilot has no parameters for: be conservative
        return is_correction_param
    return names.__contains__


def _relevant(changes: list[ParamChange], recording: Recording, sensors) -> list[ParamChange]:
    uses = enters_correction_of([s for s in sensors if s in ("acc", "gyr", "mag")],
                                recording.instance)
    return [c for c in changes if uses(c.name)]
