"""``apmcal live CONNECTION``: record from a vehicle over MAVLink, calibrate, optionally upload."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from apmcal.cli.common import (
    POSITIVE_SECONDS,
    add_any_generation_option,
    add_baud_option,
    add_calibration_options,
    check_outputs,
    check_writable,
    console_for,
    default_backup_name,
    default_path,
    number_type,
    upload_values,
)
from apmcal.cli.log import summarise_and_calibrate
from apmcal.core.errors import ApmcalError


def add_parser(sub) -> None:
    """The ``live`` sub-command and its options."""
    live = sub.add_parser("live", help="record from a vehicle over MAVLink and calibrate")
    live.add_argument("connection", help="pymavlink connection string, e.g. udp:127.0.0.1:14550")
    add_baud_option(live)
    live.add_argument("--duration", type=POSITIVE_SECONDS, default=60.0,
                      help="seconds to record (default 60)")
    live.add_argument("--rate", type=number_type(int, 1, 1000, what="an integer rate [Hz]"),
                      default=50, help="IMU stream rate [Hz], 1 to 1000 (default 50)")
    live.add_argument("--save-log", default=None, help="keep the recording as this .tlog "
                           "(default apmcal-files/apmcal-live-<time>.tlog)")
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
    live.add_argument("--backup", default=None,
                      help="backup file (default apmcal-files/apmcal-backup-<time>.param)")
    add_any_generation_option(live)
    add_calibration_options(live)


def run(args) -> int:
    """``apmcal live``: record from a vehicle, calibrate, optionally upload; exit status."""
    from apmcal.sources import read_log
    from apmcal.sources.live import VehicleLink

    console = console_for(args)
    log_path = args.save_log or default_path(f"apmcal-live-{time.strftime('%Y%m%d-%H%M%S')}.tlog")
    # every output checked before connecting: no minute of recording lost to a typo
    check_writable(log_path, "recording")
    check_outputs(args)
    if args.upload:     # the default backup goes to the current directory: check that too
        check_writable(args.backup or default_backup_name(), "backup file")
    try:
        link = VehicleLink(args.connection, record_to=log_path, baud=args.baud,
                           announce=console.print)
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
    report = summarise_and_calibrate(contents, args)
    if args.upload:
        values = values_to_upload(report, args.connection, console)
        if values:
            upload_values(args.connection, values, args.backup, params, console, args.baud,
                          generation=report.proposal.generation,
                          any_generation=args.any_generation)
    return report.status


def values_to_upload(report, connection: str, console) -> dict[str, float]:
    """The proposed values that may be written (:attr:`SessionReport.writable
    <apmcal.report.session.SessionReport.writable>`: none graded REDO unless --accept-redo,
    none out of the firmware's limits), saying which were withheld; {} when none may be
    (said: the exit status is then 1).

    Raises
    ------
    ApmcalError
        When nothing was proposed.
    """
    if report.proposal is None or not report.proposal.values and not report.proposal.rejected:
        raise ApmcalError("not uploading: no parameter proposed", connection)
    writable = report.writable
    for line in writable.lines("the vehicle"):
        console.print(line)
    if not writable.values:
        console.print("nothing uploaded: every value proposed is withheld; exit status 1")
    elif writable.withheld:
        console.print(f"uploading the other {len(writable.values)} values")
    return dict(writable.values)


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
    """Refuse a recording during which the correction parameters changed
    (:func:`apmcal.ardupilot.names.changed_correction_params`).

    Raises
    ------
    ApmcalError
        When a correction parameter differs.
    """
    from apmcal.ardupilot.names import changed_correction_params

    changed = changed_correction_params(before, after)
    if changed:
        raise ApmcalError("calibration parameters changed while recording (" + ", ".join(changed)
                          + "); wait for the vehicle to finish booting and record again",
                          connection)
