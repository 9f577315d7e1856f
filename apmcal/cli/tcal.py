"""``apmcal tcal LOG``: fit ArduPilot's IMU temperature calibration (INS_TCALn_*) from a still
warm-up log, print it, write or upload it."""
from __future__ import annotations

from apmcal.cli.common import (
    POSITIVE_SECONDS,
    add_baud_option,
    check_writable,
    check_writable_dir,
    console_for,
    default_backup_name,
    upload_values,
)


def add_parser(sub) -> None:
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
                                                     "(default apmcal-files/apmcal-backup-<time>.param)")
    add_baud_option(tcal)
    tcal.add_argument("--json", default=None, metavar="FILE", help="write the fit as JSON")
    tcal.add_argument("--report", default=None, metavar="DIR",
                      help="write an HTML report with the drift figures to DIR/index.html")
    tcal.add_argument("--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    """``apmcal tcal``: fit, print and write or upload the temperature calibration; exit status."""
    from apmcal.calibration.tcal import TemperatureCalibration, calibrate_temperature
    from apmcal.report.tcal import print_tcal
    from apmcal.sources import read_log
    from apmcal.sources.units import require_plausible_units

    check_writable(args.param_file, "parameter file")
    check_writable(args.json, "JSON file")
    check_writable_dir(args.report, "the report")
    if args.upload:
        check_writable(args.backup or default_backup_name(), "backup file")

    console = console_for(args)
    contents = read_log(args.file)
    require_plausible_units(contents)       # a sensor in impossible units is not data
    tcal = TemperatureCalibration(calibrate_temperature(contents, args.records, args.instance,
                                                        args.min_still))
    print_tcal(tcal.results, console)
    values = tcal.params()
    if args.json:
        tcal.save(args.json)
    if getattr(args, "report", None):
        from apmcal.report.html import write_tcal_html

        console.print(f"wrote {write_tcal_html(tcal, args.file, args.report)}")
    withheld = [r.withheld for r in tcal.results if r.withheld]
    if args.param_file:
        from apmcal.ardupilot.paramfile import write_param_file

        # a file whose every instance is withheld holds only the reason: loading it changes
        # nothing on the vehicle
        write_param_file(args.param_file, values, "\n".join([f"apmcal tcal of {args.file}",
                                                              *withheld]))
        console.print(f"wrote {args.param_file}" + ("" if values else
                                                    " (no parameter: nothing to enable)"))
    if args.upload and not values:
        console.print("nothing uploaded: no temperature calibration is significant")
    elif args.upload:
        upload_values(args.upload, values, args.backup, None, console, args.baud)
        # AP_InertialSensor_tempcal.cpp: INS_TCALn_ENABLE is @RebootRequired
        console.print("INS_TCALn_ENABLE takes effect at the vehicle's next reboot")
    return 0
