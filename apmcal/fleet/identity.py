"""Who a log belongs to and which calibration it flew with.

Identity (ardupilot-facts.md "Identity and vibration records"): the board's UID line that
ArduPilot logs at boot (``"<board> XXXXXXXX XXXXXXXX
XXXXXXXX"``, e.g. ``"Pixhawk1 00310019 3138510E 35363631"``, ``"PX4v2 004A002F 33345119
32383433"``), else the vehicle type and SYSID_THISMAV. The calibration in force: the INS_*,
COMPASS_* and AHRS_ORIENTATION calibration parameters (:data:`CORRECTION_PARAM_PREFIXES`), the
temperature calibration INS_TCAL* and INS_*_CALTEMP; the sensors' DEV_IDs (COMPASS_DEV_ID*,
INS_ACC*_ID, INS_GYR*_ID), whose change means the hardware changed.
"""
from __future__ import annotations

import math
import re

from apmcal.ardupilot.names import CORRECTION_PARAM_PREFIXES

UID_RE = re.compile(r"^(?P<board>[A-Za-z][\w.-]*)\s+(?P<uid>[0-9A-Fa-f]{8}(?: [0-9A-Fa-f]{8}){2})\s*$")
FRAME_RE = re.compile(r"^Frame:\s*(?P<frame>\S+)")
DEV_ID_RE = re.compile(r"^(COMPASS_DEV_ID\d?|INS_(ACC|GYR)\d?_ID)$")
TCAL_RE = re.compile(r"^(INS_TCAL\d|INS_(ACC|GYR)\d?_CALTEMP)")
# the boot gyro calibration rewrites INS_GYROFFS at every boot (INS_GYR_CAL=1): a health figure,
# not a change of calibration
BOOT_GYRO_RE = re.compile(r"^INS_GYR\d?OFFS_")
FRAME_PARAMS = ("FRAME_CLASS", "FRAME_TYPE", "FRAME", "Q_FRAME_CLASS", "Q_FRAME_TYPE",
                "FRAME_CONFIG")


def board_uid(messages: list[str]) -> tuple[str | None, str | None]:
    """(board name, UID) from the log's boot messages, or (None, None)."""
    for text in messages:
        m = UID_RE.match(text.strip())
        if m:
            return m["board"], m["uid"].upper()
    return None, None


def frame_of(messages: list[str], params: dict[str, float]) -> str | None:
    """The frame: the "Frame: QUAD" message, else the frame parameters, else None."""
    for text in messages:
        m = FRAME_RE.match(text.strip())
        if m:
            return m["frame"]
    found = [f"{p}={params[p]:g}" for p in FRAME_PARAMS if _finite(params.get(p))]
    return ",".join(found) or None


def _finite(v) -> bool:
    return v is not None and isinstance(v, (int, float)) and math.isfinite(v)


def identity(contents) -> dict:
    """The vehicle's identity fields of a :class:`~apmcal.core.recording.LogContents`.

    Returns
    -------
    dict
        vehicle_type, firmware, board, uid, sysid (float or None), frame, vehicle_id (the
        grouping key: "<board> <uid>", else "<vehicle_type> sysid <n>").
    """
    board, uid = board_uid(contents.messages)
    sysid = contents.params.get("SYSID_THISMAV")
    sysid = float(sysid) if _finite(sysid) else None
    vtype = contents.vehicle or "unknown"
    if uid:
        vid = f"{board} {uid}"
    else:
        vid = f"{vtype} sysid {int(sysid) if sysid is not None else '?'}"
    return {"vehicle_type": vtype, "firmware": contents.firmware, "board": board, "uid": uid,
            "sysid": sysid, "frame": frame_of(contents.messages, contents.params),
            "vehicle_id": vid}


def is_calibration(name: str) -> bool:
    """True for a calibration parameter (offsets, scales, orientation, temperature calibration)."""
    return name.startswith(CORRECTION_PARAM_PREFIXES) or bool(TCAL_RE.match(name))


def calibration_in_force(params: dict[str, float]) -> dict[str, float]:
    """The calibration parameters of ``params`` (finite values only), name → value."""
    return {k: float(v) for k, v in sorted(params.items()) if is_calibration(k) and _finite(v)}


def dev_ids(params: dict[str, float]) -> dict[str, float]:
    """The sensors' DEV_ID parameters, name → value (0: no sensor in that slot)."""
    return {k: float(v) for k, v in sorted(params.items()) if DEV_ID_RE.match(k) and _finite(v)}


def sensor_of(dev_id_name: str) -> str:
    """"compass", "accelerometer" or "gyro" for a DEV_ID parameter name."""
    if dev_id_name.startswith("COMPASS"):
        return "compass"
    return "accelerometer" if dev_id_name.startswith("INS_ACC") else "gyro"


def compares_as_change(name: str) -> bool:
    """True when a new value of ``name`` between flights means the calibration was changed."""
    return not BOOT_GYRO_RE.match(name)
