"""The verdict (apmcal/verdict.py) and the honesty of the σ it is built on, on sitl sessions.

Sessions are made in one pass of sitl's error model at 50 Hz (sitl_helpers.session_recording,
about 0.3 s each) and calibrated as `apmcal log` does.
"""
import numpy as np
import pytest
from sitl_helpers import session_recording, sigma_z

from apmcal.calibration.log import Options, calibrate
from apmcal.report.verdict import compass, judge
from apmcal.solvers.report_types import CalibrationReport, MagneticField
from apmcal.solvers.result import Calibration, SensorCalibration

LAT = 5.6037
# clean: the errors ArduPilot's parameters hold, noise, and the physics apmcal models
CLEAN = (["all"], ["nominal", "local_gravity", "earth_rate"])


def calibrated(seed, disable=(), enable=(), method="ferraris", **kw):
    truth, rec, vehicle = session_recording(seed, disable, enable, **kw)
    return truth, calibrate(rec, Options(method=method, lat_deg=LAT)), vehicle


def test_clean_session_is_good():
    _, cal, _ = calibrated(1, *CLEAN)
    v = judge(cal)
    assert {k: x.grade for k, x in v.items()} == {"acc": "good", "gyr": "good",
                                                   "overall": "good"}, v


def test_every_effect_on_is_usable_because_the_model_does_not_fit():
    _, cal, _ = calibrated(1)
    v = judge(cal)
    assert v["acc"].grade == "usable" and "the model does not fit" in v["acc"].reason
    assert "warm up" in v["acc"].next_step and v["overall"].grade == "usable"


def test_one_pose_does_not_measure_the_accelerometer_and_grades_what_it_measured():
    """One still pose cannot tell the accelerometer's offset from a tilt: "not measured by this
    session" with the session that would (six faces), and the overall grade is the gyro's."""
    _, cal, _ = calibrated(2, *CLEAN, method="static", script="onepos")
    v = judge(cal)
    assert v["acc"].grade == "not measured" and "six faces" in v["acc"].next_step
    assert not v["acc"].measured
    assert v["overall"].grade == v["gyr"].grade == "good"


def test_compass_not_turned_is_not_measured():
    _, cal, _ = calibrated(2, *CLEAN, method="static", script="onepos", mag=True)
    assert "mag" not in cal.sensors                   # refused: samples do not turn
    v = judge(cal)
    assert v["mag"].grade == "not measured" and "turn the vehicle" in v["mag"].next_step
    assert v["overall"].grade == "good"


def test_a_compass_the_session_did_not_measure_does_not_grade_the_session():
    """A compass not measured (too few directions) is "not measured" on its own line, with what
    to do; the overall grade is the accelerometer's. A compass that failed otherwise counts."""
    acc = SensorCalibration(sigma={"offset": [0.01] * 3, "matrix": np.full((3, 3), 1e-3)})
    why = "compass not measured by this session: ...: turn the vehicle slowly through every"
    cal = Calibration("ferraris", {"acc": acc})
    cal.report.not_calibrated["mag"] = why
    cal.report.not_measured.append("mag")
    v = judge(cal)
    assert v["mag"].grade == "not measured" and "turn the vehicle" in v["mag"].reason
    assert v["overall"].grade == "good" and v["overall"].reason.startswith("accelerometer")
    cal.report.not_measured.clear()           # a failure of the data: it counts
    assert judge(cal)["overall"].grade == "redo"


def test_gyro_offset_beyond_physics_is_redo_whatever_its_sigma():
    """49 °/s read at rest is no gyro bias (turning, a faulty gyro, or deg/s): redo, even with
    a σ of zero."""
    cal = Calibration("static", {"gyr": SensorCalibration(offset=np.radians([49.0, 0, 0]),
                                                          sigma={"offset": [0.0] * 3})})
    v = judge(cal)
    assert v["gyr"].grade == "redo" and "49 °/s" in v["gyr"].reason, v
    ok = Calibration("static", {"gyr": SensorCalibration(offset=[0.01, 0, 0],
                                                         sigma={"offset": [0.0] * 3})})
    assert "±0.0000" not in judge(ok)["gyr"].reason


def test_nothing_measured_is_said_so():
    from apmcal.report.verdict import not_measured, overall

    v = overall({"acc": not_measured("one pose", "six faces")})
    assert v.grade == "not measured" and v.next_step == "six faces"


@pytest.mark.parametrize("cover, grade", [({"min_eig": 0.02, "fraction": 0.4}, "not measured"),
                                          ({"min_eig": 0.2, "fraction": 0.3}, "usable"),
                                          ({"min_eig": 0.6, "fraction": 0.9}, "good")])
def test_compass_coverage_rules(cover, grade):
    cal = SensorCalibration(sigma={"offset": [0.5] * 3})
    field = MagneticField(400.0, "WMM", cover["fraction"], cover["min_eig"])
    v = compass(cal, CalibrationReport(magnetic_field=field))
    assert v.grade == grade, v


def test_firmware_refusal_is_redo():
    from apmcal.ardupilot.params import ParamProposal

    cal = Calibration("ferraris", {"acc": SensorCalibration(
        sigma={"offset": [0.01] * 3, "matrix": np.full((3, 3), 1e-3)})})
    refused = ParamProposal(rejected={"INS_ACCOFFS_X": "|offset| 4 > 3.5 m/s²"})
    assert judge(cal)["acc"].grade == "good"
    assert judge(cal, refused)["acc"].grade == "redo"


# ------------------------------------------------------------------------------- honest σ
SEEDS = range(1, 7)


@pytest.fixture(scope="module")
def every_effect():
    return [calibrated(seed) for seed in SEEDS]


def test_sigma_covers_the_truth_with_every_effect_on(every_effect):
    """|error| < 3σ for ≥ 90 % of accelerometer and gyro offsets and matrix entries."""
    z = np.concatenate([np.abs(np.concatenate(list(sigma_z(t, c, v).values())))
                        for t, c, v in every_effect])
    assert np.mean(z < 3) >= 0.9, np.mean(z < 3)
    acc = np.concatenate([np.abs(sigma_z(t, c, v)["acc.offset"]) for t, c, v in every_effect])
    assert np.mean(acc < 3) >= 0.9, acc


def test_the_coverage_check_can_fail(every_effect):
    """With the noise-only σ (what was reported before the misfit) the accelerometer offsets
    miss the truth by far more than 3σ: the test above has teeth."""
    z = []
    for truth, cal, _ in every_effect:
        err = cal.sensors["acc"].offset - truth.sensor_calibrations()["acc"].offset
        z.extend(np.abs(err) / cal.report.six_face.sigma_noise_only["offset"])
    assert np.mean(np.array(z) < 3) < 0.2 and np.median(z) > 10


def test_sigma_not_inflated_on_a_clean_session():
    for seed in (1, 2, 3):
        truth, cal, vehicle = calibrated(seed, *CLEAN)
        acc = cal.sensors["acc"].sigma
        noise_only = cal.report.six_face.sigma_noise_only
        assert np.allclose(acc["offset"], noise_only["offset"])
        assert np.allclose(acc["matrix"], noise_only["matrix"])
        assert cal.report.six_face.misfit.birge_ratio < 1.5
        z = np.abs(np.concatenate(list(sigma_z(truth, cal, vehicle).values())))
        assert np.mean(z < 3) >= 0.9


def test_chi2_survival_in_closed_form_matches_scipy():
    """The misfit's χ² test avoids loading scipy.stats; its closed form must agree with it."""
    from scipy.stats import chi2

    from apmcal.solvers.misfit import chi2_survival

    for dof in range(1, 60):
        for x in (0.0, 1e-6, 0.5, 3.0, 9.0, 30.0, 80.0, 200.0):
            assert chi2_survival(x, dof) == pytest.approx(chi2.sf(x, dof), rel=1e-10, abs=1e-300)
