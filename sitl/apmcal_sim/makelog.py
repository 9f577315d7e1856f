"""Generate a sample log from the simulated vehicle without real time.

    python -m apmcal_sim.makelog --script ferraris --out logs/ferraris.tlog --seed 1 \
        [--truth-out logs/ferraris.truth.json] [--rate 50] [--firmware 3.2] [--set NAME=VALUE ...]

.tlog: PARAM_VALUE of every parameter at the start, STATUSTEXT firmware string, HEARTBEAT 1 Hz,
SYS_STATUS, RAW_IMU (and with --highres HIGHRES_IMU) at --rate, SCALED_PRESSURE at 2 Hz.
.bin : FMT, PARM (all), MSG (firmware string), IMU and MAG (MOX..Z = COMPASS_MOT·throttle or
       current) at --rate, GPS (3D fix at the site, GWk/GMS of the start time + t) at 1 Hz,
       BAT (Volt 12.6 V, Curr = the simulated current, 20 A × throttle) at 10 Hz.
Parameters are NEUTRAL (offsets 0, scales 1, INS_GYR_CAL=0 so no boot gyro offsets) unless --set.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal_sim.cli_common import add_firmware_args, add_truth_args, apply_firmware_args, make_truth
from apmcal_sim.errors import SitlError
from apmcal_sim.logwriter import DataflashWriter, TlogWriter
from apmcal_sim.vehicle import VERSION_TEXT, SimVehicle

START_UNIX = 1_780_000_000.0     # fixed start time (2026-05-28) so logs are byte-reproducible
BAT_RATE_HZ = 10.0               # BAT records per second (.bin)
BAT_VOLT = 12.6                  # constant battery voltage [V] (a full 3S pack)


def make_vehicle(args) -> SimVehicle:
    """The simulated vehicle for ``python -m apmcal_sim.makelog``: neutral parameters (``--set`` ones
    applied), no boot-time gyro offsets, a fixed start time."""
    truth = make_truth(args)
    v = SimVehicle(truth, args.script, args.firmware, None, fs=args.fs, seed=args.seed,
                   duration=args.duration, gyro_boot_s=1.0, start_unix=START_UNIX)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None                 # neutral: no boot-time gyro offsets
    for item in args.set or []:
        name, _, value = item.partition("=")
        if v.params.set(name.strip(), value, save=False) is None:
            raise SitlError(f"unknown parameter or bad value {item!r}", where="--set")
    v.reset_zero_compass_diagonals()    # the firmware does it at its first compass sample
    apply_firmware_args(v, args)
    return v


def write_tlog(v: SimVehicle, out: Path, rate: float, seconds: float,
               highres: bool = False) -> None:
    """Write ``seconds`` of the vehicle's telemetry to the .tlog ``out``: the parameters, then
    RAW_IMU (and HIGHRES_IMU with ``highres``) at ``rate`` [Hz] with the other streams."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    v.set_interval("RAW_IMU", rate)
    if highres:
        v.set_interval("HIGHRES_IMU", rate)
    v.set_interval("SCALED_PRESSURE", 2.0)
    with TlogWriter(out) as w:
        for name in v.params.names:     # parameters in force at the start
            msg = mavlink.MAVLink_param_value_message(name.encode(), v.params[name],
                                                      mavlink.MAV_PARAM_TYPE_REAL32,
                                                      len(v.params), v.params.index(name))
            w.write(START_UNIX, v.encode(msg))
        _drain(v, seconds, lambda t, m: w.write(START_UNIX + t, v.encode(m)))


def write_bin(v: SimVehicle, out: Path, rate: float, seconds: float,
              imu_instance: bool = False, messages: tuple = ()) -> None:
    """Write ``seconds`` of the vehicle to the dataflash .bin ``out``: PARM, MSG (the firmware
    string, then ``messages``, e.g. a board's UID line), then IMU and MAG at ``rate`` [Hz], GPS
    at 1 Hz and BAT at 10 Hz."""
    v.set_interval("HIGHRES_IMU", rate)
    with DataflashWriter(out, imu_instance=imu_instance) as w:
        for name in v.params.names:
            w.parm(0, name, v.params[name])
        w.msg(0, VERSION_TEXT[v.generation])
        for text in messages:
            w.msg(0, text)
        ofs = [v.params[f"COMPASS_OFS_{a}"] for a in "XYZ"]
        site = v.truth.site
        bat_due = [0]                       # index k of the next BAT record, due at k / 10 Hz

        def emit_chunk(messages):
            # motor offsets and currents of a whole step at once: numpy per message would
            # cost more than the simulation itself
            imu_t = np.array([t for t, m in messages if m.get_type() == "HIGHRES_IMU"])
            motor, current = v.motor_offset(imu_t), v.current_at(imu_t)
            k = 0
            for t, m in messages:
                if m.get_type() == "HEARTBEAT":     # 1 Hz: a GPS fix dates the log (no RTC)
                    w.gps(int(round(t * 1e6)), v.start_unix + t, site["lat"], site["lon"],
                          site["alt"])
                if m.get_type() != "HIGHRES_IMU":
                    continue
                us = int(round(t * 1e6))
                w.imu(us, (m.xgyro, m.ygyro, m.zgyro), (m.xacc, m.yacc, m.zacc), m.temperature)
                per_mgauss = v.highres_mag_per_mgauss    # dataflash MAG: mGauss, bug or not
                w.mag(us, (m.xmag / per_mgauss, m.ymag / per_mgauss, m.zmag / per_mgauss), ofs,
                      motor[k])
                if t >= bat_due[0] / BAT_RATE_HZ - 1e-9:   # with the first IMU sample due
                    w.bat(us, BAT_VOLT, float(current[k]))
                    bat_due[0] = int(t * BAT_RATE_HZ + 1e-9) + 1
                k += 1
        _drain_chunks(v, seconds, emit_chunk)


def _drain(v: SimVehicle, seconds: float, emit) -> None:
    _drain_chunks(v, seconds, lambda messages: [emit(t, m) for t, m in messages])


def _drain_chunks(v: SimVehicle, seconds: float, emit_chunk) -> None:
    end = v.tick + int(round(seconds * v.fs))
    while v.tick < end:
        v.step(min(1.0, (end - v.tick) / v.fs))
        emit_chunk(v.pop_messages())


def main(argv=None) -> int:
    """Write one simulated log (``python -m apmcal_sim.makelog``); the exit status."""
    ap = argparse.ArgumentParser(prog="python -m apmcal_sim.makelog", description=__doc__.split("\n")[0])
    ap.add_argument("--script", default="ferraris")
    ap.add_argument("--out", required=True, help="output .tlog or .bin")
    ap.add_argument("--truth-out", help="write the injected truth JSON here")
    ap.add_argument("--rate", type=float, default=50.0, help="IMU message rate [Hz]")
    ap.add_argument("--fs", type=float, default=1000.0,
                    help="sensor sample rate [Hz] (default 1000; equal to --rate, every logged "
                         "sample is one sensor sample, as on a board read at its loop rate)")
    ap.add_argument("--firmware", choices=("3.2", "3.3"), default="3.2")
    ap.add_argument("--duration", type=float,
                    help="script length [s] (onepos/warmup/tumble/motors)")
    ap.add_argument("--set", action="append", metavar="NAME=VALUE",
                    help="parameter in force (default: all neutral)")
    ap.add_argument("--highres", action="store_true",
                    help=".tlog: also HIGHRES_IMU at --rate (SI floats; see --highres-mag-bug)")
    ap.add_argument("--imu-instance", action="store_true",
                    help=".bin: IMU records with the 4.x instance column I")
    add_truth_args(ap)
    add_firmware_args(ap)
    args = ap.parse_args(argv)
    try:
        v = make_vehicle(args)
        seconds = v.motion.duration + 1.0
        out = Path(args.out)
        if out.suffix.lower() == ".bin":
            write_bin(v, out, args.rate, seconds, args.imu_instance)
        elif out.suffix.lower() == ".tlog":
            write_tlog(v, out, args.rate, seconds, args.highres)
        else:
            raise SitlError("output must end in .tlog or .bin", out)
        if args.truth_out:
            v.truth.save(args.truth_out, extra=session_info(v, args, seconds))
    except ApmcalError as err:
        print(f"makelog: {err}", file=sys.stderr)
        return 2
    return 0


def session_info(v: SimVehicle, args, seconds: float) -> dict:
    """What a test needs besides the errors: script sections, params, time base."""
    return {"script": v.script, "seed": args.seed, "firmware": v.generation,
            "start_unix": START_UNIX, "duration_s": seconds,
            "time_base": "t (sections, gyr t_ref/drift, temperature) = seconds since boot = "
                         "tlog timestamp - start_unix = RAW_IMU time_usec/1e6 = dataflash TimeUS/1e6",
            "sections": [list(s) for s in v.motion.sections()], "params": v.params.as_dict(),
            "earth_field_ned_mgauss": v.field_ned.tolist(), "wmm_year": v.wmm_year}


if __name__ == "__main__":
    sys.exit(main())
