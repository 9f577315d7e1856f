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
from apmcal.sources.live import VehicleLink, float32
from apmcal.vehicle.paramfile import read_param_file, write_param_file


@dataclass
class UploadReport:
    written: dict[str, float] = field(default_factory=dict)    # name -> value read back
    previous: dict[str, float] = field(default_factory=dict)   # name -> value before
    backup_path: str = ""


def same_float32(a: float, b: float) -> bool:
    """True if ``a`` and ``b`` are the same value once stored as float32."""
    return np.float32(a) == np.float32(b)


def check_before_writing(values: dict[str, float], vehicle_params: dict[str, float],
                         where: str) -> None:
    """Refuse the whole upload (nothing written) for unknown names or non-finite values."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise ApmcalError(f"value {value!r} is not finite; nothing was written", where,
                              f"param {name}")
        if name not in vehicle_params:
            raise ApmcalError("the vehicle has no such parameter (wrong firmware generation?); "
                              "nothing was written", where, f"param {name}")


def upload_params(link: VehicleLink, values: dict[str, float], backup_path: str | Path,
                  vehicle_params: dict[str, float] | None = None) -> UploadReport:
    """Back up every parameter, then set ``values`` one by one, verifying each read-back.

    If any write is not confirmed, every parameter already changed is put back to its backed-up
    value (and that is verified too) before :class:`ApmcalError` is raised: the vehicle is never
    left half-calibrated.
    """
    if vehicle_params is None:
        vehicle_params = link.fetch_params()
    check_before_writing(values, vehicle_params, link.connection)
    write_param_file(backup_path, vehicle_params,
                     f"apmcal backup of all parameters of {link.connection} before upload")
    report = UploadReport(backup_path=str(backup_path),
                          previous={n: vehicle_params[n] for n in values})
    for name, value in values.items():
        echoed = link.set_param(name, value)
        if echoed is None or not same_float32(echoed, value):
            # The vehicle may have stored something else (or stored it and lost the answer):
            # the failing name is put back too.
            _roll_back(link, report, also=name)
            got = "no answer" if echoed is None else f"read back {echoed!r}"
            raise ApmcalError(f"write of {value!r} not confirmed ({got}); all changes rolled "
                              f"back from {backup_path}", link.connection, f"param {name}")
        report.written[name] = echoed
    return report


def _roll_back(link: VehicleLink, report: UploadReport, also: str) -> None:
    """Put every written name, and the one that failed, back to its backed-up value."""
    failed = [name for name in [*report.written, also]
              if not _put_back(link, name, report.previous[name])]
    if failed:
        raise ApmcalError(f"rollback failed for {', '.join(failed)}: restore with "
                          f"'apmcal restore {link.connection} {report.backup_path}'",
                          link.connection)


def _put_back(link: VehicleLink, name: str, value: float) -> bool:
    """True once the vehicle holds ``value`` for ``name`` (set, or found unchanged)."""
    echoed = link.set_param(name, value)
    if echoed is None:      # a write the vehicle ignores may still have left the value as it was
        echoed = link.read_param(name)
    return echoed is not None and same_float32(echoed, value)


def restore_params(link: VehicleLink, backup_path: str | Path,
                   names: list[str] | None = None) -> UploadReport:
    """Put back the values of a backup file (all, or only ``names``), verified by read-back."""
    backup = read_param_file(backup_path)
    wanted = {n: backup[n] for n in (names or backup)}
    current = link.fetch_params()
    changed = {n: v for n, v in wanted.items()
               if n in current and not same_float32(current[n], v)}
    report = UploadReport(backup_path=str(backup_path),
                          previous={n: current[n] for n in changed})
    for name, value in changed.items():
        echoed = link.set_param(name, value)
        if echoed is None or not same_float32(echoed, float32(value)):
            raise ApmcalError(f"restore of {value!r} not confirmed", link.connection,
                              f"param {name}")
        report.written[name] = echoed
    return report
