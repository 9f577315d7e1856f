"""Which parameters upload and restore may write: calibration ones unless told
otherwise, never the counters and identity the vehicle keeps itself.

Kept free of heavy imports: the command line's help texts read it.
"""
from __future__ import annotations

from apmcal.ardupilot.names import CORRECTION_PARAM_PREFIXES
from apmcal.core.errors import ApmcalError

#: What upload and restore write unless told otherwise: the parameters of the sensor
#: corrections (INS_ACC*/INS_GYR* offsets and scales of each IMU, COMPASS_OFS/DIA/ODI/MOT/
#: ORIENT/EXTERN of each compass, AHRS_ORIENTATION: apmcal.ardupilot.names' list, ardupilot-facts.md
#: "How the firmware applies the parameters") and the other results of a calibration:
#: temperature calibration (INS_TCAL*), compass scale (COMPASS_SCALE*), level trim (AHRS_TRIM_*).
CALIBRATION_PREFIXES = CORRECTION_PARAM_PREFIXES + ("INS_TCAL", "COMPASS_SCALE", "AHRS_TRIM")
#: The same, in words, for messages and help texts
CALIBRATION_IN_WORDS = ("INS_ACC*/INS_GYR* offsets and scales, INS_TCAL*, COMPASS_OFS/DIA/ODI/"
                        "MOT/SCALE/ORIENT/EXTERN*, AHRS_ORIENTATION, AHRS_TRIM_*")
#: Never written, even with all_params: counters and statistics the vehicle keeps itself
#: (ArduPilot's AP_Stats STAT_BOOTCNT/FLTTIME/RUNTIME, saved every 30 s and overwritten from its
#: own count; writing STAT_RESET resets them all; SYS_NUM_RESETS of older firmware) and the
#: firmware's identity (a FORMAT_VERSION it does not expect makes it erase every parameter at
#: the next boot).
NEVER_WRITTEN_PREFIXES = ("STAT_", "SYS_NUM_RESETS", "FORMAT_VERSION", "SYSID_SW_MREV",
                          "SYSID_SW_TYPE")


def is_calibration_param(name: str) -> bool:
    """True for a name upload and restore write by default (:data:`CALIBRATION_PREFIXES`)."""
    return name.startswith(CALIBRATION_PREFIXES)


def is_never_written(name: str) -> bool:
    """True for a counter or identity parameter (:data:`NEVER_WRITTEN_PREFIXES`)."""
    return name.startswith(NEVER_WRITTEN_PREFIXES)


def may_write(name: str, all_params: bool = False) -> bool:
    """True if upload / restore may write ``name`` (all but counters with ``all_params``)."""
    return not is_never_written(name) and (all_params or is_calibration_param(name))


def check_scope(names, where: str, all_params: bool = False) -> None:
    """Refuse (nothing written) a name upload may not write; ``where`` is the file or link."""
    for name in names:
        if is_never_written(name):
            raise ApmcalError("a counter or identity the vehicle keeps itself, never written; "
                              "nothing was written", where, f"param {name}")
        if not may_write(name, all_params):
            raise ApmcalError(f"not a calibration parameter (apmcal writes only "
                              f"{CALIBRATION_IN_WORDS} unless --all-params); nothing was "
                              f"written", where, f"param {name}")
