"""Parameter files as MAVProxy, Mission Planner and QGroundControl read and write them.

ardupilot-facts.md "Writing parameters": one ``NAME VALUE`` (or Mission Planner's ``NAME,VALUE``)
per line, ``#`` comments. QGroundControl's ``.params`` (``fmt="qgc"``): tab-separated
``VEHICLE_ID COMPONENT_ID NAME VALUE TYPE`` lines under ``#`` header lines, TYPE 9 =
MAV_PARAM_TYPE_REAL32 (QGroundControl's ParameterManager::writeParametersToStream; the type every
ArduPilot parameter apmcal writes has on the vehicle); all three are read.
Values are written with 9 significant digits ("%.9g"), enough for any float32 to
survive the text round trip exactly (the vehicle stores REAL32).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from apmcal.core.errors import ApmcalError

_NAME = re.compile(r"^[A-Za-z0-9_]{1,16}$")     # MAVLink param_id: at most 16 characters

# A backup keeps a non-finite vehicle value as this comment: every loader skips it (no line that
# cannot be written back), yet the name stays visible and :func:`read_unrestorable` finds it.
NOT_RESTORABLE = "not finite on the vehicle; not restorable"
_UNRESTORABLE = re.compile(r"^#\s*([A-Za-z0-9_]{1,16})\s+(\S+)\s+\(" + re.escape(NOT_RESTORABLE)
                           + r"\)\s*$")


def format_value(value: float) -> str:
    """The float32 value of ``value`` with 9 significant digits (round-trips float32 exactly)."""
    return "%.9g" % float(np.float32(value))


QGC_HEADER = "# Vehicle-Id Component-Id Name Value Type"
#: The comment line recording the firmware generation a file's values were made for
#: (ardupilot.firmware.GENERATIONS): its formulas differ, so values for one are wrong on the other
GENERATION_COMMENT = "# apmcal firmware generation: "
_GENERATION = re.compile(r"^#\s*apmcal firmware generation:\s*(\S+)")
MAV_PARAM_TYPE_REAL32 = 9


def write_param_file(path: str | Path, values: dict[str, float], header_comment: str = "",
                     *, comment_non_finite: bool = False, fmt: str = "param",
                     generation: str | None = None) -> None:
    """Write ``values`` as sorted ``NAME VALUE`` lines, ``header_comment`` as ``#`` lines first,
    then (with ``generation``) the line recording the firmware generation the values were made
    for (:data:`GENERATION_COMMENT`, read back by :func:`read_param_generation`).

    ``comment_non_finite`` (for backups of what a vehicle holds): a NaN/inf value becomes the
    line ``# NAME nan (not finite on the vehicle; not restorable)`` instead of an error.

    Parameters
    ----------
    path : str or Path
    values : dict of str to float
        Parameter name → value (in the parameter's own unit).
    header_comment : str, optional
        Text for the leading ``#`` lines.
    comment_non_finite : bool, optional
        See above.
    fmt : {"param", "qgc"}
        ``NAME VALUE`` lines, or QGroundControl's tab-separated ``.params`` (vehicle 1,
        component 1, type REAL32).
    generation : str, optional
        The firmware generation ("3.2", "3.3+") the values were made for.

    Raises
    ------
    ApmcalError
        For a name that is not a valid parameter name or a value that is not finite (the
        vehicle would drop it silently), or when the file cannot be written.
    """
    if fmt not in ("param", "qgc"):
        raise ApmcalError(f"unknown parameter file format {fmt!r} (param or qgc)", path)
    lines = [f"# {line}".rstrip() for line in header_comment.splitlines()]
    if generation is not None:
        lines.append(f"{GENERATION_COMMENT}{generation}")
    if fmt == "qgc":
        lines.append(QGC_HEADER)
    for name in sorted(values):
        value = float(values[name])
        if not _NAME.match(name):
            raise ApmcalError("not a valid parameter name (letters, digits, _; ≤ 16)", path,
                              f"param {name!r}")
        if math.isfinite(value) and fmt == "qgc":
            lines.append(f"1\t1\t{name}\t{format_value(value)}\t{MAV_PARAM_TYPE_REAL32}")
        elif math.isfinite(value):
            lines.append(f"{name} {format_value(value)}")
        elif comment_non_finite:
            lines.append(f"# {name} {value!r} ({NOT_RESTORABLE})")
        else:
            raise ApmcalError(f"value {value!r} is not finite", path, f"param {name}")
    try:
        Path(path).write_text("\n".join(lines) + "\n")
    except OSError as exc:
        raise ApmcalError(f"cannot write parameter file ({exc.strerror})", path) from None


def read_param_file(path: str | Path) -> dict[str, float]:
    """Read ``NAME VALUE`` / ``NAME,VALUE`` / ``NAME<TAB>VALUE`` lines, or QGroundControl's
    ``VEHICLE COMPONENT NAME VALUE TYPE`` lines; ``#`` comments and blank lines are skipped. A later line for
    the same name wins (as when the GCS loads the file).

    Raises
    ------
    ApmcalError
        Naming the file and line for anything else (bad name, missing or non-numeric value,
        NaN/inf, extra fields), or when the file cannot be read.
    """
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise ApmcalError("no such parameter file", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ApmcalError(f"cannot read parameter file ({exc})", path) from None
    values: dict[str, float] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        body = line.split("#", 1)[0].strip()
        if not body:
            continue
        fields = [f for f in re.split(r"[,\s]+", body) if f]
        where = f"line {number}"
        if len(fields) == 5 and fields[0].isdigit() and fields[1].isdigit() \
                and fields[4].isdigit():
            fields = fields[2:4]                 # QGroundControl: vehicle, component, .., type
        if len(fields) != 2:
            raise ApmcalError(f"expected 'NAME VALUE', got {body!r}", path, where)
        name, text_value = fields
        if not _NAME.match(name):
            raise ApmcalError(f"not a valid parameter name: {name!r}", path, where)
        try:
            value = (float(int(text_value, 16)) if text_value.lower().startswith("0x")
                     else float(text_value))       # MAVProxy also accepts hex values
        except ValueError:
            raise ApmcalError(f"value {text_value!r} of {name} is not a number", path,
                              where) from None
        if not math.isfinite(value):
            raise ApmcalError(f"value of {name} is {text_value}, not finite", path, where)
        values[name] = value
    return values


def read_unrestorable(path: str | Path) -> list[str]:
    """Names a backup holds only as ``# NAME nan (not finite ...)`` comments (see
    :func:`write_param_file`); the file must be readable (:func:`read_param_file` first)."""
    lines = Path(path).read_text().splitlines()
    return [m.group(1) for m in map(_UNRESTORABLE.match, lines) if m]


def read_param_generation(path: str | Path) -> str | None:
    """The firmware generation a parameter file records (:data:`GENERATION_COMMENT`), None
    when it records none (a file of another tool, a backup); the file must be readable
    (:func:`read_param_file` first)."""
    for line in Path(path).read_text().splitlines():
        m = _GENERATION.match(line)
        if m:
            return m.group(1)
    return None
