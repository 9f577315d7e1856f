"""ArduPilot parameter names shared by readers, preprocessing, upload and the command line (no
heavy imports: the command line's help texts read them).

The sensor-correction parameters: the ones whose change while a sensor is logged means the
firmware corrected its samples with other values (ardupilot-facts.md "How the firmware applies
the parameters").
"""
from __future__ import annotations

#: Parameters the firmware uses to correct (or rotate) the IMU and compass samples it reports:
#: a name starting with one of these is a correction parameter.
CORRECTION_PARAM_PREFIXES = ("INS_ACCOFFS", "INS_ACCSCAL", "INS_ACC2OFFS", "INS_ACC2SCAL",
                             "INS_ACC3OFFS", "INS_ACC3SCAL", "INS_GYROFFS", "INS_GYR2OFFS",
                             "INS_GYR3OFFS", "COMPASS_OFS", "COMPASS_DIA", "COMPASS_ODI",
                             "COMPASS_MOT", "COMPASS_ORIENT", "COMPASS_EXTERN",
                             "AHRS_ORIENTATION")


def is_correction_param(name: str) -> bool:
    """True if ``name`` starts with one of :data:`CORRECTION_PARAM_PREFIXES`."""
    return name.startswith(CORRECTION_PARAM_PREFIXES)


def changed_correction_params(before: dict[str, float], after: dict[str, float]) -> list[str]:
    """The correction parameters whose value differs between two snapshots of a vehicle's
    parameters, as "NAME old -> new" (absent: None), sorted by name.

    RAW_IMU is corrected with the parameters in force (ardupilot-facts.md "What the telemetry
    really carries"), so samples from before and after such a change (a boot gyro calibration
    still running, another ground station writing) cannot be un-corrected with one set.
    """
    return [f"{k} {before.get(k)} -> {after.get(k)}" for k in sorted(set(before) | set(after))
            if is_correction_param(k) and before.get(k) != after.get(k)]
