"""What of a flight's compass proposal may be written, by the one rule of every command
(:class:`apmcal.ardupilot.limits.Writable`), and the flight log's firmware it is judged for:
shared by ``apmcal log`` on a flight and the browser interface (moved here from the command
line, unchanged)."""
from __future__ import annotations


def flight_writable(result, log_params: dict, generation: str, accept_redo: bool = False):
    """What of a flight's compass proposal may be written (the one rule of
    :class:`apmcal.ardupilot.limits.Writable`): a compass whose proposed calibration is graded
    REDO is withheld unless --accept-redo, one with a value out of the firmware's limits
    always, whole."""
    from apmcal.ardupilot.limits import Writable, firmware_limit_violations

    values, redo, refused = result.params(), {}, {}
    for c in result.compasses:
        names = [n for n in c.proposed if n in values]
        grade = getattr(getattr(c, "health_proposed", None), "verdict", None)
        if grade == "redo":
            redo |= {n: f"compass {c.instance}'s proposed calibration is graded REDO"
                     for n in names}
        limits = firmware_limit_violations({n: values[n] for n in names},
                                           {**log_params, **c.in_force}, generation)
        if limits:
            first = next(iter(limits))
            refused |= {n: limits.get(n, f"withheld with the rest of compass {c.instance} "
                                         f"({first} refused)") for n in names}
    return Writable.sort(values, redo, refused, accept_redo)


def flight_firmware(path) -> tuple[dict, str]:
    """The parameters of a flight log (its COMPASS_OFFS_MAX for the firmware's limits) and its
    firmware generation ("3.2" or "3.3+")."""
    from apmcal.ardupilot.firmware import firmware_generation
    from apmcal.sources import read_log

    contents = read_log(path)
    return dict(contents.params), firmware_generation(contents.params, contents.firmware)
