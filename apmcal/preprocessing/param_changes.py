"""Keep only the samples recorded under one set of calibration parameters.

ardupilot-facts.md "What the telemetry really carries": the firmware corrects every RAW_IMU /
dataflash sample with the parameters in force when it is made. The readers report the last value
of each parameter, and preprocessing undoes the correction with those values, so samples made
before a calibration parameter changed (an accel calibration or a compass upload during the log)
would be un-corrected with the wrong values. They are dropped, with a warning that says why.
"""
from __future__ import annotations

from dataclasses import replace

from apmcal.errors import ApmcalError
from apmcal.recording import ParamChange, Recording


def after_param_changes(recording: Recording, changes: list[ParamChange],
                        path: str) -> tuple[Recording, list[str]]:
    """The samples of ``recording`` after the last calibration parameter change, and warnings.

    Raises
    ------
    ApmcalError
        A change whose time the log does not tell (the samples cannot be split safely), or no
        sample left after the last change.
    """
    if not changes:
        return recording, []
    untimed = next((c for c in changes if c.time_s is None), None)
    if untimed is not None:
        raise ApmcalError(f"{untimed.name} changed from {untimed.old:g} to {untimed.new:g} "
                          "while recording, at a time the log does not tell: the samples "
                          "cannot be un-corrected with one parameter set", path, untimed.where)
    last = max(changes, key=lambda c: c.time_s)
    kept = recording.data.loc[recording.data["t"] > last.time_s].reset_index(drop=True)
    if len(kept) < 2:
        raise ApmcalError(f"{last.name} changed from {last.old:g} to {last.new:g} at "
                          f"t={last.time_s:.3f} s and no samples follow: record again with the "
                          "parameters settled", path, last.where)
    names = sorted({c.name for c in changes})
    warning = (f"calibration parameters changed while recording ({', '.join(names)}; last: "
               f"{last}): only the {len(kept)} of {len(recording.data)} samples after "
               f"t={last.time_s:.3f} s are used")
    return replace(recording, data=kept), [warning]
