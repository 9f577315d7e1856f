"""What of a flight's compass proposal may be written, by the one rule of every command
(:class:`apmcal.ardupilot.limits.Writable`), and the flight log's firmware it is judged for:
shared by ``apmcal log`` on a flight and the browser interface (moved here from the command
line, unchanged)."""
from __future__ import annotations


def flight_writable(result, log_params: dict, generation: str, accept_redo: bool = False):
    """What of a flight's compass proposal may be written (the one rule of
    :class:`apmcal.ardupilot.limits.Writable`): a compass whose proposed calibration is graded
    REDO is withheld unless --accept-redo, one with a value out of the firmware's limits
    always, whole. A parameter the compasses share (COMPASS_MOTCT: one for all of them) is
    withheld only with every compass that proposes it: a compass written with its COMPASS_MOT
    needs the MOTCT that switches them on."""
    from apmcal.ardupilot.limits import Writable, firmware_limit_violations

    values, redo, refused = result.params(), {}, {}
    kept_by: dict[str, bool] = {}           # name → some compass proposing it is written
    for c in result.compasses:
        names = [n for n in c.proposed if n in values]
        grade = getattr(getattr(c, "health_proposed", None), "verdict", None)
        why_redo = {}
        if grade == "redo":
            why_redo = {n: f"compass {c.instance}'s proposed calibration is graded REDO"
                        for n in names}
        limits = firmware_limit_violations({n: values[n] for n in names},
                                           {**log_params, **c.in_force}, generation)
        why_refused = {}
        if limits:
            first = next(iter(limits))
            why_refused = {n: limits.get(n, f"withheld with the rest of compass {c.instance} "
                                            f"({first} refused)") for n in names}
        written = not why_refused and (accept_redo or not why_redo)
        for n in names:
            kept_by[n] = kept_by.get(n, False) or written
        redo |= why_redo
        refused |= why_refused
    redo = {n: why for n, why in redo.items() if not kept_by.get(n)}
    refused = {n: why for n, why in refused.items() if not kept_by.get(n)}
    return Writable.sort(values, redo, refused, accept_redo)


def flight_firmware(path) -> tuple[dict, str]:
    """The parameters of a flight log (its COMPASS_OFFS_MAX for the firmware's limits) and its
    firmware generation ("3.2" or "3.3+")."""
    from apmcal.ardupilot.firmware import firmware_generation
    from apmcal.sources import read_log

    contents = read_log(path)
    return dict(contents.params), firmware_generation(contents.params, contents.firmware)
