"""``python -m apmcal_sim [CONNECTION]`` — run the simulated vehicle on a MAVLink connection."""
from __future__ import annotations

import argparse
import sys

from apmcal.core.errors import ApmcalError
from apmcal_sim import motion
from apmcal_sim.cli_common import add_firmware_args, add_truth_args, apply_firmware_args, make_truth


def parse_args(argv=None):
    """The command line of ``python -m apmcal_sim`` (``argv``: sys.argv[1:] when None)."""
    ap = argparse.ArgumentParser(prog="python -m apmcal_sim",
                                 description="Simulated APM 2.8 (ArduCopter 3.2/3.3) on MAVLink.")
    ap.add_argument("connection", nargs="?", default="udpout:127.0.0.1:14550",
                    help="pymavlink connection string (default udpout:127.0.0.1:14550), or "
                         "'pty': a simulated serial port, its device (/dev/pts/N) printed first")
    ap.add_argument("--write-truth", metavar="FILE.json", help="write the injected errors used")
    ap.add_argument("--speedup", type=float, default=1.0, help="simulated s per wall-clock s")
    ap.add_argument("--script", default="onepos", choices=motion.SCRIPTS,
                    help="the vehicle's motion (default onepos: still and level). ardupilot6: "
                         "a simulated person turns it through ArduPilot's six accel-cal poses, "
                         "each held --pose-hold s, from when a ground station starts recording "
                         "(for apmcal live --guide ardupilot6 --auto); operator: you turn it by "
                         "typing poses")
    ap.add_argument("--pose-hold", type=float, default=15.0, metavar="S",
                    help="with --script ardupilot6: simulated seconds each pose is held (default "
                         "15, enough for the guide's --hold 10)")
    ap.add_argument("--firmware", default="3.2", choices=("3.2", "3.3"))
    ap.add_argument("--duration", type=float, help="stop after this many simulated seconds")
    ap.add_argument("--param-file", default="sitl-params.json",
                    help="parameter persistence file (JSON), kept across restarts (default "
                         "sitl-params.json here; .gitignore covers it)")
    ap.add_argument("--tlog", help="also record the session to this .tlog")
    ap.add_argument("--full-params", action="store_true",
                    help="a real vehicle's full-size parameter table (about 1,350 names), as a "
                         "ground station downloads it over a slow or lossy link")
    add_truth_args(ap)
    add_firmware_args(ap)
    return ap.parse_args(argv)


def main(argv=None) -> int:
    """Run the simulated vehicle; the exit status (0, or 2 after a one-line error)."""
    args = parse_args(argv)
    try:
        from apmcal_sim.mavlink_vehicle import MavlinkVehicle
        from apmcal_sim.vehicle import SimVehicle, SixPosePerson
        truth = make_truth(args)
        if args.write_truth:
            truth.save(args.write_truth)
        person = args.script == "ardupilot6"      # the poses follow the ground station
        vehicle = SimVehicle(truth, "operator" if person else args.script, args.firmware,
                             args.param_file, seed=args.seed,
                             duration=args.duration if args.script != "operator" else None,
                             full_params=args.full_params)
        apply_firmware_args(vehicle, args)
        if person:
            # on the bench, switched on a moment ago: booted, its gyro calibrated, before a
            # ground station can ask for anything (apmcal refuses a recording across the boot
            # calibration, however soon after this command it starts)
            vehicle.run_for(vehicle.gyro_boot_s + 0.1)
            vehicle.pop_messages()
        endpoint = MavlinkVehicle(vehicle, args.connection, args.speedup, args.tlog)
        if person:
            endpoint.on_poll.append(SixPosePerson(args.pose_hold).step)
            print(f"sitl: once a ground station starts recording, the vehicle is turned through "
                  f"ArduPilot's six poses, {args.pose_hold:g} s each", file=sys.stderr,
                  flush=True)
        if hasattr(endpoint.conn, "device"):        # a pty: say where the serial port is
            print(f"serial port: {endpoint.conn.device}", flush=True)
        if args.script == "operator":
            start_operator_console(endpoint)
        try:
            endpoint.serve(args.duration)
        except KeyboardInterrupt:
            pass
        finally:
            endpoint.close()
    except ApmcalError as err:
        print(f"sitl: {err}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as err:
        print(f"sitl: {args.connection}: {err}", file=sys.stderr)
        return 2
    return 0


def start_operator_console(endpoint, keys=None, out=None) -> None:
    """Operator mode: you are the person at the vehicle. A pose typed here (level, left,
    right, nose down, nose up, back) and Enter turns the simulated vehicle to it (3 s);
    "tumble" turns it slowly through every direction (40 s), as a compass calibration asks."""
    import threading

    from apmcal_sim.vehicle import parse_pose_text

    keys, out = keys or sys.stdin, out or sys.stderr
    print("sitl operator: type a pose (level, left, right, nose down, nose up, back) and Enter "
          "to turn the vehicle, or tumble to turn it through every direction", file=out,
          flush=True)

    def read() -> None:
        for line in keys:
            if line.strip().lower() == "tumble":
                endpoint.call_soon(lambda v: v.tumble())
                print("sitl operator: tumbling through every direction (40 s)", file=out,
                      flush=True)
                continue
            pose = parse_pose_text(line)
            if pose is None:
                print(f"sitl operator: no pose in {line.strip()!r}", file=out, flush=True)
                continue
            endpoint.call_soon(lambda v, p=pose: v.goto_pose(p))
            print(f"sitl operator: turning to {pose}", file=out, flush=True)

    threading.Thread(target=read, daemon=True).start()


if __name__ == "__main__":
    sys.exit(main())
