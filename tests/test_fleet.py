"""apmcal fleet: flags against a simulated fleet's injected events, the cache, bad files, Dask
(a real LocalCluster, and a real `dask scheduler` with two `dask worker` processes on loopback),
and the real logs of ../shared/data."""
import json
import re
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from once_per_run import once_per_run

from apmcal.cli import main
from apmcal.fleet.run import run_fleet
from apmcal_sim.fleet import score_flags, write_fleet

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "ardupilot"


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """5 vehicles × 4 flights (one of each scenario), seed 3 (the flags were tuned on seed 0);
    simulated once per test run (tests/once_per_run.py)."""
    folder = once_per_run(tmp_path_factory, "sim_fleet",
                          lambda f: write_fleet(5, 4, f / "logs", seed=3)) / "logs"
    return folder, json.loads((folder / "truth.json").read_text())


@pytest.fixture(scope="module")
def serial_run(fleet, tmp_path_factory):
    """The serial run, measured once per test run; each worker's run reads its cache."""
    folder, _ = fleet
    first = once_per_run(tmp_path_factory, "sim_fleet_out",
                         lambda out: run_fleet([str(folder)], out, serial=True))
    out = tmp_path_factory.mktemp("out_serial")
    shutil.copytree(first / "cache", out / "cache")
    return run_fleet([str(folder)], out, serial=True)


def comparable(flights: pd.DataFrame) -> pd.DataFrame:
    """A flights table without what legitimately differs between runs (cache use)."""
    return flights.drop(columns=["cached"]).sort_values("path").reset_index(drop=True)


def test_flags_find_the_injected_events(fleet, serial_run):
    _, truth = fleet
    score = score_flags(serial_run.flags.to_dict("records"), truth)
    assert score["events"] == 5
    assert score["found_fraction"] >= 0.9, score["missed"]
    assert score["false_fraction"] <= 0.1, score["false_flags"]
    # the figures behind the flags against the injected values
    v = serial_run.vehicles.set_index("vehicle_id")
    sensitive = truth["vehicles"]["veh04"]
    slope = v.loc[sensitive["uid_line"], "gyro_temp_slope_dps_per_c"]
    injected = np.degrees(sensitive["flights"][0]["gyro_coef_rad_s_per_k"])
    assert slope == pytest.approx(injected, rel=0.1)


def test_heading_error_against_the_injected_offsets(fleet, serial_run):
    """Every flight's heading error against asin(|horizontal (hard iron + COMPASS_OFS)| / B_h)
    of the truth (the residual offset the simulated calibration leaves, body = compass frame)."""
    from apmcal.core.geomag import decimal_year, earth_field_ned
    from apmcal.sensor_model.truth import DEFAULT_SITE

    folder, truth = fleet
    by_path = serial_run.flights.set_index("path")
    n = 0
    for v in truth["vehicles"].values():
        for f in v["flights"]:
            row = by_path.loc[str((folder / f["file"]).resolve())]
            when = pd.Timestamp(f["unix_s"], unit="s", tz="UTC").to_pydatetime()
            field, _ = earth_field_ned(DEFAULT_SITE["lat"], DEFAULT_SITE["lon"],
                                       DEFAULT_SITE["alt"], decimal_year(when))
            residual = np.add(f["hard_iron_mgauss"], f["compass_ofs"])
            expected = np.degrees(np.arcsin(np.hypot(*residual[:2]) / np.hypot(*field[:2])))
            assert row["heading_error_deg"] == pytest.approx(expected, abs=0.3), f["file"]
            n += 1
    assert n == 20


def test_outputs_written(serial_run):
    out = serial_run.out
    flights = pd.read_parquet(out / "flights.parquet")
    assert len(flights) == 20 and (flights["status"] == "ok").all()
    assert len(pd.read_parquet(out / "vehicles.parquet")) == 5
    flags = pd.read_csv(out / "flags.csv")
    assert list(flags.columns[:4]) == ["vehicle_id", "level", "kind", "date"]
    page = (out / "index.html").read_text()
    assert page.count("data:image/png;base64,") == 5
    assert "http://" not in page and "https://" not in page     # nothing from the network


def test_rerun_uses_the_cache(fleet, tmp_path):
    folder, _ = fleet
    small = tmp_path / "logs"
    shutil.copytree(folder / "veh01", small / "veh01")
    first = run_fleet([str(small)], tmp_path / "out", serial=True)
    assert not first.flights["cached"].any()
    again = run_fleet([str(small)], tmp_path / "out", serial=True)
    assert again.flights["cached"].all()
    pd.testing.assert_frame_equal(comparable(first.flights), comparable(again.flights))
    changed = small / "veh01" / "flight_03.bin"
    changed.write_bytes(changed.read_bytes() + b"\0" * 16)     # new content: measured again
    third = run_fleet([str(small)], tmp_path / "out", serial=True)
    redone = third.flights.loc[~third.flights["cached"].astype(bool), "path"].tolist()
    assert redone == [str(changed.resolve())]


def test_damaged_and_text_files_become_rows(fleet, tmp_path):
    folder, _ = fleet
    logs = tmp_path / "logs" / "nested"
    logs.mkdir(parents=True)
    good = folder / "veh00" / "flight_00.bin"
    shutil.copy(good, logs / "good.bin")
    (logs / "broken.bin").write_bytes(np.random.default_rng(1).bytes(3000))
    (logs / "notes.log").write_text("flight notes: props changed, nothing else\n")
    result = run_fleet([str(tmp_path / "logs")], tmp_path / "out", serial=True, cache=False)
    rows = result.flights.set_index(result.flights["path"].map(lambda p: Path(p).name))
    assert rows.loc["good.bin", "status"] == "ok"
    for name in ("broken.bin", "notes.log"):
        assert rows.loc[name, "status"] == "error"
        assert name in rows.loc[name, "reason"]     # the reason names the file


def test_local_cluster_same_as_serial(fleet, serial_run, tmp_path):
    folder, _ = fleet
    result = run_fleet([str(folder)], tmp_path / "out", workers=2, cache=False)
    pd.testing.assert_frame_equal(comparable(serial_run.flights), comparable(result.flights),
                                  check_exact=True)
    pd.testing.assert_frame_equal(serial_run.flags, result.flags)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args) -> list[str]:
    return [sys.executable, "-m", "distributed.cli.dask_" + args[0], *args[1:]]


def test_scheduler_and_two_workers_on_loopback(fleet, serial_run, tmp_path):
    from dask.distributed import Client

    folder, _ = fleet
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [subprocess.Popen(_dask("scheduler", "--host", "127.0.0.1", "--port", str(port),
                                    "--dashboard-address", ":0"), cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen(_dask("worker", address, "--nthreads", "1",
                                                "--host", "127.0.0.1", "--no-dashboard"),
                                          cwd=ROOT, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL))
        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(address, timeout="5s") as client:
                    client.wait_for_workers(2, timeout=60)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        out = tmp_path / "out"
        code = main(["fleet", str(folder), "--out", str(out), "--scheduler", address,
                     "--no-cache", "--quiet"])
        assert code == 1          # the injected events raise flags
        flights = pd.read_parquet(out / "flights.parquet")
        expected = pd.read_parquet(serial_run.out / "flights.parquet")
        pd.testing.assert_frame_equal(comparable(expected), comparable(flights), check_exact=True)
        assert pd.read_csv(out / "flags.csv").equals(pd.read_csv(serial_run.out / "flags.csv"))
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_exit_codes_and_bad_input(fleet, tmp_path, capsys, monkeypatch):
    folder, truth = fleet
    # a healthy vehicle alone: no flag, exit 0
    assert main(["fleet", str(folder / "veh00"), "--out", str(tmp_path / "a"), "--workers", "0",
                 "--quiet"]) == 0
    assert main(["fleet", str(tmp_path / "nowhere"), "--out", str(tmp_path / "b")]) == 2
    assert "nowhere" in capsys.readouterr().err
    # a manifest naming one vehicle's logs by glob
    manifest = tmp_path / "logs.txt"
    manifest.write_text(f"# one vehicle\n{folder}/veh01/*.bin\n")
    assert main(["fleet", str(manifest), "--out", str(tmp_path / "c"), "--workers", "0",
                 "--quiet"]) == 1
    assert len(pd.read_parquet(tmp_path / "c" / "flights.parquet")) == 4
    # without Dask: one line saying how to install it, exit 2
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    assert main(["fleet", str(folder), "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err.strip()
    assert "pip install 'apmcal[fleet]'" in err and len(err.splitlines()) == 1


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    """The real logs of ../shared/data in nested folders, with a damaged copy and a text file,
    through `apmcal fleet` once per test run (tests/once_per_run.py): (exit status, output
    folder, number of real logs)."""
    if not REAL.is_dir():
        pytest.skip(f"real logs absent: {REAL} (the shared data folder is not in this checkout)")
    tmp = once_per_run(tmp_path_factory, "fleet_real_logs", _real_run)
    return int((tmp / "exit_status").read_text()), tmp / "out", int((tmp / "n_real").read_text())


def _real_run(tmp: Path) -> None:
    logs = tmp / "logs"
    real = sorted(p for p in REAL.iterdir() if p.suffix.lower() in (".bin", ".log", ".tlog"))
    for i, p in enumerate(real):
        dest = logs / ("a" if i % 2 else "b/c") / p.name
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(p, dest)
    src = REAL / "pixhawk1_copter368.bin"
    data = src.read_bytes()
    (logs / "b" / "damaged_copy.bin").write_bytes(data[:200] + np.random.default_rng(2).bytes(5000))
    (logs / "a" / "readme.log").write_text("not a log, just some text\n")
    out = tmp / "out"
    code = main(["fleet", str(logs), "--out", str(out), "--workers", "1", "--quiet"])
    (tmp / "exit_status").write_text(str(code))
    (tmp / "n_real").write_text(str(len(real)))


def test_real_logs(real_run):
    code, out, n_real = real_run
    assert code == 1            # log171's compasses are past usable (test_fleet_and_log_agree...)
    flights = pd.read_parquet(out / "flights.parquet")
    assert len(flights) == n_real + 2
    by_name = flights.set_index(flights["path"].map(lambda p: Path(p).name))
    assert by_name.loc["damaged_copy.bin", "status"] == "error"
    assert by_name.loc["readme.log", "status"] == "error"
    assert (by_name.drop(["damaged_copy.bin", "readme.log"])["status"] == "ok").all()
    # boards told apart by their logged UID, and each vehicle says how it was identified
    assert "Pixhawk1 00310019 3138510E 35363631" in set(flights["vehicle_id"])
    vehicles = pd.read_parquet(out / "vehicles.parquet").set_index("vehicle_id")
    assert vehicles.loc["Pixhawk1 00310019 3138510E 35363631", "identified_by"] == \
        "board UID (boot message)"
    assert vehicles["identified_by"].str.len().gt(0).all()
    assert (out / "index.html").exists()
    json.loads(by_name.loc["pixhawk1_copter368.bin", "dev_ids_json"])


def test_fleet_and_log_agree_on_log171(real_run, tmp_path):
    """The compass figures of a flight are the ones `apmcal log FLIGHT` prints, to the bit, and
    a compass in use past usable there is a flag here (the fleet used to say "compass not
    measured (need 0.15)" and raise nothing, where `apmcal log` graded all three REDO)."""
    _, out, _ = real_run
    log171 = REAL / "pixhawk_3imu_log171.bin"
    # exit 1: log171's proposals grade REDO and are withheld from a parameter file
    assert main(["log", str(log171), "--json", str(tmp_path / "log.json")]) in (0, 1)
    compasses = json.loads((tmp_path / "log.json").read_text())["compasses"]
    flights = pd.read_parquet(out / "flights.parquet")
    row = flights[flights["path"].str.endswith(log171.name)].iloc[0]
    for c in compasses:
        i = c["instance"]
        assert row[f"compass{i}_heading_p95_deg"] == c["in_force_health"]["heading_error_p95_deg"]
        assert row[f"compass{i}_verdict"] == c["in_force_health"]["verdict"] == "redo"
    flags = pd.read_csv(out / "flags.csv")
    compass = flags[(flags["vehicle_id"] == row["vehicle_id"])
                    & (flags["kind"] == "compass_recalibrate")]
    assert len(compass) == 1 and compass["level"].iloc[0] == "action"
    in_use = [c for c in compasses if row[f"compass{c['instance']}_in_use"]]
    for c in in_use:       # COMPASS_USE3 is 0 on log171: its third compass is not judged
        p95 = c["in_force_health"]["heading_error_p95_deg"]
        assert f"compass {c['instance']} {p95:.1f}°" in compass["reason"].iloc[0]
    assert len(in_use) == 2


def _points(g: pd.DataFrame, panel: str) -> int:
    """What one vehicle's flights give a trend panel to draw: finite values (for the gyro bias
    against temperature, distinct board temperatures a degree apart or more)."""
    cols = {"heading": ["heading_error_deg"], "acc": ["acc_norm_err_ms2"],
            "hard_iron": [c for c in g if c.endswith("_hard_iron_x_mgauss")]}
    if panel == "gyro_temp":
        temps = pd.concat([g.get("temp_start_c", pd.Series(dtype=float)),
                           g.get("temp_end_c", pd.Series(dtype=float))]).dropna()
        return 2 if len(temps) and temps.max() - temps.min() >= 1.0 else 0
    return max([int(g[c].notna().sum()) for c in cols[panel] if c in g] or [0])


def test_page_shows_only_plots_with_data_and_words(real_run):
    """index.html of the real logs: a trend image only for a vehicle with something to draw,
    each of its panels with two points or more (no empty axes, no single dots) and every
    figure with two points or more drawn; no "NaT", no raw column names."""
    _, out, _ = real_run
    page = (out / "index.html").read_text()
    flights = pd.read_parquet(out / "flights.parquet")
    ok = flights[flights["status"] == "ok"]
    panels = ("heading", "hard_iron", "gyro_temp", "acc")
    drawn = sum(any(_points(g, p) >= 2 for p in panels) for _, g in ok.groupby("vehicle_id"))
    assert page.count("data:image/png;base64,") == drawn
    assert 0 < drawn < ok["vehicle_id"].nunique()
    from apmcal.fleet.page import trend_panels

    for vid, g in ok.groupby("vehicle_id"):
        assert set(trend_panels(g)) == {p for p in panels if _points(g, p) >= 2}, vid
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", page).replace("_nan.log", "")
    assert "NaT" not in text and "nan" not in text.lower()
    headers = re.findall(r"<th>(.*?)</th>", page)
    assert headers and not [h for h in headers if "_" in h]       # labels, not column names
    assert "undated" in page                      # the undated logs say so


def test_exit_2_when_no_log_could_be_read(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "notes.log").write_text("flight notes: props changed, nothing else\n")
    (logs / "broken.bin").write_bytes(np.random.default_rng(1).bytes(3000))
    code = main(["fleet", str(logs), "--out", str(tmp_path / "out"), "--workers", "0"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "none of the 2 log(s) could be read" in err and "broken.bin" in err
    assert (tmp_path / "out" / "flights.parquet").exists()     # every reason kept


def test_heading_error_hand_worked():
    """A compass sphere offset by 30 mGauss along x: asin(30 / B_h) at the WMM's B_h."""
    from apmcal.calibration.health import compass_health
    from apmcal.core.geomag import earth_field_ned
    from apmcal.core.recording import Recording

    rng = np.random.default_rng(0)
    site, year = (45.0, 7.0, 0.0), 2026.0
    field, _ = earth_field_ned(*site, year)
    b_h = float(np.hypot(field[0], field[1]))
    d = rng.standard_normal((4000, 3))
    mag = d / np.linalg.norm(d, axis=1, keepdims=True) * np.linalg.norm(field)
    mag += np.array([30.0, 0.0, -12.0]) + rng.normal(0, 2.0, mag.shape)
    rec = Recording(pd.DataFrame({"t": np.arange(4000) * 0.1, "mag_x": mag[:, 0],
                                  "mag_y": mag[:, 1], "mag_z": mag[:, 2]}))
    out, notes = compass_health(rec, site, year)
    assert out["mag_residual_x_mgauss"] == pytest.approx(30.0, abs=0.5)
    assert out["mag_residual_z_mgauss"] == pytest.approx(-12.0, abs=0.5)
    expected = np.degrees(np.arcsin(30.0 / b_h))
    assert out["heading_error_deg"] == pytest.approx(expected, abs=3 * out["heading_error_sigma_deg"] + 0.05)
    assert abs(out["field_residual_mgauss"]) < 1.0
    # no site: the residual, but no heading error, and a note why
    out, notes = compass_health(rec, None, None)
    assert "heading_error_deg" not in out and "site is unknown" in notes[0]


def test_identity_from_boot_messages():
    from apmcal.core.recording import LogContents
    from apmcal.fleet.identity import calibration_in_force, compares_as_change, identity

    c = LogContents(path="x.bin", format="bin", vehicle="ArduCopter",
                    messages=["ArduCopter V3.6.8 (2f409678)", "Pixhawk1 00310019 3138510E 35363631",
                              "Frame: QUAD"],
                    params={"SYSID_THISMAV": 7, "COMPASS_OFS_X": 12.0, "INS_GYROFFS_X": 0.01,
                            "INS_TCAL1_ENABLE": 1, "RATE_RLL_P": 0.1})
    ident = identity(c)
    assert ident["vehicle_id"] == "Pixhawk1 00310019 3138510E 35363631"
    assert ident["frame"] == "QUAD" and ident["sysid"] == 7
    cal = calibration_in_force(c.params)
    assert set(cal) == {"COMPASS_OFS_X", "INS_GYROFFS_X", "INS_TCAL1_ENABLE"}
    assert not compares_as_change("INS_GYROFFS_X") and compares_as_change("COMPASS_OFS_X")
    c.messages = []
    assert identity(c)["vehicle_id"] == "ArduCopter sysid 7"
