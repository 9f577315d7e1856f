"""``apmcal restore CONNECTION BACKUP``: put back the calibration parameters of a backup file."""
from __future__ import annotations

from apmcal.cli.common import add_baud_option, console_for, print_skipped
from apmcal.cli.upload import ALL_PARAMS_HELP


def add_parser(sub) -> None:
    """The ``restore`` sub-command and its options."""
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



def run(args) -> int:
    """``apmcal restore``: write a backup back to the vehicle; exit status."""
    from apmcal.ardupilot.paramfile import read_param_file
    from apmcal.link.upload import restore_params
    from apmcal.sources.live import VehicleLink

    read_param_file(args.backup_file)       # a missing or bad file fails before connecting
    console = console_for(args)
    with VehicleLink(args.connection, baud=args.baud, announce=console.print) as link:
        result = restore_params(link, args.backup_file, all_params=args.all_params)
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
