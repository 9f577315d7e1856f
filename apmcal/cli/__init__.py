"""The ``apmcal`` command line: one module per command over the library.

    apmcal log FILE [--method M] [--lat DEG --lon DEG] [--param-file OUT] [--json OUT]
    apmcal live CONNECTION [--duration S] [--rate HZ] [--method M] [--upload] ...
    apmcal upload CONNECTION FILE.param [--backup FILE] [--all-params]
    apmcal restore CONNECTION BACKUP.param [--all-params]
    apmcal tcal LOG [--param-file OUT] [--upload CONNECTION]
    apmcal gap FILE [--report DIR] [--json OUT] [--write-twin TWIN.json]
    apmcal fleet PATH... --out DIR [--workers N | --scheduler tcp://HOST:PORT]
    apmcal ui [--port N] [--no-browser]

Every failure the user can cause ends in one line on stderr and a non-zero exit status; Ctrl-C
ends with one line and status 130 (128 + SIGINT, the shell's convention).

Modules: :mod:`~apmcal.cli.common` (the one-line parser, number options, console, output checks,
the upload step), then one per command, each with ``add_parser(subparsers)`` and ``run(args)``:
:mod:`~apmcal.cli.log`, :mod:`~apmcal.cli.live`, :mod:`~apmcal.cli.upload`,
:mod:`~apmcal.cli.restore`, :mod:`~apmcal.cli.gap`, :mod:`~apmcal.cli.tcal`,
:mod:`~apmcal.cli.fleet`, :mod:`~apmcal.cli.ui`. A command module
imports only argparse and :mod:`~apmcal.cli.common` when loaded, so that ``apmcal --help`` stays
light; the library is imported when the command runs.
"""
from __future__ import annotations

import logging
import os
import sys
import warnings

from apmcal.cli import fleet, gap, live, log, restore, tcal, ui, upload
from apmcal.cli.common import (
    EXIT_INTERNAL_ERROR,
    EXIT_INTERRUPTED,
    EXIT_USER_ERROR,
    OneLineParser,
    VersionAction,
)
from apmcal.core.blas_threads import one_blas_thread_from_start
from apmcal.core.errors import ApmcalError

#: sub-command → its module, in the order ``apmcal --help`` lists them
COMMANDS = {"log": log, "live": live, "upload": upload, "restore": restore, "gap": gap,
            "tcal": tcal, "fleet": fleet, "ui": ui}


def build_parser():
    """The ``apmcal`` parser with one sub-command per module of :data:`COMMANDS`."""
    parser = OneLineParser(prog="apmcal", description="IMU calibration for ArduPilot flight "
                                                      "controllers, from logs or a live vehicle")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS.values():
        module.add_parser(sub)
    parser.subcommands = sub.choices        # an unknown option is the sub-command's error
    return parser


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
    (the operating system takes the memory back at once); so does ``apmcal ui``, which may have
    run diagnoses, once it has closed the vehicle's link and its files. The other commands
    (vehicle links, parameter files) exit the ordinary way."""
    code = main()
    command = next((a for a in sys.argv[1:] if not a.startswith("-")), None)
    if command in ("gap", "ui"):
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
    args, extra = parser.parse_known_args(argv)
    if extra:           # said by the sub-command's parser: "see apmcal gap --help"
        parser.subcommands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
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
    command = COMMANDS[args.command].run
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
