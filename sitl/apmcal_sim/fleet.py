"""A simulated fleet: dataflash logs of several vehicles over weeks, with injected events.

    python -m apmcal_sim.fleet --vehicles 5 --flights 6 --out DIR [--seed 0] [--rate 25] [--hold 8]

Writes DIR/<vehicle>/flight_<k>.bin (one short session per flight: a still pre-flight hold, a
turn about each body axis, a still hold after) and DIR/truth.json, the events injected. Vehicle
i gets the scenario ``SCENARIOS[i % 5]``:

- ``healthy``: calibration in force matches the sensors throughout (COMPASS_OFS within a few
  mGauss, :data:`CALIBRATION_SLACK_MGAUSS`, as after a good calibration);
- ``compass_drift``: the compass's hard-iron offset [mGauss] grows from the second flight on
  while COMPASS_OFS stays, so the heading error rises (event ``compass_drift``);
- ``compass_swap``: at the middle flight the compass is replaced: a new COMPASS_DEV_ID, a new
  hard-iron offset, and COMPASS_OFS recalibrated for it (events ``hardware_changed`` and
  ``recalibration``);
- ``recalibration``: at the middle flight a new payload moves the hard-iron offset and the
  compass is recalibrated for it (event ``recalibration``);
- ``gyro_temperature``: a gyro whose bias moves strongly with temperature (no temperature
  calibration), every flight warming the board (event ``gyro_temperature``).

Each vehicle has its own SYSID_THISMAV and a board UID line ("fmuv3 <24 hex digits>"); flights
are three days apart from 2026-03-01 at ambient temperatures that vary with the season. The
logged sensors are those of :class:`apmcal_sim.vehicle.SimVehicle` with most error effects off
(see :func:`vehicle_truth`), so the events are the only departures from a good calibration.
"""
from __future__ import annotations

import argparse
import datetime
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.sensor_model.truth import Truth
from apmcal_sim import motion
from apmcal_sim.makelog import write_bin
from apmcal_sim.vehicle import SimVehicle

SCENARIOS = ("healthy", "compass_drift", "compass_swap", "recalibration", "gyro_temperature")
FIRST_FLIGHT = datetime.datetime(2026, 3, 1, 9, 0, tzinfo=datetime.timezone.utc)
DAYS_BETWEEN_FLIGHTS = 3.0
HOLD_S = 8.0                   # still hold before and after the turns [s]
TURN_S = 5.0                   # one full turn about a body axis [s]
DRIFT_MGAUSS_PER_FLIGHT = 30.0  # compass_drift: horizontal hard-iron growth per flight [mGauss]
SENSITIVE_GYRO_COEF = 4e-4      # gyro_temperature: bias per kelvin [rad/s/K] (0.023 °/s/K)
NORMAL_GYRO_COEF = 1e-5         # the others [rad/s/K]
WARMUP = {"rise_k": 18.0, "tau_s": 12.0}   # the board warms 18 K with a 12 s time constant
COMPASS_DEV_IDS = (466441.0, 662793.0)     # before / after a swap (bus, address, type codes)
CALIBRATION_SLACK_MGAUSS = 5.0  # 1-σ error of each vehicle's COMPASS_OFS against its hard iron


@dataclass
class FlightPlan:
    """What one flight of one vehicle looks like: its truth and the parameters in force."""

    vehicle: str
    index: int
    unix_s: float
    ambient_c: float
    hard_iron: np.ndarray               # true compass offset [mGauss, compass frame]
    compass_ofs: np.ndarray             # COMPASS_OFS in force [mGauss]
    gyro_coef: float                    # gyro bias per kelvin [rad/s/K]
    compass_dev_id: float
    extra: dict = field(default_factory=dict)


def flight_motion(hold_s: float = HOLD_S) -> motion.Motion:
    """A still hold of ``hold_s`` [s], a full turn about the body z, x, y and a diagonal axis,
    a still hold of ``hold_s``."""
    m = motion.Motion().hold(hold_s, "preflight")
    for axis, label in (((0, 0, 1), "yaw"), ((1, 0, 0), "roll"), ((0, 1, 0), "pitch"),
                        ((1, 1, 1), "diagonal")):
        m.rotate(axis, 360.0, TURN_S, label).hold(1.0, "pause")
    return m.hold(hold_s, "postflight")


def vehicle_truth(seed: int, plan: FlightPlan) -> Truth:
    """The sensors of one flight: only gyro bias, noise, hard iron and temperature drift on."""
    truth = Truth.random(seed).with_effects(disable=["all"])
    truth = truth.with_effects(enable=["gyro_bias", "acc_noise", "gyro_noise", "mag_noise",
                                       "mag_hard_iron", "temperature_drift", "local_gravity"])
    truth.mag_hard_iron = [float(x) for x in plan.hard_iron]
    truth.temperature.update(WARMUP, ambient_c=plan.ambient_c, acc_coef=[0.0] * 3,
                             gyro_coef=[plan.gyro_coef] * 3)
    return truth


def plan_vehicle(i: int, flights: int, rng: np.random.Generator) -> tuple[list[FlightPlan], list]:
    """The flights of vehicle ``i`` and the events injected into them (truth records)."""
    name = f"veh{i:02d}"
    scenario = SCENARIOS[i % len(SCENARIOS)]
    base = rng.normal(0.0, 80.0, 3)
    slack = rng.normal(0.0, CALIBRATION_SLACK_MGAUSS, 3)   # no calibration is exact
    angle = rng.uniform(0, 2 * np.pi)          # compass_drift: direction of the growth
    middle = flights // 2
    plans, events = [], []
    for k in range(flights):
        unix = FIRST_FLIGHT.timestamp() + (k * DAYS_BETWEEN_FLIGHTS + i * 0.1) * 86400.0
        ambient = 12.0 + 10.0 * np.sin(2 * np.pi * (k / max(flights, 1))) + rng.normal(0, 2)
        hard, ofs = base.copy(), -base + slack
        coef, dev = NORMAL_GYRO_COEF, COMPASS_DEV_IDS[0]
        if scenario == "compass_drift" and k >= 1:
            hard = base + DRIFT_MGAUSS_PER_FLIGHT * k * np.array([np.cos(angle), np.sin(angle), 0.3])
        if scenario in ("compass_swap", "recalibration") and k >= middle:
            new = base + np.array([120.0, -90.0, 40.0])
            hard, ofs = new, -new + slack
            if scenario == "compass_swap":
                dev = COMPASS_DEV_IDS[1]
        if scenario == "gyro_temperature":
            coef = SENSITIVE_GYRO_COEF
        plans.append(FlightPlan(name, k, unix, float(ambient), hard, ofs, coef, dev))
    date = lambda k: datetime.datetime.fromtimestamp(plans[k].unix_s, datetime.timezone.utc)
    if scenario == "compass_drift":
        events.append({"vehicle": name, "kind": "compass_drift", "flight": 1,
                       "date": date(1).date().isoformat()})
    if scenario == "compass_swap":
        events.append({"vehicle": name, "kind": "hardware_changed", "flight": middle,
                       "date": date(middle).date().isoformat(), "param": "COMPASS_DEV_ID"})
    if scenario in ("compass_swap", "recalibration"):
        events.append({"vehicle": name, "kind": "recalibration", "flight": middle,
                       "date": date(middle).date().isoformat()})
    if scenario == "gyro_temperature":
        events.append({"vehicle": name, "kind": "gyro_temperature", "flight": 0,
                       "date": date(0).date().isoformat(),
                       "gyro_coef_dps_per_k": float(np.degrees(SENSITIVE_GYRO_COEF))})
    return plans, events


def uid_line(i: int) -> str:
    """The board's UID message as ArduPilot logs it at boot: board name and 96-bit UID."""
    return f"fmuv3 {0x00400020 + i:08X} {0x3436510B + 7 * i:08X} {0x36383331 + 13 * i:08X}"


def write_flight(plan: FlightPlan, i: int, out: Path, rate: float, seed: int,
                 hold_s: float = HOLD_S) -> None:
    """Simulate one flight and write it as a dataflash log ``out``."""
    truth = vehicle_truth(seed * 1000 + i, plan)
    v = SimVehicle(truth, "operator", "3.3", None, fs=2 * rate, seed=seed * 1000 + 100 * i + plan.index,
                   gyro_boot_s=1.0, start_unix=plan.unix_s)
    v.motion = flight_motion(hold_s)
    v._boot_gyro = None                 # INS_GYROFFS below are in force; no boot calibration
    v.params.set("INS_GYR_CAL", 0, save=False)
    v.params.set("SYSID_THISMAV", i + 1, save=False)
    for axis, g, o in zip("XYZ", truth.gyro_bias, plan.compass_ofs):
        v.params.set(f"INS_GYROFFS_{axis}", g, save=False)
        v.params.set(f"COMPASS_OFS_{axis}", o, save=False)
    v.params.declare("COMPASS_DEV_ID", plan.compass_dev_id)
    v.params.declare("INS_GYR_ID", 2752522.0)
    v.params.declare("INS_ACC_ID", 2752522.0)
    write_bin(v, out, rate, v.motion.duration + 0.5, messages=(uid_line(i), "Frame: QUAD"))


def write_fleet(vehicles: int, flights: int, out: Path, seed: int = 0, rate: float = 25.0,
                hold_s: float = HOLD_S) -> dict:
    """Write the fleet's logs under ``out`` and return the truth (also saved as truth.json);
    ``rate`` [Hz] of the IMU/MAG records, ``hold_s`` [s] each still hold (longer logs)."""
    if vehicles < 1 or flights < 2:
        raise ApmcalError("need at least one vehicle and two flights", str(out))
    rng = np.random.default_rng(seed)
    truth = {"vehicles": {}, "events": [], "seed": seed, "rate_hz": rate}
    for i in range(vehicles):
        plans, events = plan_vehicle(i, flights, rng)
        folder = out / plans[0].vehicle
        folder.mkdir(parents=True, exist_ok=True)
        for plan in plans:
            write_flight(plan, i, folder / f"flight_{plan.index:02d}.bin", rate, seed, hold_s)
        truth["vehicles"][plans[0].vehicle] = {
            "scenario": SCENARIOS[i % len(SCENARIOS)], "sysid": i + 1, "uid_line": uid_line(i),
            "flights": [{"file": f"{p.vehicle}/flight_{p.index:02d}.bin", "unix_s": p.unix_s,
                         "ambient_c": p.ambient_c, "hard_iron_mgauss": p.hard_iron.tolist(),
                         "compass_ofs": p.compass_ofs.tolist(), "gyro_coef_rad_s_per_k": p.gyro_coef,
                         "compass_dev_id": p.compass_dev_id} for p in plans]}
        truth["events"].extend(events)
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return truth


#: the flag kind (apmcal.fleet.flags) that reports each injected event, and whether its date
#: must be the event's
EXPECTED_FLAG = {"compass_drift": ("compass_recalibrate", False),
                 "hardware_changed": ("hardware_changed", True),
                 "recalibration": ("calibration_changed", True),
                 "gyro_temperature": ("gyro_tcal", False)}


def score_flags(flags: list[dict], truth: dict) -> dict:
    """Compare ``apmcal fleet``'s flags (vehicle_id, kind, date) with the injected events.

    A vehicle's id is its UID line (board and UID, as :mod:`apmcal.fleet.identity` forms it).
    An event is found when a flag of its kind (:data:`EXPECTED_FLAG`) names its vehicle (and
    its date where the kind is dated); a flag that matches no event is false.

    Returns
    -------
    dict
        events, found, found_fraction, flags, false, false_fraction, missed (events),
        false_flags (flags).
    """
    vid = {name: v["uid_line"] for name, v in truth["vehicles"].items()}
    wanted = []
    for e in truth["events"]:
        kind, dated = EXPECTED_FLAG[e["kind"]]
        wanted.append((vid[e["vehicle"]], kind, e["date"] if dated else None, e))
    match = lambda f, w: (f["vehicle_id"] == w[0] and f["kind"] == w[1]
                          and (w[2] is None or f["date"] == w[2]))
    missed = [w[3] for w in wanted if not any(match(f, w) for f in flags)]
    false = [f for f in flags if not any(match(f, w) for w in wanted)]
    n_e, n_f = len(wanted), len(flags)
    return {"events": n_e, "found": n_e - len(missed),
            "found_fraction": (n_e - len(missed)) / n_e if n_e else 1.0,
            "flags": n_f, "false": len(false), "false_fraction": len(false) / n_f if n_f else 0.0,
            "missed": missed, "false_flags": false}


def print_score(flags_csv: Path, truth_json: Path) -> int:
    """Print :func:`score_flags` of a flags.csv against a truth.json; 1 when it falls short of
    90 % of the events found with at most 10 % false flags, 2 when a file cannot be read."""
    import csv

    try:
        with open(flags_csv, newline="") as f:
            flags = list(csv.DictReader(f))
        truth = json.loads(truth_json.read_text())
    except (OSError, ValueError) as err:
        print(f"apmcal_sim.fleet: {err}", file=sys.stderr)
        return 2
    score = score_flags(flags, truth)
    print(json.dumps(score, indent=1))
    return 0 if score["found_fraction"] >= 0.9 and score["false_fraction"] <= 0.1 else 1


def main(argv=None) -> int:
    """``python -m apmcal_sim.fleet``: write a simulated fleet; the exit status."""
    ap = argparse.ArgumentParser(prog="python -m apmcal_sim.fleet", description=__doc__.split("\n")[0])
    ap.add_argument("--vehicles", type=int, default=5)
    ap.add_argument("--flights", type=int, default=6)
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=25.0, help="IMU/MAG log rate [Hz]")
    ap.add_argument("--hold", type=float, default=HOLD_S,
                    help=f"each still hold before and after the turns [s] (default {HOLD_S:g})")
    ap.add_argument("--score", metavar="FLAGS.csv",
                    help="instead of writing: score apmcal fleet's flags.csv against "
                         "DIR/truth.json (prints JSON; exit 1 below 90 %% found or above 10 %% "
                         "false)")
    args = ap.parse_args(argv)
    if args.score:
        return print_score(Path(args.score), Path(args.out) / "truth.json")
    try:
        write_fleet(args.vehicles, args.flights, Path(args.out), args.seed, args.rate, args.hold)
    except (ApmcalError, OSError) as err:
        print(f"apmcal_sim.fleet: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
