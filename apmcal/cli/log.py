"""``apmcal log FILE``: summarise and calibrate a .tlog, .bin, .log or .csv file."""
from __future__ import annotations

from apmcal.cli.common import add_calibration_options, check_outputs, console_for
from apmcal.core.blas_threads import single_threaded_blas
from apmcal.core.errors import ApmcalError


def add_parser(sub) -> None:
    """The ``log`` sub-command and its options."""
    log = sub.add_parser("log", help="summarise and calibrate from a .tlog, .bin, .log or .csv file")
    log.add_argument("file", help="the log: .tlog, dataflash .bin or .log, or .csv")
    add_calibration_options(log)
    log.add_argument("--summary-only", action="store_true", help="only print what the file holds")
    log.add_argument("--layout", default="auto",
                     help="CSV layout: auto, si, imucal, imucal_annotated, mpu6050, imu_tk (default auto)")


@single_threaded_blas      # small BLAS products on long arrays: threads only contend (see there)
def run(args) -> int:
    """``apmcal log``: read a file, summarise and calibrate it; exit status."""
    from apmcal.sources import read_log

    check_outputs(args)
    status, lacking = run_flight(args)      # a flight: the compass check instead
    if status is not None:
        return status
    if args.layout == "auto":
        contents = read_log(args.file)
    else:
        from apmcal.sources.csv import read_csv

        contents = read_csv(args.file, layout=args.layout)
    try:
        return summarise_and_calibrate(contents, args).status
    finally:        # said also when the calibration itself is refused
        if lacking:
            from textwrap import fill

            console_for(args).print("compass in flight: not checked\n" + fill(
                lacking, width=100, initial_indent="  ", subsequent_indent="    "))


def run_flight(args) -> tuple[int | None, str | None]:
    """On a flight log with ``--method auto``: the compass check printed and written, and
    (the exit status, None); for any other file or choice (None, what a flown log lacked for
    the check, or None): the caller calibrates it as before."""
    if args.method != "auto" or args.layout != "auto" or args.summary_only:
        return None, None
    from apmcal.calibration.health import flight_compass

    site = (args.lat, args.lon) if args.lat is not None and args.lon is not None else None
    checked = flight_compass(args.file, site)       # the figures apmcal fleet records too
    result, lacking = checked.result, checked.lacking
    if result is None:
        return None, lacking
    console = console_for(args)
    for line in result.lines():
        console.print(line)
    console.print("IMU calibration: not attempted on a flight log (choose --method static, "
                  "ferraris, ... to calibrate the IMU from its still stretches)")
    from apmcal.calibration.flight_proposal import flight_firmware, flight_writable

    log_params, generation = flight_firmware(args.file)
    writable = flight_writable(result, log_params, generation,
                               getattr(args, "accept_redo", False))
    for line in writable.lines(args.param_file or "the parameter file"):
        console.print(line)
    if args.param_file and writable.values:
        from pathlib import Path

        from apmcal.ardupilot.paramfile import write_param_file

        write_param_file(args.param_file, writable.values,
                         f"apmcal flight compass fit of {Path(args.file).name}",
                         fmt=getattr(args, "param_format", "param"),
                         generation=generation)
        withheld = len(writable.withheld)
        console.print(f"wrote {args.param_file}" + (f" without the {withheld} values withheld "
                                                    "above; exit status 1" if withheld else ""))
    elif args.param_file:
        console.print(f"nothing written to {args.param_file}: every value proposed is withheld "
                      "(above); exit status 1")
    if getattr(args, "report", None):
        from apmcal.report.html import write_flight_html

        console.print(f"wrote {write_flight_html(result, args.report)}")
    if args.json:
        result.save_json(args.json)
        console.print(f"wrote {args.json}")
    return writable.status, None


def summarise_and_calibrate(contents, args):
    """Print the summary and (unless --summary-only) the calibration; write the outputs.

    The JSON file is written last but also when the parameter file could not be (it then says
    why under "param_file_error"), before that error is raised.

    Parameters
    ----------
    contents : LogContents
    args : argparse.Namespace
        The log or live command's options.

    Returns
    -------
    SessionReport
        Its ``status`` is the exit status: 1 when the firmware would reject some proposed value.

    Raises
    ------
    ApmcalError
        When the units are implausible, nothing could be calibrated or an output cannot be
        written.
    """
    from apmcal.report.session import SessionReport
    from apmcal.sources.units import require_plausible_units

    console = console_for(args)
    require_plausible_units(contents)       # a sensor in impossible units is not data
    report = SessionReport.build(contents)
    param_error = None
    if getattr(args, "summary_only", False):
        report.print_summary(console)
    else:
        from apmcal.calibration.log import calibrate_log
        from apmcal.core.options import Options

        report = report.with_calibration(*calibrate_log(contents, Options(
            args.method, args.lat, args.lon, args.min_still, args.instance, args.firmware)))
        report.accept_redo = getattr(args, "accept_redo", False)
        param_error = write_params(report, args.param_file, None,
                                   getattr(args, "param_format", "param"))
        # the verdict first, then how to apply it, the proposal, the numbers; what the file
        # holds last
        report.print_calibration(console, args.verbose, getattr(args, "connection", None))
        console.print()
        report.print_summary(console, args.verbose)
        if args.param_file and param_error is None:
            say_written(console, args.param_file, report.outputs, report.writable)
    if getattr(args, "report", None) and report.calibration is not None:
        from apmcal.report.html import write_session_html

        console.print(f"wrote {write_session_html(report, contents, args.report)}")
    if args.json:
        report.save(args.json)
        console.print(f"wrote {args.json}")
    if param_error is not None:
        raise param_error
    return report


def say_written(console, path, outputs: dict, writable) -> None:
    """"wrote FILE" (naming what was withheld from it), or why nothing was written."""
    if "param_file" not in outputs:
        console.print(f"nothing written to {path}: every value proposed is withheld (above); "
                      "exit status 1")
        return
    withheld = len(writable.withheld) if writable is not None else 0
    console.print(f"wrote {path}" + (f" without the {withheld} values withheld above; exit "
                                     "status 1" if withheld else ""))


def write_params(report, path, console, fmt: str = "param") -> ApmcalError | None:
    """``--param-file``: the proposal written (and said), or the error that stopped it, to be
    raised once the JSON file is written too (``fmt``: "param" or "qgc")."""
    if not path:
        return None
    try:
        report.write_params(path, fmt)
    except ApmcalError as err:
        return err
    if console is not None:
        console.print(f"wrote {path}")
    return None
