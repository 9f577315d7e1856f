"""Write parameters to a vehicle: backed up first, verified by read-back, reversible.

ardupilot-facts.md "Writing parameters": PARAM_SET (REAL32) is answered with PARAM_VALUE
carrying the stored value; unknown names and NaN are dropped silently; the value must be
compared at float32 tolerance by the ground station itself.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apmcal.errors import ApmcalError
from apmcal.preprocessing.firmware import acc_param_names, firmware_generation, mag_param_names
from apmcal.sources.live import VehicleLink
from apmcal.vehicle.params import acc_violations, offset_violations, soft_iron_violations
from apmcal.vehicle.paramfile import read_param_file, read_unrestorable, write_param_file

INSTANCES = range(3)        # IMU / compass instances 1..3 (suffix "", "2", "3")


@dataclass
class UploadReport:
    written: dict[str, float] = field(default_factory=dict)    # name -> value read back
    previous: dict[str, float] = field(default_factory=dict)   # name -> value before
    backup_path: str = ""
    skipped: list[str] = field(default_factory=list)       # restore: names the vehicle lacks
    unrestorable: list[str] = field(default_factory=list)  # restore: NaN/inf in the backup


def same_float32(a: float, b: float) -> bool:
    """True if ``a`` and ``b`` are the same value once stored as float32."""
    return np.float32(a) == np.float32(b)


# ----------------------------------------------------------------------------- checks
def check_before_writing(values: dict[str, float], vehicle_params: dict[str, float],
                         where: str) -> None:
    """Refuse the whole upload (nothing written) for unknown names, non-finite values, or
    values outside the firmware's limits."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise ApmcalError(f"value {value!r} is not finite; nothing was written", where,
                              f"param {name}")
        if name not in vehicle_params:
            raise ApmcalError("the vehicle has no such parameter (wrong firmware generation?); "
                              "nothing was written", where, f"param {name}")
    violations = firmware_limit_violations(values, vehicle_params)
    if violations:
        name, why = next(iter(violations.items()))
        more = f" (and {len(violations) - 1} more)" if len(violations) > 1 else ""
        raise ApmcalError(f"{why}: out of the firmware's limits{more}; nothing was written",
                          where, f"param {name}")


def firmware_limit_violations(values: dict[str, float],
                              vehicle_params: dict[str, float]) -> dict[str, str]:
    """name -> reason, for values of ``values`` outside the limits of
    :mod:`apmcal.vehicle.params` (the same constants :func:`to_ardupilot_params` refuses by;
    ardupilot-facts.md "How the firmware applies the parameters", "ArduPilot's own
    calibrators"). The firmware stores any finite value; these are its parameter ranges and
    pre-arm checks. The generation and COMPASS_OFFS_MAX come from ``vehicle_params``; compass
    values are judged as the vehicle will hold them after the upload (a DIA or offset written
    alone is checked with the other two axes the vehicle has)."""
    generation = firmware_generation(vehicle_params)
    merged = {**vehicle_params, **values}      # DIA is judged per instance, after the upload
    reasons: dict[str, str] = {}
    for instance in INSTANCES:
        reasons |= acc_violations(values, instance, generation)
        reasons |= _compass_violations(values, merged, instance, generation)
    return reasons


def _compass_violations(values, merged, instance: int, generation: str) -> dict[str, str]:
    names = mag_param_names(instance)
    # all-zero DIA is the firmware's "no soft-iron matrix" (identity), not a zero gain
    dia_unset = all(merged.get(n) == 0 for n in names["dia"])
    reasons = {}
    if any(n in values for n in names["ofs"]):
        reasons |= offset_violations([merged.get(n, 0.0) for n in names["ofs"]], names["ofs"],
                                     merged, generation)
    judged = {n: values[n] for n in names["odi"] if n in values}
    if any(n in values for n in names["dia"]) and not dia_unset:
        judged |= {n: merged.get(n, 1.0) for n in names["dia"]}   # all three, as they will be
    return reasons | soft_iron_violations(judged, names)


# ----------------------------------------------------------------------------- upload
def upload_params(link: VehicleLink, values: dict[str, float], backup_path: str | Path,
                  vehicle_params: dict[str, float] | None = None) -> UploadReport:
    """Back up every parameter, then set ``values`` one by one, verifying each read-back.

    If any write is not confirmed, or the user presses Ctrl-C, every parameter already changed
    is put back to its backed-up value (and that is verified too) before :class:`ApmcalError`
    is raised: the vehicle is never left half-calibrated.
    """
    if vehicle_params is None:
        vehicle_params = link.fetch_params()
    check_before_writing(values, vehicle_params, link.connection)
    # NaN/inf on the vehicle become comment lines: the backup holds nothing restore cannot write
    write_param_file(backup_path, vehicle_params,
                     f"apmcal backup of all parameters of {link.connection} before upload",
                     comment_non_finite=True)
    report = UploadReport(backup_path=str(backup_path),
                          previous={n: vehicle_params[n] for n in values})
    try:
        failure = _write_all(link, values, report)
    except KeyboardInterrupt:
        # the write under way may have been stored: it is put back with the others
        pending = next((n for n in values if n not in report.written), None)
        _roll_back(link, report, also=pending, cause="interrupted")
        raise ApmcalError(f"interrupted; all changes rolled back from {backup_path}",
                          link.connection) from None
    if failure is not None:
        name, value, echoed = failure
        # The vehicle may have stored something else (or stored it and lost the answer):
        # the failing name is put back too.
        _roll_back(link, report, also=name, cause=f"write of {name} not confirmed")
        got = "no answer" if echoed is None else f"read back {echoed!r}"
        raise ApmcalError(f"write of {value!r} not confirmed ({got}); all changes rolled "
                          f"back from {backup_path}", link.connection, f"param {name}")
    return report


def _write_all(link: VehicleLink, values: dict[str, float], report: UploadReport):
    """Set ``values`` in order into ``report.written``; (name, value, echoed) of the first write
    not confirmed, None when all are."""
    for name, value in values.items():
        echoed = link.set_param(name, value)
        if echoed is None or not same_float32(echoed, value):
            return name, value, echoed
        report.written[name] = echoed
    return None


def _roll_back(link: VehicleLink, report: UploadReport, also: str | None, cause: str) -> None:
    """Put every written name, and ``also`` (the write under way), back to its backed-up value.

    A rollback that fails, or is itself interrupted, names the command that finishes it.
    """
    names = [*report.written, *([also] if also is not None else [])]
    restore = f"restore with 'apmcal restore {link.connection} {report.backup_path}'"
    try:
        failed = [name for name in names if _put_back(link, name, report.previous[name]) is None]
    except KeyboardInterrupt:
        raise ApmcalError(f"{cause}; rollback interrupted: {restore}", link.connection) from None
    if failed:
        lost = [n for n in failed if not math.isfinite(report.previous[n])]
        note = (f" ({', '.join(lost)} held a non-finite value before, which cannot be written "
                f"back)" if lost else "")
        raise ApmcalError(f"{cause}; rollback failed for {', '.join(failed)}{note}: {restore}",
                          link.connection)


def _put_back(link: VehicleLink, name: str, value: float) -> float | None:
    """The value read back once the vehicle holds ``value`` for ``name`` (set, or found
    unchanged); None when that cannot be confirmed."""
    if not math.isfinite(value):    # ardupilot-facts.md: NaN is dropped, never stored
        return None
    echoed = link.set_param(name, value)
    if echoed is None:      # a write the vehicle ignores may still have left the value as it was
        echoed = link.read_param(name)
    return echoed if echoed is not None and same_float32(echoed, value) else None


# ----------------------------------------------------------------------------- restore
def restore_params(link: VehicleLink, backup_path: str | Path,
                   names: list[str] | None = None) -> UploadReport:
    """Put back the values of a backup file (all, or only ``names``), verified by read-back.

    Names the vehicle does not have go to ``skipped``, and names the backup holds only as
    "not restorable" comments to ``unrestorable``. Every other name is tried, even after a
    failure, so the vehicle ends as close to the backup as possible; then one
    :class:`ApmcalError` lists every name that could not be confirmed.
    """
    backup = read_param_file(backup_path)
    unrestorable = [n for n in read_unrestorable(backup_path) if n not in backup]
    wanted = _wanted(backup, unrestorable, names, backup_path)
    current = link.fetch_params()
    changed = {n: v for n, v in wanted.items()
               if n in current and not same_float32(current[n], v)}
    report = UploadReport(backup_path=str(backup_path),
                          previous={n: current[n] for n in changed},
                          skipped=[n for n in wanted if n not in current],
                          unrestorable=[n for n in unrestorable if names is None or n in names])
    failed = []
    for name, value in changed.items():
        echoed = _put_back(link, name, value)
        if echoed is None:
            failed.append(name)
        else:
            report.written[name] = echoed
    if failed:
        skipped = (f"; {len(report.skipped)} names the vehicle does not have skipped"
                   if report.skipped else "")
        raise ApmcalError(f"restore not confirmed for {len(failed)} of {len(changed)} changed "
                          f"parameters: {', '.join(failed)} (all others restored{skipped})",
                          link.connection)
    return report


def _wanted(backup: dict[str, float], unrestorable: list[str], names: list[str] | None,
            backup_path) -> dict[str, float]:
    """The backup's values for ``names`` (all when None); a name it lacks is an error, found
    before anything is written."""
    if names is None:
        return dict(backup)
    absent = [n for n in names if n not in backup and n not in unrestorable]
    if absent:
        raise ApmcalError(f"not in the backup: {', '.join(absent)}; nothing was written",
                          backup_path)
    return {n: backup[n] for n in names if n in backup}
