"""What every command shares: the one-line parser, number options, the console, output checks
before any work, and the upload step that log-free commands and ``live`` end with."""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

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
    p.add_argument("--param-file", default=None, metavar="FILE",
                   help="write the proposed parameters to FILE (Mission Planner/MAVProxy .param; "
                        "QGroundControl's .params with --param-format qgc)")
    p.add_argument("--param-format", choices=["param", "qgc"], default="param",
                   help="format of --param-file: param (default) or qgc (tab-separated .params)")
    add_accept_redo_option(p)
    p.add_argument("--json", default=None, metavar="FILE",
                   help="write summary and calibration as JSON (also when --param-file fails)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write an HTML report with figures to DIR/index.html")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.add_argument("--verbose", action="store_true",
                   help="also print the specialist's lines (fit internals, paper references, "
                        "the model's misfit); the --json output always has them")


def add_accept_redo_option(p: argparse.ArgumentParser) -> None:
    """--accept-redo: write (and upload) the values of a sensor graded REDO too."""
    p.add_argument("--accept-redo", action="store_true",
                   help="also write (and upload) the values of a sensor graded REDO, which are "
                        "otherwise left out (exit status 1); values out of the firmware's "
                        "limits are never written")


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
    """Refuse, before any work, an output path that cannot be written: tried by creating it
    (and removing it again when it did not exist), so that /proc, a read-only mount or a full
    disk is found now and not after the work.

    Parameters
    ----------
    path : str, Path or None
        None: nothing to check.
    what : str
        What the file is, for the message.

    Raises
    ------
    ApmcalError
        When the path is a directory, its directory is missing, or it cannot be created.
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
    else:
        why = _try_create(p)
        if why is None:
            return
    # refused before reading or recording anything: no other output (--json included) is
    # written either, so the user fixes the path and loses nothing
    raise ApmcalError(f"cannot write {what}: {why}; stopped before any work, nothing written",
                      str(path))


def _try_create(p: Path) -> str | None:
    """Open ``p`` for appending (created if missing, then removed); why not, or None."""
    existed = p.exists()
    try:
        with open(p, "a"):
            pass
    except OSError as err:
        return (err.strerror or str(err)).lower()
    if not existed:
        try:
            p.unlink()
        except OSError:
            pass
    return None


def check_writable_dir(path, what: str) -> None:
    """Refuse, before any work, an output directory that cannot be made or written into
    (made now when missing; a probe file created in it and removed).

    Raises
    ------
    ApmcalError
        When the path is a file, cannot be made, or a file cannot be created in it.
    """
    if path is None:
        return
    p = Path(path)
    if p.exists() and not p.is_dir():
        why = "not a directory"
    else:
        try:
            p.mkdir(parents=True, exist_ok=True)
            why = _try_create(p / ".apmcal-write-check")
        except OSError as err:
            why = (err.strerror or str(err)).lower()
        if why is None:
            return
    raise ApmcalError(f"cannot write {what}: {why}; stopped before any work, nothing written",
                      str(path))


def check_outputs(args) -> None:
    """Every output path of a calibration command checked before reading or recording."""
    if not getattr(args, "summary_only", False):
        check_writable(args.param_file, "parameter file")
    check_writable(args.json, "JSON file")
    check_writable_dir(getattr(args, "report", None), "the report")


#: where ``live`` and the uploads put the files the user named no place for (recordings, backups);
#: the project's .gitignore covers it
DEFAULT_FOLDER = "apmcal-files"


def default_path(name: str) -> str:
    """``apmcal-files/<name>``, the folder made when missing (a failure is left to the
    output check, which names it)."""
    try:
        Path(DEFAULT_FOLDER).mkdir(exist_ok=True)
    except OSError:
        pass
    return str(Path(DEFAULT_FOLDER) / name)


def default_backup_name() -> str:
    """``apmcal-files/apmcal-backup-<local time>.param``."""
    return default_path(f"apmcal-backup-{time.strftime('%Y%m%d-%H%M%S')}.param")


def upload_values(connection, values, backup, vehicle_params, console, baud,
                  all_params=False, generation: str | None = None,
                  any_generation: bool = False):
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
    generation : str, optional
        The firmware generation the values were made for ("3.2", "3.3+"; None: not known).
    any_generation : bool
        Upload to a vehicle of another generation all the same.

    Raises
    ------
    ApmcalError
        When the backup cannot be written, the vehicle's firmware generation is not the one
        the values were made for (unless ``any_generation``), or the upload fails.
    """
    from apmcal.link.upload import upload_params
    from apmcal.sources.live import VehicleLink

    backup = backup or default_backup_name()
    check_writable(backup, "backup file")
    with VehicleLink(connection, baud=baud, announce=console.print) as link:
        if generation is not None:
            vehicle_params = vehicle_params or link.fetch_params()
            check_generation(generation, vehicle_params, connection, any_generation, console)
        result = upload_params(link, values, backup, vehicle_params, all_params)
    console.print(f"wrote and verified {len(result.written)} parameters; backup in {backup} "
                  f"(undo: apmcal restore {connection} {backup})")
    print_skipped(result, console)


#: the flag that uploads values made for another firmware generation than the vehicle's
ANY_GENERATION_FLAG = "--any-generation"


def add_any_generation_option(p: argparse.ArgumentParser) -> None:
    """--any-generation: upload values made for another firmware generation all the same."""
    p.add_argument(ANY_GENERATION_FLAG, action="store_true",
                   help="upload although the values were made for another firmware generation "
                        "than the vehicle's (3.2 and 3.3+ apply them by other formulas)")


def check_generation(generation: str, vehicle_params: dict, connection: str,
                     any_generation: bool, console) -> None:
    """Refuse, before anything is written, values made for another firmware generation than
    the vehicle's (:func:`apmcal.ardupilot.firmware.firmware_generation` of its parameters);
    with ``any_generation`` say it and go on.

    Raises
    ------
    ApmcalError
        On a mismatch without ``any_generation``.
    """
    from apmcal.ardupilot.firmware import firmware_generation

    vehicle = firmware_generation(vehicle_params)
    if vehicle == generation:
        return
    said = (f"the values were made for firmware {generation}, the vehicle's parameters are "
            f"those of {vehicle}: the two apply them by different formulas")
    if not any_generation:
        raise ApmcalError(f"{said}; nothing was written (calibrate again with this vehicle's "
                          f"log, or {ANY_GENERATION_FLAG} to write them all the same)",
                          connection)
    console.print(f"warning: {said}; uploading all the same ({ANY_GENERATION_FLAG})")


def print_skipped(result, console) -> None:
    """Names the vehicle does not have (UploadReport.skipped, when the report carries it)."""
    skipped = list(getattr(result, "skipped", None) or [])
    if skipped:
        console.print(f"skipped {len(skipped)} names the vehicle does not have: "
                      + ", ".join(skipped))
