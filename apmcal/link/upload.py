"""Write parameters to a vehicle: backed up first, verified by read-back, reversible.

ardupilot-facts.md "Writing parameters": PARAM_SET (REAL32) is answered with PARAM_VALUE
carrying the stored value; unknown names and NaN are dropped silently; the value must be
compared at float32 tolerance by the ground station itself (done by
:meth:`apmcal.link.params.ParamProtocol.set_param`, which returns the value only once confirmed).

Only calibration parameters are written unless the caller asks for all (``all_params``);
counters the vehicle keeps itself are never written (:mod:`apmcal.ardupilot.scope`). The backup
still holds every parameter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from apmcal.ardupilot.limits import firmware_limit_violations
from apmcal.ardupilot.paramfile import read_param_file, read_unrestorable, write_param_file
from apmcal.ardupilot.scope import check_scope, may_write
from apmcal.core.errors import ApmcalError
from apmcal.link.params import ParamProtocol, same_float32

# a put-back matters more than a write: at least this many tries before giving up (more when
# the loss seen on the link calls for them, ParamProtocol.attempts)
ROLLBACK_ATTEMPTS = 5

@dataclass
class UploadReport:
    """What an upload or a restore did.

    Attributes
    ----------
    written : dict of str to float
        Name → value read back.
    previous : dict of str to float
        Name → value before.
    backup_path : str
        The backup file of all parameters.
    skipped : list of str
        Restore: names the vehicle lacks.
    unrestorable : list of str
        Restore: NaN/inf in the backup.
    left_out : list of str
        Restore: differ, but not written (out of scope).
    """
    written: dict[str, float] = field(default_factory=dict)    # name -> value read back
    previous: dict[str, float] = field(default_factory=dict)   # name -> value before
    backup_path: str = ""
    skipped: list[str] = field(default_factory=list)       # restore: names the vehicle lacks
    unrestorable: list[str] = field(default_factory=list)  # restore: NaN/inf in the backup
    left_out: list[str] = field(default_factory=list)      # restore: differ, but not written


# ----------------------------------------------------------------------------- checks
def check_before_writing(values: dict[str, float], vehicle_params: dict[str, float],
                         where: str, all_params: bool = False) -> None:
    """Refuse the whole upload (nothing written) for names out of scope (:func:`check_scope`),
    unknown names, non-finite values, or values outside the firmware's limits.

    Raises
    ------
    ApmcalError
        The first reason found; nothing is written.
    """
    check_scope(values, where, all_params)
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


# ----------------------------------------------------------------------------- upload
def upload_params(link: ParamProtocol, values: dict[str, float], backup_path: str | Path,
                  vehicle_params: dict[str, float] | None = None,
                  all_params: bool = False) -> UploadReport:
    """Back up every parameter, then set ``values`` one by one, verifying each read-back.

    Only calibration parameters unless ``all_params`` (:func:`check_scope`). If any write is
    not confirmed, or the user presses Ctrl-C, every parameter already changed is put back to
    its backed-up value (and that is verified too) before :class:`ApmcalError` is raised: the
    vehicle is never left half-calibrated.

    Parameters
    ----------
    link : ParamProtocol
        The vehicle's link.
    values : dict of str to float
        Parameter name → value to write.
    backup_path : str or Path
        Where the backup of every parameter goes (written before any change).
    vehicle_params : dict of str to float, optional
        The vehicle's parameters, fetched when None.
    all_params : bool, optional
        Allow parameters other than calibration ones.

    Returns
    -------
    UploadReport

    Raises
    ------
    ApmcalError
        A value refused before writing (:func:`check_before_writing`), a write not
        confirmed, or Ctrl-C (all changes rolled back), or a rollback not confirmed.
    """
    check_scope(values, link.connection, all_params)     # before the (slow) parameter list
    if vehicle_params is None:
        vehicle_params = link.fetch_params()
    check_before_writing(values, vehicle_params, link.connection, all_params)
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
        name, value, reported = failure
        # The vehicle may have stored something else (or stored it and lost the answer):
        # the failing name is put back too.
        _roll_back(link, report, also=name, cause=f"write of {name} not confirmed")
        raise ApmcalError(f"write of {value!r} not confirmed ({_reported(reported)}); all "
                          f"changes rolled back from {backup_path}", link.connection,
                          f"param {name}")
    return report


def _reported(value: float | None) -> str:
    """What the vehicle last said about a parameter, for a message."""
    return "no answer" if value is None else f"vehicle reports {value!r}"


def _write_all(link: ParamProtocol, values: dict[str, float], report: UploadReport):
    """Set ``values`` in order into ``report.written``; (name, value, last reported value) of
    the first write not confirmed, None when all are."""
    for name, value in values.items():
        confirmed = link.set_param(name, value)
        if not _is_held(confirmed, value):
            return name, value, confirmed
        report.written[name] = confirmed
    return None


def _roll_back(link: ParamProtocol, report: UploadReport, also: str | None, cause: str) -> None:
    """Put every written name, and ``also`` (the write under way), back to its backed-up value.

    A rollback that fails, or is itself interrupted, names the command that finishes it.
    """
    names = [*report.written, *([also] if also is not None else [])]
    restore = f"restore with 'apmcal restore {link.connection} {report.backup_path}'"
    failed = {}
    try:
        for name in names:
            previous = report.previous[name]
            if not math.isfinite(previous):   # ardupilot-facts.md: NaN is dropped, never stored
                failed[name] = "held a non-finite value before, which cannot be written back"
            elif not _is_held(reported := _put_back(link, name, previous), previous):
                failed[name] = _reported(reported)
    except KeyboardInterrupt:
        raise ApmcalError(f"{cause}; rollback interrupted: {restore}", link.connection) from None
    if failed:
        raise ApmcalError(f"{cause}; rollback not confirmed for {_listed(failed)}: {restore}",
                          link.connection)


def _listed(said: dict[str, str]) -> str:
    """'A (vehicle reports 0.3), B (no answer)'."""
    return ", ".join(f"{name} ({why})" for name, why in said.items())


def _is_held(reported: float | None, value: float) -> bool:
    """True when the vehicle confirmed holding ``value``."""
    return reported is not None and same_float32(reported, value)


def _put_back(link: ParamProtocol, name: str, value: float) -> float | None:
    """What the vehicle last reported for ``name`` after being set back to ``value`` (that
    value once confirmed); None when it never answered. Tried as often as the link's loss
    calls for (:meth:`ParamProtocol.attempts`), at least ROLLBACK_ATTEMPTS times."""
    return link.set_param(name, value, attempts=link.attempts(ROLLBACK_ATTEMPTS))


# ----------------------------------------------------------------------------- restore
def restore_params(link: ParamProtocol, backup_path: str | Path,
                   names: list[str] | None = None, all_params: bool = False) -> UploadReport:
    """Put back the values of a backup file (all, or only ``names``), verified by read-back.

    Only calibration parameters are written unless ``all_params``, and never counters
    (:func:`may_write`): the others that differ from the vehicle go to ``left_out``. Names the
    vehicle does not have go to ``skipped``, and names the backup holds only as "not
    restorable" comments to ``unrestorable``. Every other name is tried, even after a failure,
    so the vehicle ends as close to the backup as possible; then one :class:`ApmcalError` lists
    every name that could not be confirmed.

    Parameters
    ----------
    link : ParamProtocol
        The vehicle's link.
    backup_path : str or Path
        A backup written by :func:`upload_params` (or any parameter file).
    names : list of str, optional
        Only these names; all when None.
    all_params : bool, optional
        Allow parameters other than calibration ones.

    Returns
    -------
    UploadReport

    Raises
    ------
    ApmcalError
        An unreadable backup, a name it lacks or that is out of scope, or writes not
        confirmed.
    """
    backup = read_param_file(backup_path)
    unrestorable = [n for n in read_unrestorable(backup_path) if n not in backup]
    wanted = _wanted(backup, unrestorable, names, backup_path)
    if names is not None:       # asked for by name: out of scope is an error, not a silent skip
        check_scope(wanted, str(backup_path), all_params)
    in_scope = {n: v for n, v in wanted.items() if may_write(n, all_params)}
    current = link.fetch_params()
    changed = {n: v for n, v in in_scope.items()
               if n in current and not same_float32(current[n], v)}
    report = UploadReport(backup_path=str(backup_path),
                          previous={n: current[n] for n in changed},
                          skipped=[n for n in in_scope if n not in current],
                          unrestorable=[n for n in unrestorable if names is None or n in names],
                          left_out=[n for n, v in wanted.items() if n not in in_scope
                                    and n in current and not same_float32(current[n], v)])
    failed = {}
    for name, value in changed.items():     # read_param_file refuses NaN: all are finite
        reported = _put_back(link, name, value)
        if _is_held(reported, value):
            report.written[name] = reported
        else:
            failed[name] = _reported(reported)
    if failed:
        skipped = (f"; {len(report.skipped)} names the vehicle does not have skipped"
                   if report.skipped else "")
        raise ApmcalError(f"restore not confirmed for {len(failed)} of {len(changed)} changed "
                          f"parameters: {_listed(failed)} (all others restored{skipped})",
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
