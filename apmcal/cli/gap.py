"""The ``apmcal gap`` command: arguments in, summary and files out (see ``apmcal gap --help``)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from apmcal.core.errors import ApmcalError

if TYPE_CHECKING:
    from apmcal.core.options import Options


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
    from apmcal.cli import check_writable

    check_writable(args.json, "JSON file")
    check_writable(args.write_twin, "twin file")
    if args.report is not None:
        report = Path(args.report)
        if report.exists() and not report.is_dir():
            raise ApmcalError("cannot write the report: not a directory", str(report))
        if not report.exists() and not report.parent.is_dir():
            raise ApmcalError(f"cannot write the report: {report.parent} does not exist",
                              str(report))


def run_gap(args, console) -> int:
    """Run the diagnosis (or its benchmark) and write what was asked for.

    Raises
    ------
    ApmcalError
        When --lon comes without --lat, no log file is given (and no --benchmark), or an
        effect name or output path is not usable.
    """
    if args.lon is not None and args.lat is None:
        raise ApmcalError("--lon needs --lat")
    if args.benchmark:
        from apmcal_sim.gap_benchmark import run_benchmark

        check_outputs(args)
        return run_benchmark(args, console)
    if args.file is None:
        raise ApmcalError("give a log file (or --benchmark)")
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

    opts = Options(lat_deg=args.lat, lon_deg=args.lon, min_still_s=args.min_still,
                   instance=args.instance, generation=args.firmware)
    diagnose, [(session, warnings, error)] = workers.beside(
        LogReading(args.file, opts), [("session", ())], _import_diagnosis)
    for line in warnings:
        console.print(line, soft_wrap=True)
    if error is not None:
        raise error
    with console.status("diagnosing") as status:
        return diagnose(session, names, seed=args.seed,
                        progress=lambda msg: status.update(f"diagnosing: {msg}"))


def _import_diagnosis():
    from apmcal.diagnosis.run import diagnose, preload_imports

    preload_imports()
    return diagnose


@dataclass(frozen=True)
class LogReading:
    """One log to read and cut into a diagnosis session (a job for a forked worker).

    Attributes
    ----------
    file : str
        The log.
    options : Options
        Site and session options.
    """

    file: str
    options: Options

    def session(self) -> tuple:
        """(session or None, the log's warning lines, the ApmcalError that stopped the reading
        or None): the warnings are printed even when the log is then refused."""
        from apmcal.diagnosis.session.log import session_from_log
        from apmcal.sources import read_log
        from apmcal.sources.units import require_plausible_units

        warnings: list[str] = []
        try:
            contents = read_log(self.file)
            require_plausible_units(contents)   # a sensor in impossible units is not data
            warnings = [line for line in contents.messages if line.startswith("warning: ")]
            return session_from_log(contents, self.options), warnings, None
        except ApmcalError as err:
            return None, warnings, err
