"""A fleet recorded from ArduPilot's own firmware (SITL), for the fleet tests and benchmark
(not a test module).

Each vehicle is one parameter store (``eeprom.bin`` in its own folder, kept between flights as
on a real vehicle) and its own MAV_SYSID (``--sysid``); each flight is one boot of the firmware
dated by ``--start-time``: logging from boot (LOG_DISARMED 1: the pre-flight wait is a still
period on the ground), takeoff to 10 m, a square with the autopilot's own yaw, two slow full
turns, land, a few seconds on the ground. Events are parameters written on the ground
before the flight, followed by a reboot (as after a compass calibration), and kept in the store
for the flights after: SIM_* for what happens to the hardware, COMPASS_*/INS_* for the
calibration in force. The exact calibration of the simulated sensors
is the one of ``../shared/ardupilot-sitl/README.md`` (COMPASS_OFS = SIM_MAG1_OFS, ...).

The dataflash logs are copied into one flat folder under names that say nothing of the vehicle
(the fleet must tell the vehicles apart from the logs' contents), and each flight's .tlog
(RAW_IMU streamed at 10 Hz beside the driver's own messages) into another.

:data:`EVENT_FLEET` is the fleet of tests/test_fleet_firmware.py; to record it yourself:

    python tests/sitl_fleet.py DIR          # then: apmcal fleet DIR/bin --out REPORT
"""
from __future__ import annotations

import datetime
import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

FIRST_FLIGHT = datetime.datetime(2026, 3, 1, 9, 0, tzinfo=datetime.timezone.utc)
DAYS_BETWEEN_FLIGHTS = 3.0
# the same for every vehicle and flight: one compass (the analysis of each costs as much as a
# log's reading), pre-arm checks off (a compass calibration far off fails them)
BOOT_PARAMS = {"LOG_DISARMED": 1, "ARMING_CHECK": 0,
               **{f"SIM_MAG{n}_DEVID": 0 for n in range(2, 9)}}
RAW_IMU = 27                    # MAVLink message id, streamed into the .tlog
SQUARE_M = 20.0
LEG_S = 8.0
TURN_RATE_DEG_S = 30.0
TURNS_DEG = 720.0
GROUND_AFTER_S = 5.0


EXACT_OFS = (5.0, 13.0, -18.0)      # SIM_MAG1_OFS and COMPASS_OFS of copter.parm: exact
HARD_IRON_SHIFT = (90.0, -60.0, 40.0)     # mGauss
ACC_BIAS = 0.35                           # m/s², on the sensor's z axis
WRONG_OFS = (70.0, -50.0, 30.0)           # mGauss
# a compass replaced by another (SIM_MAG1_DEVID: SIM_MAG4_DEVID's default, off in BOOT_PARAMS)
# and made the first by priority, as a ground station does after the swap (without it arming is
# refused, "Compass not healthy"); not recalibrated. The firmware files the new compass in slot 2
# (COMPASS_DEV_ID 97539 → 0, COMPASS_DEV_ID2 0 → 97283) and moves the external flag with it
# (COMPASS_EXTERNAL 1 → 0, COMPASS_EXTERN2 0 → 1); from the boot after, in slot 1
COMPASS_DEVID, NEW_COMPASS_DEVID = 97539, 97283
COMPASS_SWAP = {"SIM_MAG1_DEVID": NEW_COMPASS_DEVID, "COMPASS_PRIO1_ID": NEW_COMPASS_DEVID}


def _ofs(prefix: str, v) -> dict:
    return {f"{prefix}_{a}": float(x) for a, x in zip("XYZ", v)}


def _plus(a, b) -> tuple:
    return tuple(x + y for x, y in zip(a, b))


@dataclass
class VehiclePlan:
    """One vehicle: its MAV_SYSID, its number of flights and the parameters written before
    given flights (flight index from 0 → {name: value}); ``event`` says what they mean."""

    sysid: int
    flights: int
    writes: dict[int, dict[str, float]] = field(default_factory=dict)
    event: str = "none"


# four vehicles, three flights each: one untouched, one whose compass's hard iron moves before
# flight 2 and is never recalibrated, one whose accelerometer gets a z bias from flight 2 and
# whose compass is replaced before flight 3, one flown with a wrong COMPASS_OFS on flight 1 and
# recalibrated before flight 2
EVENT_FLEET = [
    VehiclePlan(11, 3),
    VehiclePlan(12, 3, {1: _ofs("SIM_MAG1_OFS", _plus(EXACT_OFS, HARD_IRON_SHIFT))},
                "hard iron shifted, never recalibrated"),
    VehiclePlan(13, 3, {1: {"SIM_ACC1_BIAS_Z": ACC_BIAS}, 2: COMPASS_SWAP},
                "accelerometer bias; compass replaced"),
    VehiclePlan(14, 3, {0: _ofs("COMPASS_OFS", _plus(EXACT_OFS, WRONG_OFS)),
                        1: _ofs("COMPASS_OFS", EXACT_OFS)},
                "wrong compass calibration, recalibrated")]


def fly_one(sitl) -> None:
    """Takeoff, a square with the autopilot's yaw, two slow full turns, land, ground (``sitl``
    an :class:`ardupilot_sitl.ArduPilotSitl` of a copter)."""
    sitl.request_message(RAW_IMU, 10.0)
    sitl.takeoff(10.0)
    for north, east in ((SQUARE_M, 0), (SQUARE_M, SQUARE_M), (0, SQUARE_M), (0, 0)):
        sitl.fly_to(north, east, 10.0, LEG_S)
    sitl.fly_to(0, 0, 10.0, TURNS_DEG / TURN_RATE_DEG_S, yaw_rate_deg_s=TURN_RATE_DEG_S)
    sitl.land()
    sitl.run_for(GROUND_AFTER_S)


def _fly_vehicle(folder: Path, plan: VehiclePlan, position: int, n_plans: int,
                 speedup: float, fly) -> dict:
    """Every flight of one vehicle, in order; its truth entry."""
    from ardupilot_sitl import ArduPilotSitl

    flights = []
    for k in range(plan.flights):
        when = FIRST_FLIGHT + datetime.timedelta(days=k * DAYS_BETWEEN_FLIGHTS,
                                                 hours=plan.sysid % 24)
        work = folder / "work" / f"sysid{plan.sysid}"
        writes = plan.writes.get(k, {})
        boot = {"model": "quad", "speedup": speedup, "sysid": plan.sysid,
                "start_time": when.timestamp(), "boot_params": BOOT_PARAMS}
        read_back = {}
        if writes:      # on the ground, then a reboot (as after a compass calibration)
            with ArduPilotSitl(work, keep_eeprom=k > 0, **boot) as sitl:
                sitl.set_params(writes)
                read_back = {name: sitl.get_param(name) for name in writes}
        with ArduPilotSitl(work, keep_eeprom=k > 0 or bool(writes), **boot) as sitl:
            fly(sitl)
        name = f"log_{k * n_plans + position + 1:03d}"       # vehicles interleaved
        shutil.copy(sitl.dataflash_logs()[-1], folder / "bin" / f"{name}.bin")   # this boot's
        shutil.copy(sitl.tlog, folder / "tlog" / f"{name}.tlog")
        flights.append({"index": k, "file": f"{name}.bin", "tlog": f"{name}.tlog",
                        "unix_s": when.timestamp(), "writes": writes, "read_back": read_back})
    return {"sysid": plan.sysid, "event": plan.event, "flights": flights}


def record_fleet(folder, plans: list[VehiclePlan], speedup: float = 200.0,
                 parallel: int = 2, fly=fly_one) -> dict:
    """Fly every plan into ``folder``: ``bin/`` (the dataflash logs, flat, named log_NNN.bin,
    the vehicles' flights interleaved in date order), ``tlog/`` and ``truth.json``; up to
    ``parallel`` vehicles at once (each a firmware process of its own); ``fly(sitl)`` flies
    each flight (default :func:`fly_one`).

    Returns the truth: per vehicle its sysid, event, and per flight the log's name, date, the
    parameters written and the values read back from the firmware after them.
    """
    from concurrent.futures import ThreadPoolExecutor

    folder = Path(folder)
    (folder / "bin").mkdir(parents=True, exist_ok=True)
    (folder / "tlog").mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor(max(1, parallel)) as pool:
        done = [pool.submit(_fly_vehicle, folder, plan, i, len(plans), speedup, fly)
                for i, plan in enumerate(plans)]
        truth = {"vehicles": {str(p.sysid): f.result() for p, f in zip(plans, done)}}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth


if __name__ == "__main__":
    import sys
    import time

    if len(sys.argv) != 2:
        sys.exit("usage: python tests/sitl_fleet.py DIR   (records EVENT_FLEET into DIR)")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "sitl"))
    t0 = time.perf_counter()
    record_fleet(sys.argv[1], EVENT_FLEET)
    print(f"recorded into {sys.argv[1]} in {time.perf_counter() - t0:.0f} s: bin/, tlog/, "
          "truth.json")
