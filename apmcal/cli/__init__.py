"""The ``apmcal`` command line.

    apmcal log FILE [--method M] [--lat DEG --lon DEG] [--param-file OUT] [--json OUT]
    apmcal live CONNECTION [--duration S] [--rate HZ] [--method M] [--upload] ...
    apmcal upload CONNECTION FILE.param [--backup FILE] [--all-params]
    apmcal restore CONNECTION BACKUP.param [--all-params]
    apmcal tcal LOG [--param-file OUT] [--upload CONNECTION]

Every failure the user can cause ends in one line on stderr and a non-zero exit status; Ctrl-C
ends with one line and status 130 (128 + SIGINT, the shell's convention).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
import warnings
from pathlib import Path

from apmcal.core.blas_threads import one_blas_thread_from_start, single_threaded_blas
from apmcal.core.errors import ApmcalError

EXIT_USER_ERROR = 2
EXIT_INTERNAL_ERROR = 3
EXIT_INTERRUPTED = 130          # 128 + SIGINT, what a shell reports for a Ctrl-C'd program


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (the project rule), exit status 2."""

    def error(self, message):
        """Print ``message`` as one line on stderr and exit with status 2."""
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def number_type(kind, low=None, high=None, low_open=False, what="a number"):
    """An argparse ``type=`` accepting a finite ``kind`` (int/float) in [low, high] (or (low,
    high] with ``low_open``); anything else is argparse's one-line usage error.

    Parameters
    ----------
    kind : type
        int or float.
    low, high : float, optional
        Bounds, in the option's own unit (s, Hz, deg, baud).
    low_open : bool
        Exclude ``low`` itself.
    what : str
        What the number is, for the message ("seconds", "latitude [deg]").

    Returns
    -------
    callable
        str → ``kind``, raising argparse.ArgumentTypeError for anything else.
    """
    lo = "" if low is None else (f"> {low:g}" if low_open else f">= {low:g}")
    hi = "" if high is None else f"<= {high:g}"
    wanted = f"{what} " + (f"in {'(' if low_open else '['}{low:g}, {high:g}]"
                           if lo and hi else lo or hi)

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted.strip()}, got {text!r}") from None
        if (not math.isfinite(value) or (low is not None and (value <= low if low_open
                                                                 else value < low))
                or (high is not None and value > high)):
            raise argparse.ArgumentTypeError(f"expected {wanted.strip()}, got {text!r}")
        return value

    parse.__name__ = kind.__name__
    return parse


POSITIVE_SECONDS = number_type(float, 0, low_open=True, what="seconds")
SAMPLE_RATE_HZ = number_type(float, 10, 2000, what="Hz")


def build_parser() -> argparse.ArgumentParser:
    """The ``apmcal`` parser with its sub-commands log, live, upload, restore, gap, tcal."""
    parser = OneLineParser(prog="apmcal", description=__doc__.split("\n")[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", required=True)

    log = sub.add_parser("log", help="summarise and calibrate from a .tlog, .bin, .log or .csv file")
    log.add_argument("file")
    add_calibration_options(log)
    log.add_argument("--summary-only", action="store_true", help="only print what the file holds")
    log.add_argument("--layout", default="auto",
                     help="CSV layout: auto, si, imucal, imucal_annotated, mpu6050, imu_tk (default auto)")

    live = sub.add_parser("live", help="record from a vehicle over MAVLink and calibrate")
    live.add_argument("connection", help="pymavlink connection string, e.g. udp:127.0.0.1:14550")
    add_baud_option(live)
    live.add_argument("--duration", type=POSITIVE_SECONDS, default=60.0,
                      help="seconds to record (default 60)")
    live.add_argument("--rate", type=number_type(int, 1, 1000, what="an integer rate [Hz]"),
                      default=50, help="IMU stream rate [Hz], 1 to 1000 (default 50)")
    live.add_argument("--save-log", default=None, help="keep the recording as this .tlog")
    live.add_argument("--guide", choices=["ardupilot6"], default=None,
                      help="prompt ArduPilot's six accel-cal poses one by one, check each "
                           "(instead of --duration); Enter confirms a pose")
    live.add_argument("--auto", action="store_true",
                      help="with --guide: no Enter, wait for the vehicle to be still in the "
                           "pose asked for")
    live.add_argument("--hold", type=POSITIVE_SECONDS, default=10.0,
                      help="seconds held still per pose with --guide (vehicle clock)")
    live.add_argument("--face-timeout", type=POSITIVE_SECONDS, default=120.0,
                      help="longest wait for each pose with --guide: key press, stillness, "
                           "hold (default 120 s)")
    live.add_argument("--upload", action="store_true",
                      help="write the proposed parameters to the vehicle (backed up, verified)")
    live.add_argument("--backup", default=None, help="backup file (default apmcal-backup-<time>.param)")
    add_calibration_options(live)

    add_upload_parsers(sub)

    add_gap_parser(sub)
    add_tcal_parser(sub)
    return parser


class VersionAction(argparse.Action):
    """``--version``: the version looked up only when asked for (importlib.metadata and the
    distribution lookup cost ~0.08 s, a quarter of ``apmcal --help``)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                         help="show program's version number and exit", **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        """Print ``apmcal <version>`` on stdout and exit."""
        print(f"{parser.prog} {package_version()}")      # stdout, as argparse's own action
        parser.exit()


def package_version() -> str:
    """The installed distribution's version (pyproject.toml), "unknown" when not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("apmcal")
    except PackageNotFoundError:
        return "unknown (not installed)"


def add_baud_option(p: argparse.ArgumentParser) -> None:
    """--baud for serial connections (/dev/ttyACM0, /dev/ttyUSB0, COM3), as MAVProxy has."""
    from apmcal.core.constants import DEFAULT_BAUD

    p.add_argument("--baud", type=number_type(int, 1, 12_000_000, what="a baud rate"),
                   default=DEFAULT_BAUD,
                   help=f"serial baud rate (default {DEFAULT_BAUD}: USB; 57600 for 3DR/SiK "
                        "telemetry radios); ignored by udp:/tcp: connections")


ALL_PARAMS_HELP = ("also write parameters that are not calibration (counters such as STAT_* "
                   "are never written)")


def add_upload_parsers(sub) -> None:
    """``apmcal upload`` and ``apmcal restore``."""
    from apmcal.ardupilot.scope import CALIBRATION_IN_WORDS

    upload = sub.add_parser(
        "upload", help="write a .param file to a vehicle: backed up, verified, rolled back on "
                       "failure",
        description="Write the calibration parameters of a .param file (NAME VALUE lines) to a "
                    "vehicle. Every parameter of the vehicle is first saved to a backup file; "
                    "each write is verified by read-back; if one cannot be confirmed, or on "
                    "Ctrl-C, every change is put back. Only calibration parameters "
                    f"({CALIBRATION_IN_WORDS}) unless --all-params; the file is checked "
                    "before anything is written.")
    upload.add_argument("connection", help="pymavlink connection string, e.g. "
                                           "udp:127.0.0.1:14550")
    upload.add_argument("param_file", help="the parameters to write (.param: NAME VALUE lines)")
    upload.add_argument("--backup", default=None,
                        help="backup file (default apmcal-backup-<time>.param)")
    upload.add_argument("--all-params", action="store_true", help=ALL_PARAMS_HELP)
    add_baud_option(upload)

    restore = sub.add_parser(
        "restore", help="put back the calibration parameters of a backup .param file",
        description="Put back the values of a backup file (as written by upload or live "
                    "--upload), each verified by read-back. Only calibration parameters that "
                    "differ from the vehicle are written unless --all-params; counters the "
                    "vehicle keeps (STAT_*) never are. Every name is tried, then the ones that "
                    "could not be confirmed are listed.")
    restore.add_argument("connection", help="pymavlink connection string, e.g. "
                                            "udp:127.0.0.1:14550")
    restore.add_argument("backup_file", help="the backup .param file")
    restore.add_argument("--all-params", action="store_true", help=ALL_PARAMS_HELP)
    add_baud_option(restore)


def add_tcal_parser(sub) -> None:
    """``apmcal tcal LOG``: ArduPilot's IMU temperature calibration."""
    tcal = sub.add_parser("tcal", help="fit ArduPilot's IMU temperature calibration "
                                       "(INS_TCALn_*) from a still warm-up log")
    tcal.add_argument("file", help="dataflash .bin/.log (IMU with temperature, or TCLR) or "
                                   ".tlog (RAW_IMU/SCALED_IMU with temperature)")
    tcal.add_argument("--records", choices=["auto", "imu", "tclr"], default="auto",
                      help="TCLR (the firmware learner's records), IMU samples, or auto: "
                           "TCLR when present (default)")
    tcal.add_argument("--instance", type=int, default=None, help="IMU instance (default: all)")
    tcal.add_argument("--min-still", type=POSITIVE_SECONDS, default=2.0, metavar="S",
                      help="shortest still period used [s] (default 2)")
    tcal.add_argument("--param-file", default=None, help="write INS_TCALn_* (.param)")
    tcal.add_argument("--upload", default=None, metavar="CONNECTION",
                      help="write INS_TCALn_* to the vehicle (backed up, verified)")
    tcal.add_argument("--backup", default=None, help="backup file with --upload "
                                                     "(default apmcal-backup-<time>.param)")
    add_baud_option(tcal)
    tcal.add_argument("--json", default=None, help="write the fit as JSON")
    tcal.add_argument("--quiet", action="store_true")


def cmd_tcal(args) -> int:
    """``apmcal tcal``: fit, print and write or upload the temperature calibration; exit status."""
    from apmcal.calibration.tcal import calibrate_temperature, tcal_params
    from apmcal.report.tcal import print_tcal
    from apmcal.sources import read_log
    from apmcal.sources.units import require_plausible_units

    check_writable(args.param_file, "parameter file")
    check_writable(args.json, "JSON file")
    if args.upload:
        check_writable(args.backup or default_backup_name(), "backup file")

    console = console_for(args)
    contents = read_log(args.file)
    require_plausible_units(contents)       # a sensor in impossible units is not data
    results = calibrate_temperature(contents, args.records, args.instance, args.min_still)
    print_tcal(results, console)
    values = tcal_params(results)
    if args.json:
        write_json(args.json, {"tcal": [r.to_dict() for r in results], "params": values})
    if args.param_file:
        from apmcal.ardupilot.paramfile import write_param_file

        write_param_file(args.param_file, values, f"apmcal tcal of {args.file}")
        console.print(f"wrote {args.param_file}")
    if args.upload:
        upload_values(args.upload, values, args.backup, None, console, args.baud)
        # AP_InertialSensor_tempcal.cpp: INS_TCALn_ENABLE is @RebootRequired
        console.print("INS_TCALn_ENABLE takes effect at the vehicle's next reboot")
    return 0


def add_gap_parser(sub) -> None:
    """``apmcal gap``: the gap between a real log and its simulated twin (:mod:`apmcal.diagnosis`)."""
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
                          "effects)")
    gap.add_argument("--seed", type=int, default=0, help="seed of the twin's noise (default 0)")
    gap.add_argument("--json", default=None, help="write the result as JSON")
    gap.add_argument("--report", default=None, metavar="DIR",
                     help="write a Markdown report with PNG plots into DIR")
    gap.add_argument("--write-twin", default=None, metavar="TWIN.json|TWIN.parm",
                     help="write the selected effects as a simulator configuration "
                          "(python -m apmcal_sim --twin TWIN.json), or with .parm/.param as "
                          "ArduPilot SITL parameters (docs/sitl-twin.md)")
    gap.add_argument("--benchmark", action="store_true",
                     help="instead of a log: simulate sessions with one effect withheld from "
                          "the twin and check the diagnosis finds it")
    gap.add_argument("--quick", action="store_true", help="with --benchmark: a small run")
    gap.add_argument("--rate", type=SAMPLE_RATE_HZ, default=None, metavar="HZ",
                     help="with --benchmark: the simulated sessions' sample rate [Hz] "
                          "(default 100, 50 with --quick; above 200 the slow effects are "
                          "scored on block means)")
    gap.add_argument("--quiet", action="store_true")


def add_session_options(p: argparse.ArgumentParser) -> None:
    """Which samples of a log make the session: IMU instance, holds, parameter generation."""
    p.add_argument("--instance", type=int, default=None, help="IMU instance (default: first)")
    p.add_argument("--min-still", type=POSITIVE_SECONDS, default=2.0, metavar="S",
                   help="shortest still period counted as a hold [s] (default 2)")
    p.add_argument("--firmware", choices=["3.2", "3.3+"], default=None,
                   help="parameter generation (default: from the log; Copter 3.2 is APM 2.x)")


def add_calibration_options(p: argparse.ArgumentParser) -> None:
    """Method, site (--lat/--lon [deg]), session and output options of log and live."""
    p.add_argument("--method", default="auto",
                   choices=["auto", "ferraris", "static", "ellipsoid", "joint"],
                   help="calibration method (default auto: ferraris for the six faces, "
                        "joint for hand-held poses with a compass, ellipsoid without one, "
                        "static for one level hold)")
    p.add_argument("--lat", type=number_type(float, -90, 90, what="latitude [deg]"), default=None,
                   help="latitude [deg], -90 to 90: normal gravity and Earth rate; with --lon "
                        "also the magnetometer's field magnitude (WMM). --lat alone is fine")
    p.add_argument("--lon", type=number_type(float, -180, 180, what="longitude [deg]"),
                   default=None, help="longitude [deg], -180 to 180 (needs --lat): only for the "
                                      "magnetometer's field magnitude (WMM)")
    add_session_options(p)
    p.add_argument("--param-file", default=None, help="write proposed parameters (.param)")
    p.add_argument("--json", default=None,
                   help="write summary and calibration as JSON (also when --param-file fails)")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--verbose", action="store_true",
                   help="also print the specialist's lines (fit internals, paper references, "
                        "the model's misfit); the --json output always has them")


def main(argv: list[str] | None = None, *, operator=None) -> int:
    """Run the command line; Ctrl-C anywhere in it (imports included) ends in one line, 130.
    ``operator``: where ``live --guide`` prompts and reads key presses (default: this
    terminal; a :class:`apmcal.calibration.guided.Operator`, for tests).

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: ``sys.argv[1:]``).
    operator : Operator, optional

    Returns
    -------
    int
        Exit status: 0 done, 1 some proposed value out of the firmware's limits, 2 a user
        error, 3 an internal error, 130 interrupted.
    """
    try:
        return run(argv, operator)
    except KeyboardInterrupt:
        print("apmcal: interrupted (Ctrl-C)", file=sys.stderr)
        return EXIT_INTERRUPTED


def entry() -> None:
    """The ``apmcal`` program (console script and ``python -m apmcal``): :func:`main`, then
    the exit.

    After ``apmcal gap`` — whose files are all written and closed by then — the process ends
    without Python's own teardown, which would free the diagnosis's residuals object by object
    (the operating system takes the memory back at once). The other commands (vehicle links,
    parameter files) exit the ordinary way."""
    code = main()
    command = next((a for a in sys.argv[1:] if not a.startswith("-")), None)
    if command == "gap":
        logging.shutdown()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):    # a closed pipe (| head): nothing left to say
                pass
        os._exit(code)
    sys.exit(code)


def run(argv: list[str] | None, operator=None) -> int:
    """:func:`main` without the Ctrl-C handling: parse, check, run the command; exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    args.guide_operator = operator
    if args.command == "log":
        one_blas_thread_from_start()        # before numpy loads (see apmcal.core.blas_threads)
    if getattr(args, "lon", None) is not None and args.lat is None:
        # longitude alone would be silently unused (gravity and Earth rate need the latitude,
        # the WMM field both)
        parser.error("--lon needs --lat (the magnetic field model needs both; --lat alone is "
                     "fine)")
    if getattr(args, "auto", False) and not args.guide:
        parser.error("--auto needs --guide (it waits for each guided pose)")
    if getattr(args, "guide", None) and args.hold < args.min_still:
        parser.error(f"--hold {args.hold:g} is shorter than --min-still {args.min_still:g}: "
                     "the calibration would not find the poses as still periods")
    command = {"log": cmd_log, "live": cmd_live, "upload": cmd_upload,
               "restore": cmd_restore, "gap": cmd_gap, "tcal": cmd_tcal}[args.command]
    try:
        with warnings.catch_warnings():
            if not args.debug:
                # numpy/scipy/pandas RuntimeWarnings ("Mean of empty slice", ...) are not for
                # the user's terminal: what matters is reported in the calibration's warnings
                warnings.simplefilter("ignore")
            return command(args)
    except ApmcalError as err:
        if err.path is None:   # solvers know no file names: name the input the user gave
            err.path = getattr(args, "file", None) or getattr(args, "connection", None)
        print(f"apmcal: error: {err}", file=sys.stderr)
        return EXIT_USER_ERROR
    except Exception as exc:  # a bug of ours: still one line unless --debug
        if args.debug:
            raise
        print(f"apmcal: internal error: {type(exc).__name__}: {exc} (rerun with --debug for the "
              f"traceback and report it)", file=sys.stderr)
        return EXIT_INTERNAL_ERROR


def console_for(args):
    """A rich Console that prints text literally (no markup), quiet with ``--quiet``."""
    from rich.console import Console

    # markup and emoji codes off: file names, units "[m/s²]" and notes are printed literally;
    # report.py styles with Text objects
    # piped or redirected: no line breaks of rich's own (at 80 columns they fell inside numbers
    # and vectors); the reader's pager or terminal wraps
    return Console(stderr=False, quiet=getattr(args, "quiet", False), highlight=False,
                   markup=False, emoji=False, soft_wrap=not sys.stdout.isatty())


def check_writable(path, what: str) -> None:
    """Refuse, before any work, an output path that cannot be written (without creating it).

    Parameters
    ----------
    path : str, Path or None
        None: nothing to check.
    what : str
        What the file is, for the message.

    Raises
    ------
    ApmcalError
        When the path is a directory, its directory is missing or not writable.
    """
    if path is None:
        return
    p = Path(path)
    parent = p.parent
    if p.is_dir():
        why = "is a directory"
    elif not parent.exists():
        why = f"directory {parent} does not exist"
    elif not parent.is_dir():
        why = f"{parent} is not a directory"
    elif not os.access(p if p.exists() else parent, os.W_OK):
        why = "permission denied"
    else:
        return
    # refused before reading or recording anything: no other output (--json included) is
    # written either, so the user fixes the path and loses nothing
    raise ApmcalError(f"cannot write {what}: {why}; stopped before any work, nothing written",
                      str(path))


def write_json(path, obj) -> None:
    """``obj`` as indented JSON (numpy values made plain), or one line saying why not.

    Raises
    ------
    ApmcalError
        When the file cannot be written.
    """
    from apmcal.solvers.result import jsonable

    text = json.dumps(jsonable(obj), indent=2) + "\n"
    try:
        Path(path).write_text(text)
    except OSError as exc:
        raise ApmcalError(f"cannot write JSON file ({exc.strerror or exc})", str(path)) from None


def check_outputs(args) -> None:
    """Every output path of a calibration command checked before reading or recording."""
    if not getattr(args, "summary_only", False):
        check_writable(args.param_file, "parameter file")
    check_writable(args.json, "JSON file")


@single_threaded_blas      # small BLAS products on long arrays: threads only contend (see there)
def cmd_log(args) -> int:
    """``apmcal log``: read a file, summarise and calibrate it; exit status."""
    from apmcal.sources import read_log

    check_outputs(args)
    if args.layout == "auto":
        contents = read_log(args.file)
    else:
        from apmcal.sources.csv import read_csv

        contents = read_csv(args.file, layout=args.layout)
    status, _ = summarise_and_calibrate(contents, args)
    return status


def summarise_and_calibrate(contents, args):
    """Print the summary and (unless --summary-only) the calibration; write the outputs.

    Returns (exit status, parameter proposal or None). The status is 1 when the firmware would
    reject some proposed value. The JSON file is written last but also when the parameter file
    could not be (it then says why under "param_file_error"), before that error is raised.

    Parameters
    ----------
    contents : LogContents
    args : argparse.Namespace
        The log or live command's options.

    Returns
    -------
    int
        Exit status, 0 or 1.
    ParamProposal or None

    Raises
    ------
    ApmcalError
        When the units are implausible, nothing could be calibrated or an output cannot be
        written.
    """
    from apmcal.report import text as report
    from apmcal.sources.units import require_plausible_units

    console = console_for(args)
    require_plausible_units(contents)       # a sensor in impossible units is not data
    summary = report.summarize(contents)
    report.print_summary(summary, console)
    output = {"summary": summary}      # the JSON file's own fields besides the calibration's
    calibration = proposal = None
    param_error = None
    if not getattr(args, "summary_only", False):
        from apmcal.calibration.log import Options, calibrate_log

        calibration, proposal = calibrate_log(contents, Options(
            args.method, args.lat, args.lon, args.min_still, args.instance, args.firmware))
        report.print_calibration(calibration, proposal, console, args.verbose)
        output["verdict"] = report.verdict_dict(calibration, proposal)
        if proposal is not None:       # its values are the calibration's own "params"
            output["rejected_params"] = dict(proposal.rejected)
        if args.param_file:
            try:
                write_proposal(args.param_file, proposal, calibration, contents)
            except ApmcalError as err:
                param_error = err
                output["param_file_error"] = str(err)
            else:
                output["param_file"] = args.param_file
                console.print(f"wrote {args.param_file}")
    if args.json:
        if calibration is None:
            write_json(args.json, output)
        else:
            calibration.save(args.json, extra=output)      # schema, units, report + ours
        console.print(f"wrote {args.json}")
    if param_error is not None:
        raise param_error
    return (0 if proposal is None or not proposal.rejected else 1), proposal


def write_proposal(path, proposal, calibration, contents) -> None:
    """The proposed parameters as a .param file (ApmcalError when there are none or on OSError).

    Raises
    ------
    ApmcalError
        Without a proposal (no firmware generation) or when the file cannot be written.
    """
    if proposal is None:
        raise ApmcalError("not an ArduPilot log, so no firmware generation to write "
                          "parameters for: add --firmware 3.2 or --firmware 3.3+",
                          contents.path)
    from apmcal.ardupilot.paramfile import write_param_file

    try:
        write_param_file(path, proposal.values,
                         f"apmcal {calibration.method} calibration of {contents.path}")
    except OSError as exc:     # write_param_file wraps its own; this is belt and braces
        raise ApmcalError(f"cannot write parameter file ({exc.strerror or exc})", path) from None


def cmd_live(args) -> int:
    """``apmcal live``: record from a vehicle, calibrate, optionally upload; exit status."""
    from apmcal.sources import read_log
    from apmcal.sources.live import VehicleLink

    console = console_for(args)
    log_path = args.save_log or f"apmcal-live-{time.strftime('%Y%m%d-%H%M%S')}.tlog"
    # every output checked before connecting: no minute of recording lost to a typo
    check_writable(log_path, "recording")
    check_outputs(args)
    if args.upload:     # the default backup goes to the current directory: check that too
        check_writable(args.backup or default_backup_name(), "backup file")
    try:
        link = VehicleLink(args.connection, record_to=log_path, baud=args.baud)
    except OSError as exc:
        if exc.filename is None or Path(exc.filename) != Path(log_path):
            raise
        raise ApmcalError(f"cannot write recording ({exc.strerror or exc})", log_path) from None
    with link:
        params = link.fetch_params()
        link.request_imu_stream(args.rate)
        if args.guide:
            n = record_guided(link, args)
        else:
            console.print(f"recording {args.duration:g} s from {args.connection} to {log_path}")
            n = record_with_progress(link, args.duration, console)
        if n == 0:
            raise ApmcalError("no IMU messages received (stream request ignored? check "
                              "SRn_RAW_SENS)", args.connection)
        check_params_unchanged(params, link.fetch_params(), args.connection)
    contents = read_log(log_path)
    status, proposal = summarise_and_calibrate(contents, args)
    if args.upload:
        values = values_to_upload(proposal, args.connection, console)
        upload_values(args.connection, values, args.backup, params, console, args.baud)
    return status


def values_to_upload(proposal, connection: str, console) -> dict[str, float]:
    """The proposed values that passed the firmware's limits.

    A sensor out of limits is withheld whole (ParamProposal.rejected); the others are uploaded
    all the same, since a rejected compass (say) says nothing against the accelerometer and
    gyro values. Nothing to upload at all is an ApmcalError.

    Parameters
    ----------
    proposal : ParamProposal or None
    connection : str
        For the message.
    console : rich.console.Console

    Returns
    -------
    dict
        Parameter name → value.

    Raises
    ------
    ApmcalError
        When no value is within the firmware's limits.
    """
    if proposal is None or not proposal.values:
        why = ", ".join(proposal.rejected) if proposal and proposal.rejected else "none proposed"
        raise ApmcalError(f"not uploading: no parameter within the firmware's limits ({why})",
                          connection)
    if proposal.rejected:
        console.print("not uploading, out of the firmware's limits: "
                      + ", ".join(proposal.rejected) + "; uploading the other "
                      f"{len(proposal.values)} values")
    return dict(proposal.values)


def record_guided(link, args) -> int:
    """The six poses, prompted and checked (apmcal.calibration.guided); the IMU message count.

    Six accepted poses are what the six-face method needs: with ``--method auto`` it is used,
    and a face the calibration then cannot find is an error, never another method.
    """
    from apmcal.calibration.guided import GuideOptions, TerminalOperator, record_six_faces

    operator = args.guide_operator or TerminalOperator(sys.stdin, sys.stdout)
    result = record_six_faces(link, GuideOptions(args.hold, args.auto, args.face_timeout),
                              operator)
    if args.method == "auto":
        args.method = "ferraris"
    return result.n_imu


def record_with_progress(link, duration_s: float, console) -> int:
    """Receive for ``duration_s`` with a progress bar; returns the IMU message count.

    Parameters
    ----------
    link : VehicleLink
    duration_s : float
        Recording time [s].
    console : rich.console.Console

    Returns
    -------
    int
    """
    from rich.progress import Progress

    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("recording", total=duration_s)
        return link.collect(duration_s, progress=lambda s: bar.update(task, completed=s))


def check_params_unchanged(before: dict, after: dict, connection: str) -> None:
    """Refuse a recording during which the calibration parameters changed.

    RAW_IMU is corrected with the parameters in force (ardupilot-facts.md), so samples from
    before and after a change (a boot gyro calibration still running, another GCS writing)
    cannot be un-corrected with one set.

    Parameters
    ----------
    before, after : dict
        The vehicle's parameters (name → value) before and after the recording.
    connection : str
        For the message.

    Raises
    ------
    ApmcalError
        When a calibration parameter differs.
    """
    from apmcal.core.recording import is_calibration_param

    changed = [f"{k} {before.get(k)} -> {after.get(k)}" for k in sorted(set(before) | set(after))
               if is_calibration_param(k) and before.get(k) != after.get(k)]
    if changed:
        raise ApmcalError("calibration parameters changed while recording (" + ", ".join(changed)
                          + "); wait for the vehicle to finish booting and record again",
                          connection)


def default_backup_name() -> str:
    """``apmcal-backup-<local time>.param`` in the current directory."""
    return f"apmcal-backup-{time.strftime('%Y%m%d-%H%M%S')}.param"


def upload_values(connection, values, backup, vehicle_params, console, baud,
                  all_params=False):
    """Write ``values`` to the vehicle (backed up to ``backup``, verified) and say so.

    Parameters
    ----------
    connection : str
        pymavlink connection string.
    values : dict
        Parameter name → value.
    backup : str or None
        Backup file (None: :func:`default_backup_name`).
    vehicle_params : dict or None
        The vehicle's parameters when already fetched.
    console : rich.console.Console
    baud : int
        Serial baud rate.
    all_params : bool
        Allow parameters other than calibration ones.

    Raises
    ------
    ApmcalError
        When the backup cannot be written or the upload fails.
    """
    from apmcal.link.upload import upload_params
    from apmcal.sources.live import VehicleLink

    backup = backup or default_backup_name()
    check_writable(backup, "backup file")
    with VehicleLink(connection, baud=baud) as link:
        result = upload_params(link, values, backup, vehicle_params, all_params)
    console.print(f"wrote and verified {len(result.written)} parameters; backup in {backup} "
                  f"(undo: apmcal restore {connection} {backup})")
    print_skipped(result, console)


def print_skipped(result, console) -> None:
    """Names the vehicle does not have (UploadReport.skipped, when the report carries it)."""
    skipped = list(getattr(result, "skipped", None) or [])
    if skipped:
        console.print(f"skipped {len(skipped)} names the vehicle does not have: "
                      + ", ".join(skipped))


def cmd_upload(args) -> int:
    """``apmcal upload``: write a .param file to the vehicle; exit status."""
    from apmcal.ardupilot.paramfile import read_param_file
    from apmcal.ardupilot.scope import check_scope

    values = read_param_file(args.param_file)      # the file is checked before connecting
    check_scope(values, args.param_file, args.all_params)
    upload_values(args.connection, values, args.backup, None, console_for(args), args.baud,
                  args.all_params)
    return 0


def cmd_restore(args) -> int:
    """``apmcal restore``: write a backup back to the vehicle; exit status."""
    from apmcal.ardupilot.paramfile import read_param_file
    from apmcal.link.upload import restore_params
    from apmcal.sources.live import VehicleLink

    read_param_file(args.backup_file)       # a missing or bad file fails before connecting
    with VehicleLink(args.connection, baud=args.baud) as link:
        result = restore_params(link, args.backup_file, all_params=args.all_params)
    console = console_for(args)
    console.print(f"restored {len(result.written)} parameters from {args.backup_file}")
    print_skipped(result, console)
    print_left_out(getattr(result, "left_out", []), console, args.all_params)
    return 0


def print_left_out(names: list[str], console, all_params: bool) -> None:
    """The backup's values restore did not write although the vehicle holds others."""
    if names:
        why = ("counters the vehicle keeps itself" if all_params else
               "not calibration parameters; --all-params restores all but counters")
        shown = ", ".join(names[:12]) + (" ..." if len(names) > 12 else "")
        console.print(f"left {len(names)} differing parameters as they are ({why}): {shown}")


def cmd_gap(args) -> int:
    """``apmcal gap``: see :func:`apmcal.cli.gap.run_gap`; exit status."""
    from apmcal.cli.gap import run_gap

    return run_gap(args, console_for(args))


if __name__ == "__main__":
    entry()
