"""``apmcal upload CONNECTION FILE``: write a .param file to a vehicle, backed up, verified,
rolled back on failure."""
from __future__ import annotations

from apmcal.cli.common import (
    add_any_generation_option,
    add_baud_option,
    console_for,
    upload_values,
)

ALL_PARAMS_HELP = ("also write parameters that are not calibration (counters such as STAT_* "
                   "are never written)")


def add_parser(sub) -> None:
    """The ``upload`` sub-command and its options."""
    from apmcal.ardupilot.scope import CALIBRATION_IN_WORDS

    upload = sub.add_parser(
        "upload", help="write a .param file to a vehicle: backed up, verified, rolled back on "
                       "failure",
        description="Write the calibration parameters of a .param file (NAME VALUE lines) to a "
                    "vehicle. Every parameter of the vehicle is first saved to a backup file; "
                    "each write is verified by read-back; if one cannot be confirmed, or on "
                    "Ctrl-C, every change is put back. Only calibration parameters "
                    f"({CALIBRATION_IN_WORDS}) unless --all-params; the file is checked "
                    "before anything is written, and a file apmcal made is refused on a "
                    "vehicle of another firmware generation than the one it records.")
    upload.add_argument("connection", help="pymavlink connection string, e.g. "
                                           "udp:127.0.0.1:14550")
    upload.add_argument("param_file", help="the parameters to write (.param: NAME VALUE lines)")
    upload.add_argument("--backup", default=None,
                        help="backup file (default apmcal-files/apmcal-backup-<time>.param)")
    upload.add_argument("--all-params", action="store_true", help=ALL_PARAMS_HELP)
    add_any_generation_option(upload)
    add_baud_option(upload)



def run(args) -> int:
    """``apmcal upload``: write a .param file to the vehicle; exit status."""
    from apmcal.ardupilot.paramfile import read_param_file, read_param_generation
    from apmcal.ardupilot.scope import check_scope

    values = read_param_file(args.param_file)      # the file is checked before connecting
    check_scope(values, args.param_file, args.all_params)
    # a file apmcal made records the generation its values are for: checked against the
    # vehicle's before anything is written
    upload_values(args.connection, values, args.backup, None, console_for(args), args.baud,
                  args.all_params, read_param_generation(args.param_file),
                  args.any_generation)
    return 0
