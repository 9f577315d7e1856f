"""Who a log belongs to and which calibration it flew with.

Identity, first found wins, and how it was found (``identified_by``):

1. the user's own mapping (``--vehicles FILE``, :class:`VehicleMap`: a glob or folder → a
   vehicle name), for fleets whose logs carry nothing distinctive;
2. the board's UID line that ArduPilot logs at boot (``"<board> XXXXXXXX XXXXXXXX XXXXXXXX"``,
   e.g. ``"Pixhawk1 00310019 3138510E 35363631"``; ardupilot-facts.md "Identity and vibration
   records"). ArduPilot SITL logs the host's machine id there instead (32 hex digits, its first
   one shifted by the instance number): no board, so not taken;
3. the vehicle type and its MAVLink system id: in a .tlog the header of the autopilot's frames
   (every frame carries it, :func:`apmcal.sources.tlog.autopilot_system_id`), else the
   parameter MAV_SYSID (ArduPilot 4.7 and later) or SYSID_THISMAV (before). Different vehicles
   that share a system id are merged: give them ``--vehicles``;
4. none of these: the log is a vehicle of its own ("unidentified", named by its file).

The calibration in force: the INS_*, COMPASS_* and AHRS_ORIENTATION calibration parameters
(:data:`CORRECTION_PARAM_PREFIXES`), the temperature calibration INS_TCAL* and INS_*_CALTEMP;
the sensors' DEV_IDs (COMPASS_DEV_ID*, INS_ACC*_ID, INS_GYR*_ID), whose change means the hardware
changed.
"""
from __future__ import annotations

import glob
import math
import re
from pathlib import Path

from apmcal.ardupilot.names import CORRECTION_PARAM_PREFIXES
from apmcal.core.errors import ApmcalError

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


# ArduPilot 4.7 renamed SYSID_THISMAV to MAV_SYSID (the newer name first)
SYSID_PARAMS = ("MAV_SYSID", "SYSID_THISMAV")


def param_sysid(params: dict[str, float]) -> tuple[int | None, str | None]:
    """(system id, the parameter that gave it) from MAV_SYSID or SYSID_THISMAV, or (None, None)."""
    for name in SYSID_PARAMS:
        v = params.get(name)
        if _finite(v):
            return int(v), name
    return None, None


def identity(contents, header_sysid: int | None = None) -> dict:
    """The vehicle's identity fields of a :class:`~apmcal.core.recording.LogContents`.

    Parameters
    ----------
    contents : LogContents
    header_sysid : int, optional
        The autopilot's system id from a .tlog's frame headers (preferred to the parameters:
        it is what every frame of the session says).

    Returns
    -------
    dict
        vehicle_type, firmware, board, uid, sysid (float or None), frame, vehicle_id (the
        grouping key: "<board> <uid>", else "<vehicle_type> sysid <n>", else "unidentified
        <vehicle_type>: <file name>") and identified_by (how, in words).
    """
    board, uid = board_uid(contents.messages)
    sysid, source = param_sysid(contents.params)
    if header_sysid is not None:
        sysid, source = int(header_sysid), "MAVLink header"
    vtype = contents.vehicle or "unknown"
    if uid:
        vid, how = f"{board} {uid}", "board UID (boot message)"
    elif sysid is not None:
        vid = f"{vtype} sysid {sysid}"
        how = ("MAVLink header system id" if source == "MAVLink header"
               else f"{source} parameter")
    else:
        vid = f"unidentified {vtype}: {Path(contents.path).name}"
        how = "nothing distinctive (no board UID, no system id): give --vehicles"
    return {"vehicle_type": vtype, "firmware": contents.firmware, "board": board, "uid": uid,
            "sysid": float(sysid) if sysid is not None else None,
            "frame": frame_of(contents.messages, contents.params), "vehicle_id": vid,
            "identified_by": how}


class VehicleMap:
    """The user's mapping of logs to vehicles (``--vehicles FILE``): one line per vehicle
    ``PATTERN = NAME``, PATTERN a folder (every log below it) or a glob (``**`` recursive),
    relative to the file's folder; blank lines and ``#`` comments skipped; the first line that
    matches a log names its vehicle, over anything the log itself says.

    Raises
    ------
    ApmcalError
        Unreadable file, a line without ``=`` or a name, a pattern that matches nothing.
    """

    def __init__(self, path):
        self.path = Path(path)
        try:
            lines = self.path.read_text(errors="replace").splitlines()
        except OSError as e:
            raise ApmcalError(f"cannot read the vehicle mapping: {e.strerror or e}",
                              str(path)) from None
        self.rules: list[tuple[int, str, str, list[Path], set[Path]]] = []
        for n, line in enumerate(lines, 1):
            item = line.strip()
            if not item or item.startswith("#"):
                continue
            pattern, eq, name = (part.strip() for part in item.rpartition("="))
            if not eq or not pattern or not name:
                raise ApmcalError(f"line {n}: expected 'FOLDER_OR_GLOB = VEHICLE NAME', got "
                                  f"{item!r}", str(path))
            self.rules.append((n, pattern, name, *self._targets(pattern, n)))

    def _targets(self, pattern: str, line: int) -> tuple[list[Path], set[Path]]:
        """(folders, files) the pattern names."""
        full = pattern if Path(pattern).is_absolute() else str(self.path.parent / pattern)
        hits = [Path(full)] if Path(full).exists() else [Path(m) for m in
                                                        glob.glob(full, recursive=True)]
        if not hits:
            raise ApmcalError(f"line {line}: {pattern!r} matches no file or folder", str(self.path))
        folders = [h.resolve() for h in hits if h.is_dir()]
        return folders, {h.resolve() for h in hits if h.is_file()}

    def vehicle_of(self, log_path) -> tuple[str, str] | None:
        """(vehicle name, how it was identified) of a log, or None when no line matches."""
        p = Path(log_path).resolve()
        for n, pattern, name, folders, files in self.rules:
            if p in files or any(p.is_relative_to(f) for f in folders):
                return name, f"--vehicles {self.path.name} line {n} ({pattern})"
        return None

    def apply(self, records: list[dict]) -> None:
        """Set vehicle_id and identified_by of the read logs a line matches (in place)."""
        for rec in records:
            hit = self.vehicle_of(rec["path"]) if rec.get("status") == "ok" else None
            if hit:
                rec["vehicle_id"], rec["identified_by"] = hit


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
