"""ArduPilot parameter names shared by readers, preprocessing and the vehicle modules (no heavy
imports: the command line's help texts read them).

The sensor-correction parameters: the ones whose change while a sensor is logged means the
firmware corrected its samples with other values (ardupilot-facts.md "How the firmware applies
the parameters").
"""
from __future__ import annotations

#: Parameters the firmware uses to correct (or rotate) the IMU and compass samples it reports:
#: a name starting with one of these is a calibration parameter.
CALIBRATION_PARAM_PREFIXES = ("INS_ACCOFFS", "INS_ACCSCAL", "INS_ACC2OFFS", "INS_ACC2SCAL",
                              "INS_ACC3OFFS", "INS_ACC3SCAL", "INS_GYROFFS", "INS_GYR2OFFS",
                              "INS_GYR3OFFS", "COMPASS_OFS", "COMPASS_DIA", "COMPASS_ODI",
                              "COMPASS_MOT", "COMPASS_ORIENT", "COMPASS_EXTERN",
                              "AHRS_ORIENTATION")
