"""What of a proposal may be written to a parameter file or a vehicle: one rule for every command.

A value is withheld when the firmware would refuse it (outside its parameter ranges or pre-arm
limits for the generation at hand: :func:`firmware_limit_violations`, ardupilot-facts.md "How the
firmware applies the parameters", "ArduPilot's own calibrators") or when its sensor was graded
REDO (the caller says which names: the grade is the report's). Values out of the firmware's
limits are never written; REDO values only when the user says so (:data:`ACCEPT_REDO_FLAG`).
Either way the command says which and exits with status 1 (:attr:`Writable.status`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from apmcal.ardupilot.firmware import firmware_generation, mag_param_names
from apmcal.ardupilot.params import acc_violations, offset_violations, soft_iron_violations

INSTANCES = range(3)        # IMU / compass instances 1..3 (suffix "", "2", "3")
#: the command-line flag that writes values graded REDO all the same
ACCEPT_REDO_FLAG = "--accept-redo"


def firmware_limit_violations(values: dict[str, float],
                              vehicle_params: dict[str, float],
                              generation: str | None = None) -> dict[str, str]:
    """name -> reason, for values of ``values`` outside the limits of
    :mod:`apmcal.ardupilot.params` (the same constants :func:`to_ardupilot_params
    <apmcal.ardupilot.params.to_ardupilot_params>` refuses by). The firmware stores any finite
    value; these are its parameter ranges and pre-arm checks. The generation (unless given) and
    COMPASS_OFFS_MAX come from ``vehicle_params``; compass values are judged as the vehicle will
    hold them after the write (a DIA or offset written alone is checked with the other two axes
    the vehicle has)."""
    generation = generation or firmware_generation(vehicle_params)
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


@dataclass
class Writable:
    """A proposal sorted into what may be written and what is withheld, and why.

    Attributes
    ----------
    values : dict of str to float
        What may be written (name → value).
    redo : dict of str to str
        Withheld because its sensor was graded REDO (name → why); empty with the flag.
    out_of_limits : dict of str to str
        Withheld because the firmware would refuse it (name → why); never written.
    forced : dict of str to str
        Graded REDO but written all the same, because the user gave :data:`ACCEPT_REDO_FLAG`.
    """

    values: dict[str, float] = field(default_factory=dict)
    redo: dict[str, str] = field(default_factory=dict)
    out_of_limits: dict[str, str] = field(default_factory=dict)
    forced: dict[str, str] = field(default_factory=dict)

    @classmethod
    def sort(cls, values: dict[str, float], redo: dict[str, str],
             out_of_limits: dict[str, str] | None = None,
             accept_redo: bool = False) -> "Writable":
        """Sort ``values`` (name → value): names in ``out_of_limits`` are withheld always,
        names in ``redo`` (name → why its sensor is REDO) unless ``accept_redo``."""
        out_of_limits = dict(out_of_limits or {})
        redo = {n: why for n, why in redo.items() if n not in out_of_limits}
        keep = {n: v for n, v in values.items() if n not in out_of_limits
                and (accept_redo or n not in redo)}
        if accept_redo:
            return cls(keep, {}, out_of_limits, {n: w for n, w in redo.items() if n in values})
        return cls(keep, redo, out_of_limits)

    @property
    def withheld(self) -> dict[str, str]:
        """Every name not written, with why."""
        return {**self.out_of_limits, **self.redo}

    @property
    def status(self) -> int:
        """1 when some value is withheld (the command exits with it), else 0."""
        return 1 if self.withheld else 0

    def lines(self, target: str) -> list[str]:
        """What was withheld from ``target`` (a file, a vehicle) and why, one line per reason
        (names sharing a reason together); the forced REDO values too."""
        out = []
        for why, names in _by_reason(self.redo).items():
            out.append(f"not written to {target}: {', '.join(names)}: {why}; "
                       f"{ACCEPT_REDO_FLAG} writes them anyway")
        for why, names in _by_reason(self.out_of_limits).items():
            out.append(f"not written to {target}: {', '.join(names)}: {why} (out of the "
                       "firmware's limits)")
        for why, names in _by_reason(self.forced).items():
            out.append(f"written to {target} although graded REDO ({ACCEPT_REDO_FLAG}): "
                       f"{', '.join(names)}: {why}")
        return out


def _by_reason(reasons: dict[str, str]) -> dict[str, list[str]]:
    """why → the names withheld for it, in the order first seen."""
    out: dict[str, list[str]] = {}
    for name, why in reasons.items():
        out.setdefault(why, []).append(name)
    return out
