"""The calibration result: its JSON file (schema, units, round trip, version 1), apply on
samples, recordings and tables, and the gyro g-sensitivity as part of the applied model."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from sitl_helpers import session_recording

from apmcal.calibration.log import Options, calibrate, calibrate_log
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import Recording
from apmcal.report.lines import calibration_lines
from apmcal.report.verdict import judge
from apmcal.solvers.result import SCHEMA, Calibration, SensorCalibration
from apmcal.sources import read_log

ROOT = Path(__file__).resolve().parents[1]
SITE = Options(lat_deg=5.6037, lon_deg=-0.187)
V1_FILE = ROOT / "tests" / "data" / "calibration_v1_ferraris.json"
# the effects no method models: left out so that the g-sensitivity shows (as in test_joint.py)
UNMODELLED = ["temperature_drift", "motion_contamination", "scale_nonlinearity",
              "gyro_bias_random_walk", "earth_rate", "gyro_bias_drift", "lowpass_filter",
              "time_offset", "quantization"]


def plain(cal: Calibration) -> str:
    """Everything a result holds, as canonical JSON text (NaN-safe equality)."""
    return json.dumps(cal.to_dict(), sort_keys=True)


@pytest.fixture(scope="module")
def ferraris_with_compass():
    cal, _ = calibrate_log(read_log(ROOT / "logs" / "ferraris.tlog"), SITE)
    return cal


# ------------------------------------------------------------------------------------ JSON
def test_save_load_round_trip_keeps_every_field(ferraris_with_compass, tmp_path):
    cal = ferraris_with_compass
    assert cal.report.six_face is not None and "mag" in cal.report.ellipsoids
    assert np.any(cal.sensors["gyr"].g_sensitivity)
    cal.save(tmp_path / "c.json")
    d = json.loads((tmp_path / "c.json").read_text())
    assert d["schema"] == SCHEMA == "apmcal.calibration/2"
    assert d["units"]["acc"] == "m/s²" and d["units"]["g_sensitivity"] == "rad/s per m/s²"
    back = Calibration.load(tmp_path / "c.json")
    assert plain(back) == plain(cal)
    assert back.report.six_face.misfit.birge_ratio == cal.report.six_face.misfit.birge_ratio
    assert back.report.ellipsoids["mag"].held_out == cal.report.ellipsoids["mag"].held_out
    np.testing.assert_array_equal(back.sensors["gyr"].g_sensitivity,
                                  cal.sensors["gyr"].g_sensitivity)
    assert calibration_lines(back.report, back.sensors) == calibration_lines(cal.report,
                                                                             cal.sensors)


def test_round_trip_of_the_one_position_and_ellipsoid_reports(tmp_path):
    cal, _ = calibrate_log(read_log(ROOT / "logs" / "onepos.tlog"))
    assert cal.report.one_position is not None and cal.report.holds.used["level"].samples > 0
    cal.save(tmp_path / "s.json")
    assert plain(Calibration.load(tmp_path / "s.json")) == plain(cal)


def test_extra_fields_are_written_but_never_overwrite(ferraris_with_compass, tmp_path):
    cal = ferraris_with_compass
    cal.save(tmp_path / "e.json", extra={"verdict": {"overall": "good"}})
    assert json.loads((tmp_path / "e.json").read_text())["verdict"] == {"overall": "good"}
    assert plain(Calibration.load(tmp_path / "e.json")) == plain(cal)
    with pytest.raises(ValueError, match="report"):
        cal.save(tmp_path / "x.json", extra={"report": {}})


def test_an_unknown_schema_is_refused_in_one_line(tmp_path):
    path = tmp_path / "future.json"
    path.write_text(json.dumps({"schema": "apmcal.calibration/9", "method": "ferraris"}))
    with pytest.raises(ApmcalError) as err:
        Calibration.load(path)
    text = str(err.value)
    assert "\n" not in text and str(path) in text
    assert "unknown calibration schema 'apmcal.calibration/9'" in text


def test_not_a_calibration_file_is_one_line(tmp_path):
    (tmp_path / "bad.json").write_text("[1, 2")
    with pytest.raises(ApmcalError, match="not a calibration file"):
        Calibration.load(tmp_path / "bad.json")


def test_a_version_1_file_still_loads():
    """A file written by apmcal before the schema (`apmcal log logs/ferraris.tlog --lat 5.6037
    --lon -0.187 --json`, commit 95428ec): sensors, params and what its report said that the
    verdict needs; its gyro g-sensitivity becomes part of the applied model."""
    old = json.loads(V1_FILE.read_text())
    assert "schema" not in old
    cal = Calibration.load(V1_FILE)
    assert cal.method == "ferraris" and cal.params == old["params"]
    for name in ("acc", "gyr", "mag"):
        np.testing.assert_array_equal(cal.sensors[name].offset, old[name]["offset"])
        np.testing.assert_array_equal(cal.sensors[name].matrix, old[name]["matrix"])
    np.testing.assert_array_equal(cal.sensors["gyr"].drift, old["gyr"]["drift"])
    np.testing.assert_array_equal(cal.sensors["gyr"].g_sensitivity,
                                  old["report"]["gyr_g_sensitivity"])
    assert cal.report.recording == old["report"]["recording"]
    assert cal.report.warnings == old["report"]["warnings"]
    assert set(cal.report.rotations) == set(old["report"]["rotations"])
    assert cal.report.magnetic_field.mgauss == old["report"]["mag_field_mgauss"]
    # the verdict on the loaded file is the one the old version wrote
    assert {k: v.grade for k, v in judge(cal).items()} == {
        k: v["grade"] for k, v in old["verdict"].items()}


# ------------------------------------------------------------------------------------ apply
def test_apply_on_a_recording_and_a_dataframe(ferraris_with_compass):
    cal = ferraris_with_compass
    _, rec, _ = session_recording(3, mag=True)
    t, before = rec.t, rec.data.copy()
    out = cal.apply(rec)
    assert isinstance(out, Recording) and out.message == rec.message
    acc = cal.apply("acc", rec.xyz("acc"))
    np.testing.assert_allclose(out.xyz("acc"), acc)
    np.testing.assert_allclose(out.xyz("gyr"),
                               cal.sensors["gyr"].apply(rec.xyz("gyr"), t, force=acc))
    np.testing.assert_allclose(out.xyz("gyr"), cal.apply("gyr", rec.xyz("gyr"), t,
                                                         acc=rec.xyz("acc")))
    np.testing.assert_allclose(out.xyz("mag"), cal.apply("mag", rec.xyz("mag")))
    pd.testing.assert_frame_equal(rec.data, before)          # a copy: the input is kept
    table = cal.apply(rec.data)
    assert isinstance(table, pd.DataFrame)
    pd.testing.assert_frame_equal(table, out.data)


def test_apply_refuses_firmware_corrected_samples(ferraris_with_compass):
    _, rec, _ = session_recording(3)
    with pytest.raises(ValueError, match="raw sensor-frame"):
        ferraris_with_compass.apply(replace(rec, corrected=True))


def test_g_sensitivity_needs_the_specific_force_and_inverts_exactly():
    rng = np.random.default_rng(4)
    gyr = SensorCalibration(offset=rng.normal(size=3) * 0.02,
                            matrix=np.eye(3) + 0.01 * rng.normal(size=(3, 3)),
                            drift=[1e-5, -2e-5, 3e-5], t_ref=12.0,
                            g_sensitivity=1.8e-4 * rng.normal(size=(3, 3)))
    t = np.linspace(0, 60, 500)
    raw = rng.normal(size=(500, 3))
    force = rng.normal(size=(500, 3)) * 9.8
    w = gyr.apply(raw, t, force=force)
    np.testing.assert_allclose(gyr.invert(w, t, force=force), raw, atol=1e-12)
    without = replace(gyr, g_sensitivity=np.zeros((3, 3)))
    np.testing.assert_allclose(w, without.apply(raw - force @ gyr.g_sensitivity.T, t),
                               atol=1e-12)
    with pytest.raises(ValueError, match="g-sensitivity"):
        gyr.apply(raw, t)
    back = SensorCalibration.from_dict(json.loads(json.dumps(gyr.to_dict())))
    np.testing.assert_array_equal(back.g_sensitivity, gyr.g_sensitivity)


def test_sitl_truth_is_the_exact_inverse_of_the_simulated_gyro():
    """sitl's gyro ω_s = F·ω + b + drift·t + G·f (board frame) is what the truth's
    SensorCalibration inverts: its invert gives the simulated samples, its apply the rate."""
    linear = ["gyro_bias", "gyro_bias_drift", "gyro_scale", "gyro_misalignment", "g_sensitivity"]
    truth, rec, v = session_recording(5, disable=["all"], enable=linear)
    s = v._sense(rec.t)
    true_gyr = truth.sensor_calibrations()["gyr"]
    assert np.any(true_gyr.g_sensitivity) and np.any(true_gyr.drift)
    w, f = s["w_body"] @ v.board_rot, s["f_body"] @ v.board_rot
    np.testing.assert_allclose(true_gyr.invert(w, rec.t, force=f), rec.xyz("gyr"), atol=1e-12)
    np.testing.assert_allclose(true_gyr.apply(rec.xyz("gyr"), rec.t, force=f), w, atol=1e-12)


@pytest.mark.parametrize("method, script", [("ferraris", "ferraris"), ("joint", "handheld")])
def test_the_estimated_g_sensitivity_recovers_the_true_rate(method, script):
    """sitl injects ω_s = F·ω + b + G·f; the calibrated gyro with the estimated G is nearer the
    true rate, at rest, than the same calibration without G (hold-mean RMS error, measured:
    ferraris 1.1e-5 vs 1.4e-3 rad/s, joint 2.9e-5 vs 1.5e-3 rad/s)."""
    truth, rec, v = session_recording(7, disable=UNMODELLED, enable=["g_sensitivity"],
                                      script=script, mag=method == "joint")
    cal = calibrate(rec, replace(SITE, method=method))
    assert np.any(cal.sensors["gyr"].g_sensitivity)
    s = v._sense(rec.t)
    still = np.flatnonzero(np.linalg.norm(s["rate"], axis=1) == 0)
    holds = np.split(still, np.flatnonzero(np.diff(still) > 1) + 1)    # contiguous still runs
    true_rate = s["w_body"] @ v.board_rot
    with_g = cal.apply(rec).xyz("gyr")
    cal.sensors["gyr"] = replace(cal.sensors["gyr"], g_sensitivity=np.zeros((3, 3)))
    without_g = cal.apply(rec).xyz("gyr")

    def rms(w):
        """RMS over the holds of each hold's mean error (the noise averaged out) [rad/s]."""
        return float(np.sqrt(np.mean([(w[h] - true_rate[h]).mean(axis=0) ** 2 for h in holds])))

    assert len(holds) >= 6
    assert rms(with_g) < 0.1 * rms(without_g)
