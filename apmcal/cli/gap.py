"""``apmcal gap FILE``: the gap between a real log and its simulated twin — where it lies, which
unmodelled effect causes it (:mod:`apmcal.diagnosis`); summary and files out."""
from __future__ import annotations

from apmcal.cli.common import (
    add_session_options,
    check_writable,
    check_writable_dir,
    console_for,
    number_type,
)
from apmcal.core.errors import ApmcalError


def add_parser(sub) -> None:
    """The ``gap`` sub-command and its options."""
    gap = sub.add_parser("gap", help="diagnose the gap between a real log and its simulated "
                                     "twin: where it lies, which unmodelled effect causes it")
    gap.add_argument("file", nargs="?", help=".tlog, .bin, .log or .csv file")
    gap.add_argument("--lat", type=number_type(float, -90, 90, what="latitude [deg]"),
                     default=None, help="latitude [deg]: local gravity, Earth rate, WMM field")
    gap.add_argument("--lon", type=number_type(float, -180, 180, what="longitude [deg]"),
                     default=None, help="longitude [deg] (needs --lat): WMM field and "
                                        "declination for the compass")
    add_session_options(gap)
    gap.add_argument("--effects", default=None, metavar="A,B,...",
                     help="candidate effects to test (default: all; see apmcal.diagnosis."
                          "model.effects)")
    gap.add_argument("--seed", type=int, default=0, help="seed of the twin's noise (default 0)")
    gap.add_argument("--json", default=None, help="write the result as JSON")
    gap.add_argument("--report", default=None, metavar="DIR",
                     help="write a Markdown report with PNG plots into DIR")
    gap.add_argument("--write-twin", default=None, metavar="TWIN.json|TWIN.parm",
                     help="write the selected effects as a simulator configuration "
                          "(python -m apmcal_sim --twin TWIN.json), or with .parm/.param as "
                          "ArduPilot SITL parameters (docs/sitl-twin.md)")
    gap.add_argument("--twin-log", default=None, metavar="TWIN",
                     help="a recorded twin instead of the simulated one: the same session "
                          "recorded again by a simulator set up with --write-twin (e.g. "
                          "ArduPilot SITL), in the log's format and rate; says what is left "
                          "between the board and that recording (docs/sitl-twin.md)")
    gap.add_argument("--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    """``apmcal gap``: :func:`run_gap` with the command's console; exit status."""
    return run_gap(args, console_for(args))


def parse_effects(text: str | None) -> list[str] | None:
    """The --effects list, checked against the candidate names.

    Parameters
    ----------
    text : str or None
        Comma-separated effect names, as given (None: option not given).

    Returns
    -------
    list of str or None
        The names, or None for every candidate.

    Raises
    ------
    ApmcalError
        When a name is not a candidate effect or the list is empty.
    """
    if text is None:
        return None
    from apmcal.diagnosis.model.effects import NAMES

    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in NAMES]
    if unknown or not names:
        raise ApmcalError(f"--effects: unknown {', '.join(unknown) or 'empty list'}; "
                          f"choose from {', '.join(NAMES)}")
    return names


def check_outputs(args) -> None:
    """Every output path checked before the (long) work starts.

    Raises
    ------
    ApmcalError
        When the JSON or twin file cannot be written, or the report path is not a directory
        or its parent does not exist.
    """
    check_writable(args.json, "JSON file")
    check_writable(args.write_twin, "twin file")
    check_writable_dir(args.report, "the report")


def run_gap(args, console) -> int:
    """Run the diagnosis and write what was asked for.

    Raises
    ------
    ApmcalError
        When --lon comes without --lat, or an effect name or output path is not usable.
    """
    if args.lon is not None and args.lat is None:
        raise ApmcalError("--lon needs --lat")
    if args.file is None:
        raise ApmcalError("give a log file")
    names = parse_effects(args.effects)
    check_outputs(args)
    diagnosis = diagnose_file(args, names, console)
    from apmcal.diagnosis.output.summary import print_summary

    print_summary(diagnosis.result, console)
    if args.json:
        diagnosis.result.save(args.json)
        console.print(f"wrote {args.json}")
    if args.report:
        from apmcal.diagnosis.output.report import write_report

        path = write_report(diagnosis, args.report)
        console.print(f"wrote {path}")
    if args.write_twin:
        from apmcal.diagnosis.twin.file import write_twin

        write_twin(diagnosis, args.write_twin)
        sitl = str(args.write_twin).lower().endswith((".parm", ".param"))
        console.print(f"wrote {args.write_twin} ("
                      + ("ArduPilot SITL parameters" if sitl else
                         f"python -m apmcal_sim --twin {args.write_twin}") + ")")
    return 0


def diagnose_file(args, names, console):
    """Read, cut and diagnose the log, with a progress line per stage.

    The log is read and cut in a forked process while this one imports the diagnosis (scipy's
    optimize, signal and stats packages, sitl): reading needs none of it (it imports pandas,
    which the diagnosis does not need), and the second core would otherwise be idle then."""
    from apmcal.core.options import Options
    from apmcal.diagnosis.compute import workers
    from apmcal.diagnosis.reading import LogReading, import_diagnosis

    opts = Options(lat_deg=args.lat, lon_deg=args.lon, min_still_s=args.min_still,
                   instance=args.instance, generation=args.firmware)
    diagnose, [(session, warnings, error)] = workers.beside(
        LogReading(args.file, opts), [("session", ())], import_diagnosis)
    for line in warnings:
        console.print(line, soft_wrap=True)
    if error is not None:
        raise error
    twin = recorded_twin(args.twin_log, session, opts) if args.twin_log else None
    with console.status("diagnosing") as status:
        return diagnose(session, names, seed=args.seed, twin=twin,
                        progress=lambda msg: status.update(f"diagnosing: {msg}"))


def recorded_twin(path: str, session, opts):
    """The twin log read, cut and put on ``session``'s samples
    (:func:`apmcal.diagnosis.session.twin_log.on_samples_of`).

    Raises
    ------
    ApmcalError
        When the twin log cannot be read or cut, or does not match the real session."""
    from apmcal.diagnosis.reading import LogReading
    from apmcal.diagnosis.session.twin_log import on_samples_of

    twin, _, error = LogReading(path, opts).session()
    if error is not None:
        raise error
    return on_samples_of(session, twin, path)
