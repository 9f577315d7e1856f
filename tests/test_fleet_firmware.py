"""apmcal fleet on a fleet recorded from ArduPilot's own firmware (ArduCopter 4.7 SITL) in the
test run: vehicles told apart by what their logs carry (MAV_SYSID, the MAVLink header of a
.tlog, the user's own mapping), every injected event flagged on its vehicle and flight and
nothing else, and the compass judged on ordinary flights with the figures `apmcal log` prints.

The fleet (tests/sitl_fleet.py, EVENT_FLEET): four vehicles, each its own parameter store kept between
flights, three flights three days apart:

- MAV_SYSID 11: nothing happens; the fleet must say nothing;
- 12: the compass's hard iron moves by HARD_IRON_SHIFT before flight 2 (SIM_MAG1_OFS), never
  recalibrated: its surroundings changed on flight 2, heading error past usable since flight 2;
- 13: an accelerometer z bias ACC_BIAS from flight 2 (SIM_ACC1_BIAS_Z): recalibrate the
  accelerometers, since flight 2; and its compass replaced by another before flight 3
  (SIM_MAG1_DEVID, COMPASS_PRIO1_ID): the compass hardware changed on flight 3, and the
  settings the firmware moved with it between slots (COMPASS_EXTERNAL, an info);
- 14: COMPASS_OFS in force wrong by WRONG_OFS on flight 1, recalibrated before flight 2: the
  recalibration on flight 2, with the heading error before (past usable) and after.

Recorded once per test run at speedup 200, whatever the xdist workers (tests/once_per_run.py;
about 55 s of CPU in all, the firmware's included) and measured once (one serial fleet run,
whose cache the other runs read).
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from ardupilot_sitl import unavailable_reason
from once_per_run import once_per_run
from sitl_fleet import (
    ACC_BIAS,
    COMPASS_DEVID,
    EVENT_FLEET,
    HARD_IRON_SHIFT,
    NEW_COMPASS_DEVID,
    record_fleet,
)

from apmcal.cli import main
from apmcal.fleet.run import run_fleet

pytestmark = pytest.mark.ardupilot_sitl

# (MAV_SYSID, kind, flight, level) of every flag the fleet must raise, and no other
EXPECTED = {(12, "compass_surroundings", 2, "action"), (12, "compass_recalibrate", 2, "action"),
            (13, "acc_recalibrate", 2, "action"), (13, "hardware_changed", 3, "action"),
            (13, "calibration_changed", 3, "info"), (14, "calibration_changed", 2, "info")}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The fleet's logs and truth, recorded once per test run (whatever the xdist workers)."""
    reason = unavailable_reason()
    if reason:
        pytest.skip(reason)
    folder = once_per_run(tmp_path_factory, "sitl_fleet",
                          lambda f: record_fleet(f, EVENT_FLEET))
    return folder, json.loads((folder / "truth.json").read_text())


@pytest.fixture(scope="module")
def fleet(recorded, tmp_path_factory):
    """`apmcal fleet` on the dataflash logs: measured once per test run, into a cache each
    worker's run then reads (the records are the same, value for value)."""
    folder, _ = recorded
    first = once_per_run(tmp_path_factory, "sitl_fleet_out",
                         lambda out: run_fleet([str(folder / "bin")], out, serial=True))
    out = tmp_path_factory.mktemp("out")
    shutil.copytree(first / "cache", out / "cache")
    return run_fleet([str(folder / "bin")], out, serial=True)


def _sysid_of(vehicle_id: str) -> int:
    return int(vehicle_id.rsplit(" ", 1)[1])


def _rows(fleet, truth, sysid: int) -> pd.DataFrame:
    """The flights of one vehicle, in the order they were flown (truth)."""
    by_name = fleet.flights.set_index(fleet.flights["path"].map(lambda p: Path(p).name))
    return by_name.loc[[f["file"] for f in truth["vehicles"][str(sysid)]["flights"]]]


def test_the_events_were_injected(recorded):
    """The firmware echoed every parameter the plans wrote (float32 of the value)."""
    _, truth = recorded
    for v in truth["vehicles"].values():
        for f in v["flights"]:
            assert f["read_back"] == pytest.approx(f["writes"], abs=1e-4)


def test_vehicles_told_apart_by_their_system_id(recorded, fleet):
    _, truth = recorded
    assert len(fleet.vehicles) == 4
    for sysid in (11, 12, 13, 14):
        rows = _rows(fleet, truth, sysid)
        assert set(rows["vehicle_id"]) == {f"ArduCopter sysid {sysid}"}
        assert list(rows["flight"]) == [1, 2, 3]          # its own flights, in date order
    assert set(fleet.vehicles["identified_by"]) == {"MAV_SYSID parameter"}


def test_every_event_flagged_on_its_vehicle_and_flight_and_nothing_else(recorded, fleet):
    _, truth = recorded
    flags = fleet.flags
    got = {(_sysid_of(r.vehicle_id), r.kind, int(r.flight), r.level) for r in flags.itertuples()}
    assert got == EXPECTED, flags[["vehicle_id", "kind", "flight", "reason"]].to_string()
    for r in flags.itertuples():        # the flag names the log of that flight
        flown = truth["vehicles"][str(_sysid_of(r.vehicle_id))]["flights"][int(r.flight) - 1]
        assert Path(r.path).name == flown["file"]
    assert fleet.action_flags == 4
    swap = flags[flags["kind"] == "hardware_changed"]
    assert swap["reason"].iloc[0].startswith("compass hardware changed") and \
        f"COMPASS_DEV_ID {COMPASS_DEVID} → 0" in swap["reason"].iloc[0] and \
        f"COMPASS_DEV_ID2 0 → {NEW_COMPASS_DEVID}" in swap["reason"].iloc[0]
    assert swap["next_step"].iloc[0].startswith("recalibrate the compass")   # not recalibrated


def test_the_figures_behind_the_flags_against_the_injected_values(recorded, fleet):
    _, truth = recorded
    # 12: the fitted hard iron moved by the injected shift (within 3σ of the two fits, and the
    # whole mGauss the simulated compass reads)
    v12 = _rows(fleet, truth, 12)
    cols = [f"compass0_hard_iron_{a}_mgauss" for a in "xyz"]
    sig = [f"compass0_hard_iron_sigma_{a}_mgauss" for a in "xyz"]
    move = v12[cols].iloc[1].to_numpy(float) - v12[cols].iloc[0].to_numpy(float)
    sigma = np.hypot(v12[sig].iloc[1].to_numpy(float), v12[sig].iloc[0].to_numpy(float))
    assert np.all(np.abs(move - np.array(HARD_IRON_SHIFT)) <= 3 * sigma + 1.0), (move, sigma)
    assert (v12["heading_error_deg"].iloc[1:] > 5).all()
    # 13: |a| − g moved by the bias (scaled by INS_ACCSCAL_Z 1.001 in force) from flight 2 on
    v13 = _rows(fleet, truth, 13)["acc_norm_err_ms2"].to_numpy(float)
    assert v13[1:] - v13[0] == pytest.approx([-ACC_BIAS * 1.001] * 2, abs=0.005)
    # 14: past usable with the wrong calibration, good or usable after the recalibration
    v14 = _rows(fleet, truth, 14)["heading_error_deg"].to_numpy(float)
    assert v14[0] > 5 and (v14[1:] <= 5).all()
    info = fleet.flags[(fleet.flags["kind"] == "calibration_changed")
                       & (fleet.flags["vehicle_id"] == "ArduCopter sysid 14")]["reason"].iloc[0]
    assert f"{v14[0]:.1f}° → {v14[1]:.1f}°" in info
    # 11: untouched, within usable in the median the flag judges (one flight of an untouched
    # vehicle has read 5.7°: the flight check's reference, re-anchored every 60 s, at takeoff)
    assert np.median(_rows(fleet, truth, 11)["heading_error_deg"]) <= 5


def test_compass_figures_are_those_apmcal_log_reports(recorded, fleet, tmp_path):
    """The flight after the hard iron moved: `apmcal log FLIGHT --json` and the fleet's row."""
    folder, truth = recorded
    name = truth["vehicles"]["12"]["flights"][1]["file"]
    out = tmp_path / "log.json"
    assert main(["log", str(folder / "bin" / name), "--json", str(out)]) in (0, 1)  # 1: withheld
    compass = json.loads(out.read_text())["compasses"][0]
    row = _rows(fleet, truth, 12).loc[name]
    assert row["compass0_heading_p95_deg"] == compass["in_force_health"]["heading_error_p95_deg"]
    assert row["compass0_verdict"] == compass["in_force_health"]["verdict"] == "redo"
    for a in "XYZ":
        assert row[f"compass0_hard_iron_{a.lower()}_mgauss"] == compass["proposed"][
            f"COMPASS_OFS_{a}"]


def test_telemetry_logs_told_apart_by_the_mavlink_header(recorded, tmp_path):
    """The .tlogs carry no MAV_SYSID parameter (nor a board UID): the frames' headers do."""
    folder, truth = recorded
    result = run_fleet([str(folder / "tlog")], tmp_path / "out", serial=True)
    by_name = result.flights.set_index(result.flights["path"].map(lambda p: Path(p).name))
    for sysid, v in truth["vehicles"].items():
        rows = by_name.loc[[f["tlog"] for f in v["flights"]]]
        assert set(rows["vehicle_id"]) == {f"ArduCopter sysid {sysid}"}
        assert set(rows["identified_by"]) == {"MAVLink header system id"}
    assert len(result.vehicles) == 4


def test_the_users_own_mapping_wins(recorded, fleet, tmp_path, capsys):
    """--vehicles: globs and files name vehicles over what the logs say (the records come from
    the fleet's cache: the mapping is applied after them); a bad line stops before work."""
    folder, truth = recorded
    files = {s: [f["file"] for f in v["flights"]] for s, v in truth["vehicles"].items()}
    mapping = folder / "vehicles.txt"
    first = files["12"][0]                  # "log_002.bin" → the glob "bin/log_00[2].bin"
    mapping.write_text("# our names\n" + "".join(f"bin/{f} = Alpha\n" for f in files["11"])
                       + f"bin/{first[:-5]}[{first[-5]}].bin = Charlie\n"
                       + "".join(f"bin/{f} = Bravo\n" for f in files["12"]))
    shutil.copytree(fleet.out / "cache", tmp_path / "mapped" / "cache")
    result = run_fleet([str(folder / "bin")], tmp_path / "mapped", serial=True, vehicles=mapping)
    assert result.flights["cached"].all()
    by_name = result.flights.set_index(result.flights["path"].map(lambda p: Path(p).name))
    assert set(by_name.loc[files["11"], "vehicle_id"]) == {"Alpha"}
    assert set(by_name.loc[files["12"][1:], "vehicle_id"]) == {"Bravo"}
    assert by_name.loc[first, "vehicle_id"] == "Charlie"          # the first line that matches
    assert by_name.loc[files["11"][0], "identified_by"] == "--vehicles vehicles.txt line 2 " \
                                                             f"(bin/{files['11'][0]})"
    assert set(by_name.loc[files["13"], "vehicle_id"]) == {"ArduCopter sysid 13"}
    bad = folder / "bad.txt"
    bad.write_text("bin/log_001.bin Alpha\n")
    assert main(["fleet", str(folder / "bin"), "--out", str(tmp_path / "o"), "--vehicles",
                 str(bad), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert "bad.txt" in err and "line 1" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()          # stopped before any work
