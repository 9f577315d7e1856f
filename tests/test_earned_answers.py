"""No answer the data did not earn: a value graded REDO is never written or uploaded without
--accept-redo (and the command exits 1 saying so), values out of the firmware's limits never;
an implausible reading at rest is reported whatever the method; the overall verdict is never
GOOD when what was measured changes nothing; parameter files record their firmware generation
and upload refuses another vehicle's; --firmware against the log's own generation is said; a
CSV time column in milliseconds is not taken for seconds, and nan/inf samples are dropped as
docs/guide.md says; the full-turns figure integrates a turn as the fit does.

Each against independent truth: real logs (their values in force), a synthetic CSV whose
reading at rest is set by hand, the simulator's injected calibration (logs/*.truth.json), and a
simulated vehicle of the other generation.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from apmcal.ardupilot.paramfile import read_param_file
from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "ardupilot"
ACCRA = ["--lat", "5.6037", "--lon", "-0.187"]


def real(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"real recording {name} absent (the test data folder ../shared/data)")
    return path


def still_csv(path: Path, acc_ms2: float = 9.80665, mag_mgauss: float | None = None,
              time_factor: float = 1.0, nan_rows=(), seconds: float = 30.0) -> Path:
    """A still, level session at 100 Hz: |a| = ``acc_ms2`` [m/s²], gyro 0.01 rad/s offsets,
    optionally a still compass of |B| = ``mag_mgauss``, time × ``time_factor``, and the
    given rows' acc_y written as nan."""
    rng = np.random.default_rng(7)
    n = int(seconds * 100)
    t = np.arange(n) / 100 * time_factor
    acc = np.tile([0.0, 0.0, -acc_ms2], (n, 1)) + rng.normal(0, 0.02, (n, 3))
    gyr = np.tile([0.01, -0.02, 0.005], (n, 1)) + rng.normal(0, 0.002, (n, 3))
    cols, data = ["t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"], [t, acc, gyr]
    if mag_mgauss is not None:
        direction = np.array([0.6, 0.1, 0.79]) / np.linalg.norm([0.6, 0.1, 0.79])
        data.append(np.tile(direction * mag_mgauss, (n, 1)) + rng.normal(0, 1.0, (n, 3)))
        cols += ["mag_x", "mag_y", "mag_z"]
    rows = np.column_stack(data)
    lines = [",".join(cols)]
    for i, row in enumerate(rows):
        cells = [f"{v:.6f}" for v in row]
        if i in nan_rows:
            cells[2] = "nan"
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def verdict_of(argv, tmp_path) -> dict:
    out = tmp_path / "v.json"
    main([*argv, "--json", str(out), "--quiet"])
    return json.loads(out.read_text())["verdict"]


# -- 1: REDO never written without the flag ------------------------------------------------
def test_a_flight_writes_only_its_compasses_not_graded_redo(tmp_path, capsys):
    """pixhawk_3imu_log171.bin: compass 0's proposed calibration is USABLE, compasses 1 and 2
    are graded REDO: only compass 0 is written, with the COMPASS_MOTCT its COMPASS_MOT needs
    (one for all compasses), the command says why the rest is not and exits 1;
    --accept-redo writes them all and exits 0."""
    log = str(real("pixhawk_3imu_log171.bin"))
    param = tmp_path / "cal.param"
    assert main(["log", log, "--param-file", str(param)]) == 1
    out = " ".join(capsys.readouterr().out.split())
    written = read_param_file(param)
    assert "COMPASS_OFS_X" in written and written["COMPASS_MOTCT"] == 2
    assert not [n for n in written if n[:-2].endswith(("2", "3"))], written
    assert "compass 1's proposed calibration is graded REDO; --accept-redo writes them" in out
    assert "compass 2's proposed calibration is graded REDO" in out
    assert f"wrote {param} without the 22 values withheld above; exit status 1" in out
    assert main(["log", log, "--param-file", str(param), "--accept-redo"]) == 0
    written = read_param_file(param)
    assert "COMPASS_OFS2_X" in written and "COMPASS_MOT3_Z" in written


class _Compass:
    """What flight_writable reads of a compass fit (apmcal.calibration.flight.CompassFit)."""

    def __init__(self, instance, proposed, verdict):
        self.instance, self.proposed, self.in_force = instance, proposed, {}
        self.health_proposed = type("Health", (), {"verdict": verdict})()


class _Flight:
    def __init__(self, *compasses):
        self.compasses = compasses

    def params(self):
        return {n: v for c in self.compasses for n, v in c.proposed.items()}


def test_a_flight_compass_out_of_limits_is_withheld_whole_and_keeps_no_shared_value():
    """Worked by hand: compass 1's offsets are 2000 mGauss long (COMPASS_OFFS_MAX 1800): all
    of compass 1 is withheld, even with --accept-redo; COMPASS_MOTCT stays, compass 0 needs it.
    With compass 0 graded REDO too, COMPASS_MOTCT goes with the two of them."""
    from apmcal.calibration.flight_proposal import flight_writable

    good = _Compass(0, {"COMPASS_OFS_X": 50.0, "COMPASS_MOT_X": 1.0, "COMPASS_MOTCT": 2}, "good")
    far = _Compass(1, {"COMPASS_OFS2_X": 2000.0, "COMPASS_OFS2_Y": 0.0, "COMPASS_OFS2_Z": 0.0,
                       "COMPASS_MOT2_X": 3.0, "COMPASS_MOTCT": 2}, "usable")
    params = {"COMPASS_OFFS_MAX": 1800.0}
    w = flight_writable(_Flight(good, far), params, "3.3+", accept_redo=True)
    assert set(w.values) == {"COMPASS_OFS_X", "COMPASS_MOT_X", "COMPASS_MOTCT"}
    assert set(w.withheld) == {"COMPASS_OFS2_X", "COMPASS_OFS2_Y", "COMPASS_OFS2_Z",
                               "COMPASS_MOT2_X"}
    assert "COMPASS_OFFS_MAX" in w.withheld["COMPASS_OFS2_X"] and w.status == 1
    redo = _Compass(0, dict(good.proposed), "redo")
    w = flight_writable(_Flight(redo, far), params, "3.3+")
    assert w.values == {} and "COMPASS_MOTCT" in w.withheld


def test_a_gyro_graded_redo_is_not_written_unless_accepted(tmp_path, capsys):
    """pxf_copter_static_51.BIN: a gyro offset of 39 °/s (redo): no parameter file, exit 1,
    and the reason; --accept-redo writes the offsets it proposed and exits 0."""
    log = str(real("pxf_copter_static_51.BIN"))
    param = tmp_path / "cal.param"
    assert main(["log", log, "--param-file", str(param)]) == 1
    out = " ".join(capsys.readouterr().out.split())
    assert not param.exists()
    assert "INS_GYROFFS_X, INS_GYROFFS_Y, INS_GYROFFS_Z: the gyroscope is graded REDO" in out
    assert f"nothing written to {param}" in out
    assert main(["log", log, "--param-file", str(param), "--accept-redo"]) == 0
    assert set(read_param_file(param)) == {"INS_GYROFFS_X", "INS_GYROFFS_Y", "INS_GYROFFS_Z"}


def test_writable_sorts_redo_and_out_of_limits_values():
    from apmcal.ardupilot.limits import Writable

    values = {"INS_GYROFFS_X": 0.1, "COMPASS_OFS_X": 50.0, "INS_ACCOFFS_X": 0.2}
    redo = {"COMPASS_OFS_X": "the compass is graded REDO"}
    refused = {"INS_ACCOFFS_X": "|offset| 4 > 3.5 m/s²"}
    w = Writable.sort(values, redo, refused)
    assert w.values == {"INS_GYROFFS_X": 0.1} and w.status == 1
    assert set(w.withheld) == {"COMPASS_OFS_X", "INS_ACCOFFS_X"}
    forced = Writable.sort(values, redo, refused, accept_redo=True)
    assert forced.values == {"INS_GYROFFS_X": 0.1, "COMPASS_OFS_X": 50.0}
    assert forced.status == 1 and list(forced.forced) == ["COMPASS_OFS_X"]
    assert Writable.sort(values, redo, {}, accept_redo=True).status == 0


# -- 2: what the sensors read at rest, whatever the method ---------------------------------
def test_an_accelerometer_reading_off_g_at_rest_is_redo_not_unmeasured(tmp_path):
    """One still pose cannot measure the accelerometer, but a reading of 8.80 m/s² at rest is
    wrong as it stands: redo, with the figure; at 9.81 it stays "not measured"."""
    off = verdict_of(["log", str(still_csv(tmp_path / "off.csv", acc_ms2=8.8))], tmp_path)
    assert off["acc"]["grade"] == "redo"
    assert "at rest it reads 8.80 m/s²" in off["acc"]["reason"], off["acc"]
    assert off["overall"]["grade"] == "redo"
    ok = verdict_of(["log", str(still_csv(tmp_path / "ok.csv"))], tmp_path)
    assert ok["acc"]["grade"] == "not measured"


def test_a_compass_field_off_the_wmm_at_rest_is_redo(tmp_path):
    """A compass not turned cannot be calibrated, but one reading 700 mGauss where the WMM has
    about 330 (Accra) is wrong as it stands; one reading the WMM's field stays "not
    measured"."""
    from apmcal.core.geomag import field_magnitude

    wmm = field_magnitude(5.6037, -0.187)[0]
    off = verdict_of(["log", str(still_csv(tmp_path / "m.csv", mag_mgauss=2.1 * wmm)), *ACCRA],
                     tmp_path)
    assert off["mag"]["grade"] == "redo" and "World Magnetic Model" in off["mag"]["reason"]
    ok = verdict_of(["log", str(still_csv(tmp_path / "k.csv", mag_mgauss=wmm)), *ACCRA],
                    tmp_path)
    assert ok["mag"]["grade"] == "not measured"


def test_the_one_pose_sample_reads_what_its_injected_errors_make_of_gravity(tmp_path):
    """logs/onepos.tlog: neutral parameters in force, so at rest the vehicle reads what the
    injected accelerometer errors make of gravity (its z scale 1.057: 9.17 m/s²): redo."""
    from apmcal.sensor_model.truth import Truth

    truth = Truth.load(ROOT / "logs" / "onepos.truth.json")
    acc = truth.sensor_calibrations()["acc"]
    expected = np.linalg.norm(np.linalg.solve(acc.matrix, [0, 0, -truth.gravity()])
                              + acc.offset)
    out = tmp_path / "o.json"
    main(["log", str(ROOT / "logs" / "onepos.tlog"), "--json", str(out), "--quiet"])
    result = json.loads(out.read_text())
    assert result["report"]["at_rest"]["acc_ms2"] == pytest.approx(expected, abs=0.01)
    assert result["verdict"]["acc"]["grade"] == "redo"


def test_the_real_static_log_reads_low_at_rest(capsys):
    """pxf_copter_static_51.BIN, factory accelerometer calibration in force: |a| ≈ 8.4 m/s² at
    rest is said in the accelerometer's line, not "not measured"."""
    assert main(["log", str(real("pxf_copter_static_51.BIN"))]) == 1
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("accelerometer:"))
    assert "redo — at rest it reads 8.3" in line or "redo — at rest it reads 8.4" in line, line


# -- 3: never GOOD when what was measured changes nothing ----------------------------------
def test_gyro_offsets_a_vehicle_re_measures_at_boot_are_nothing_to_apply(tmp_path):
    """One still pose measures the gyro offsets only: with INS_GYR_CAL 1 (the vehicle
    measures them at every boot) the overall verdict is NOTHING TO APPLY, with INS_GYR_CAL 0
    (it keeps them) the gyro's own grade."""
    import apmcal
    from apmcal.report.verdict import judge

    report = apmcal.calibrate(still_csv(tmp_path / "still.csv"), generation="3.3+")
    assert set(report.proposal.values) <= {"INS_GYROFFS_X", "INS_GYROFFS_Y", "INS_GYROFFS_Z"}
    gyro = judge(report.calibration, report.proposal)["gyr"].grade
    assert judge(report.calibration, report.proposal, (), True)["overall"].grade == \
        "nothing to apply"
    assert judge(report.calibration, report.proposal, (), False)["overall"].grade == gyro


def test_not_measured_is_said_once(capsys):
    assert main(["log", str(ROOT / "logs" / "onepos.tlog")]) in (0, 1)
    out = capsys.readouterr().out
    assert "compass: not measured by this session — " in out
    assert "— compass not measured by this session" not in out


# -- 8: firmware generations ----------------------------------------------------------------
def test_a_parameter_file_records_its_generation_and_upload_refuses_another(tmp_path, capsys):
    """A file made from the 3.2 sample says "3.2"; uploading it to a simulated 3.3 vehicle is
    refused before anything is written; --any-generation writes it, saying so."""
    from sim_operator import ThreadedSim

    from apmcal.ardupilot.paramfile import read_param_generation

    param = tmp_path / "cal.param"
    assert main(["log", str(ROOT / "logs" / "ferraris.tlog"), "--param-file", str(param),
                 "--quiet"]) == 0
    assert read_param_generation(param) == "3.2"
    sim = ThreadedSim(tmp_path, generation="3.3")
    try:
        sim.wait_for_boot()
        before = sim.vehicle.params["INS_ACCOFFS_X"]
        backup = str(tmp_path / "b.param")
        assert main(["upload", sim.connection, str(param), "--backup", backup]) == 2
        err = capsys.readouterr().err
        assert "made for firmware 3.2" in err and "nothing was written" in err
        assert sim.vehicle.params["INS_ACCOFFS_X"] == before
        assert main(["upload", sim.connection, str(param), "--backup", backup,
                     "--any-generation"]) == 0
        assert "uploading all the same" in capsys.readouterr().out
        assert sim.vehicle.params["INS_ACCOFFS_X"] == pytest.approx(
            read_param_file(param)["INS_ACCOFFS_X"], rel=1e-6)
    finally:
        sim.close()


def test_a_forced_firmware_generation_is_said(capsys):
    """--firmware 3.2 on the 3.3 sample changes the values: said, not silent."""
    assert main(["log", str(ROOT / "logs" / "ferraris_params33.tlog"), "--firmware", "3.2"]) \
        in (0, 1)
    out = " ".join(capsys.readouterr().out.split())
    assert "--firmware 3.2 given, but this log's firmware (ArduCopter V3.3.3) uses the 3.3+ " \
           "formulas" in out


def test_a_forced_generation_on_a_real_ardusub_log_is_said(capsys):
    main(["log", str(real("ardusub_small.BIN")), "--firmware", "3.2"])
    out = " ".join(capsys.readouterr().out.split())
    assert "--firmware 3.2 given, but this log's firmware (ArduSub V4.1.0)" in out


def test_a_csv_time_column_in_milliseconds_is_not_taken_for_seconds(tmp_path, capsys):
    """Time in ms without a unit: refused with the header that fixes it (not read as 0.1 Hz);
    declared t[ms], the same calibration as the file in seconds."""
    ms = still_csv(tmp_path / "ms.csv", time_factor=1000.0)
    assert main(["log", str(ms)]) == 2
    assert "name the column t[ms]" in capsys.readouterr().err
    declared = tmp_path / "declared.csv"
    declared.write_text(ms.read_text().replace("t,", "t[ms],", 1))
    seconds = still_csv(tmp_path / "s.csv")
    results = []
    for path in (declared, seconds):
        out = tmp_path / f"{path.stem}.json"
        assert main(["log", str(path), "--json", str(out), "--quiet"]) == 0
        results.append(json.loads(out.read_text()))
    assert results[0]["summary"]["recordings"][0]["rate_hz"] == pytest.approx(100.0)
    np.testing.assert_allclose(results[0]["gyr"]["offset"], results[1]["gyr"]["offset"])


def test_nan_samples_in_a_csv_are_dropped_and_counted(tmp_path, capsys):
    """docs/guide.md: non-finite samples are dropped and counted in a warning; the rest is
    calibrated as without them."""
    rows = (100, 200, 300)
    with_nan = still_csv(tmp_path / "nan.csv", nan_rows=rows)
    out = tmp_path / "nan.json"
    assert main(["log", str(with_nan), "--json", str(out)]) == 0
    assert "3 of 3000 samples dropped: 3 with NaN/inf values" in capsys.readouterr().out
    clean = tmp_path / "clean.csv"
    lines = still_csv(tmp_path / "all.csv").read_text().splitlines()
    clean.write_text("\n".join(ln for i, ln in enumerate(lines) if i - 1 not in rows) + "\n")
    ref = tmp_path / "clean.json"
    assert main(["log", str(clean), "--json", str(ref), "--quiet"]) == 0
    np.testing.assert_allclose(json.loads(out.read_text())["gyr"]["offset"],
                               json.loads(ref.read_text())["gyr"]["offset"], atol=1e-9)


# -- the full-turns figure -------------------------------------------------------------------
def test_the_full_turns_figure_shows_the_true_calibration_whole():
    """On the six-face sample, the injected (true) gyro calibration makes each turn read its
    expected angle to within 1.5°, as the report's "gyroscope: good" says (integrating the
    whole span of one axis's rate gave 7-9° off for the truth itself); uncorrected, the turn
    about y is off by what the injected y scale makes of 360° (the raw rate is the true one
    divided by it)."""
    from apmcal.calibration.log import calibrate_log
    from apmcal.preprocessing.prepare import pick_recording, prepare
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.report import figures as fig
    from apmcal.sensor_model.truth import Truth
    from apmcal.sources import read_log

    contents = read_log(ROOT / "logs" / "ferraris.tlog")
    cal, _ = calibrate_log(contents)
    raw = prepare(pick_recording(contents, None)[0], None).raw
    t, g = raw.t, raw.xyz("gyr")
    spans = {a: (tn.start_s, tn.end_s) for a, tn in cal.report.rotations.items()}
    expected = {a: -360.0 for a in spans}
    holds = find_static_segments(t, raw.xyz("acc"), g)
    true = Truth.load(ROOT / "logs" / "ferraris.truth.json").sensor_calibrations()["gyr"]
    truth = fig.turn_errors(t, fig.correct(true, g, t), spans, holds, expected)
    assert set(truth) == {"x", "y", "z"}
    assert all(abs(e) < 1.5 for e in truth.values()), truth
    raw_y = fig.turn_errors(t, g, spans, holds, expected)["y"]
    assert raw_y == pytest.approx(360.0 * (1 - 1 / true.matrix[1, 1]), abs=0.5)
