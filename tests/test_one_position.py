"""[Oppong] §5 one-position static method (apmcal/solvers/one_position.py)."""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.core.constants import EARTH_RATE, STANDARD_GRAVITY, earth_rate_ned
from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.highpass import highpass
from apmcal.report.lines import calibration_lines
from apmcal.solvers.one_position import c_ecef_to_ned, one_position_calibration
from apmcal.solvers.result import Calibration

G = STANDARD_GRAVITY
KUMASI_LAT = 6.6885      # [Oppong]'s site (KNUST, Kumasi); Table 2's τ = 8.5258 ≈ cot(lat)
FS = 50.0


def lines(cal) -> list[str]:
    """The report's lines on ``cal`` (words made from the solver's numbers)."""
    return calibration_lines(cal.report, cal.sensors)


def still(n=3000, acc_bias=(0.1, -0.2, 0.3), gyr_bias=(2e-3, -1e-3, 5e-4), lat=KUMASI_LAT,
          acc_noise=0.05, gyr_noise=0.0, seed=0):
    """Level, still, x north: acc = (0, 0, −g) + bias (ArduPilot sign), gyr = Earth rate + bias."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    acc = np.array([0.0, 0.0, -G]) + acc_bias + rng.normal(scale=acc_noise, size=(n, 3))
    gyr = earth_rate_ned(lat) + gyr_bias + rng.normal(scale=gyr_noise, size=(n, 3))
    return t, acc, gyr


def test_dcm_maps_earth_rate_to_ned_for_any_longitude():
    for lon in (-1.6, 45.0, 170.0):
        w = c_ecef_to_ned(KUMASI_LAT, lon) @ np.array([0, 0, EARTH_RATE])
        np.testing.assert_allclose(w, earth_rate_ned(KUMASI_LAT), atol=1e-18)
        C = c_ecef_to_ned(KUMASI_LAT, lon)
        np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-12)


def test_accelerometer_steps_worked_by_hand():
    t, acc, gyr = still()
    cal = one_position_calibration(t, acc, gyr, lat_deg=KUMASI_LAT, lon_deg=-1.57)
    # the paper's steps recomputed here, independently of the module
    m = acc.mean(axis=0)                                      # step 1
    acc2 = acc - [0, 0, -np.linalg.norm(m)]                   # step 2 (ArduPilot z ≈ −g)
    R = acc2.mean(axis=0)                                     # step 3
    Rf = highpass(acc2, FS, 0.5).mean(axis=0)                 # steps 4-5
    b = R - Rf                                                # step 6
    np.testing.assert_allclose(cal.sensors["acc"].offset, b, rtol=0, atol=1e-9)   # float rounding
    g = np.linalg.norm(m)                                     # step 7
    beta, gamma, mu = (m - b) / -g                            # step 9, a_p = (0, 0, −g)
    F = np.array([[1, 0, beta], [0, 1, gamma], [0, 0, mu]])
    np.testing.assert_allclose(cal.sensors["acc"].matrix, np.linalg.inv(F), rtol=0, atol=1e-9)
    # degeneracies stated in the report: x/y bias = mean, z bias ≈ 0, F ≈ I — up to the
    # high-pass mean R_f of the noise (≈ 1e-4 m/s² for 0.05 m/s² noise over a minute)
    assert np.all(np.abs(Rf) < 1e-3)
    np.testing.assert_allclose(b[:2], m[:2], atol=1e-3)
    assert abs(b[2] - (m[0] ** 2 + m[1] ** 2) / (2 * g)) < 1e-3     # NOT the true 0.3 m/s²
    assert abs(mu - 1) < 1e-4 and abs(beta) < 1e-4 and abs(gamma) < 1e-4
    # Table 4's "proposed" matrix in the paper's sign convention: ≈ −I
    np.testing.assert_allclose(cal.report.one_position.acc.F_paper_convention, -np.eye(3), atol=1e-4)
    assert abs(cal.report.one_position.acc.mu_literal) < 1e-3                # literal reading: singular
    # the calibrated still record reads (0, 0, −‖mean‖): true by construction, not a check of truth
    np.testing.assert_allclose(cal.apply("acc", m[None])[0], [0, 0, -g], atol=1e-3)


def test_gyro_reproduces_table_2_tau_from_latitude_alone():
    t, acc, gyr = still(gyr_noise=0.0)
    cal = one_position_calibration(t, acc, gyr, lat_deg=KUMASI_LAT, lon_deg=-1.57)
    tau, xi, nu = cal.report.one_position.gyr.tau_xi_nu
    assert tau == pytest.approx(8.5258, abs=0.01)             # [Oppong] Table 2, "proposed"
    assert abs(xi) < 1e-6 and abs(nu) < 1e-6                  # R_f = 0 for a constant signal
    # bias = mean = true bias + Earth rate (the method cannot tell them apart)
    np.testing.assert_allclose(cal.sensors["gyr"].offset,
                               np.array([2e-3, -1e-3, 5e-4]) + earth_rate_ned(KUMASI_LAT),
                               atol=1e-12)
    # E is the recipe's artefact (τ = cot φ, ν ≈ 0): reported, never applied
    np.testing.assert_allclose(cal.report.one_position.gyr.E[0, 2], tau)
    np.testing.assert_allclose(cal.sensors["gyr"].matrix, np.eye(3))
    assert any("gyro matrix left at identity" in line for line in lines(cal))


def test_gyro_offset_sigma_is_the_standard_error_of_the_mean():
    t, acc, gyr = still(gyr_noise=1e-3)
    cal = one_position_calibration(t, acc, gyr, lat_deg=KUMASI_LAT)
    expected = 1e-3 / np.sqrt(len(t))
    np.testing.assert_allclose(cal.sensors["gyr"].sigma["offset"], expected, rtol=0.1)
    assert "offset" not in cal.sensors["acc"].sigma      # tilt and bias inseparable: no sigma


def test_report_tells_what_one_pose_cannot_determine(tmp_path):
    t, acc, gyr = still(gyr_noise=1e-3)
    cal = one_position_calibration(t, acc, gyr, lat_deg=51.5)
    cal.save(tmp_path / "static.json")                       # report must be JSON-able
    assert lines(Calibration.load(tmp_path / "static.json")) == lines(cal)
    text = "\n".join(lines(cal))
    assert "acc: 1 pose(s), 9 parameters" in text and "rank 3 of 9" in text
    assert "b_x, F_xz cannot be separated" in text
    assert "gyr: F_zz not determinable at 0.001 rad/s resolution" in text
    assert cal.method == "static"


def test_tilted_platform_is_flagged():
    t, acc, gyr = still()
    c, s = np.cos(np.radians(8)), np.sin(np.radians(8))
    acc = acc @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T
    cal = one_position_calibration(t, acc, gyr)
    assert any("NOT LEVEL" in line for line in lines(cal))
    assert any("no latitude" in line for line in lines(cal))


@pytest.mark.parametrize("case", ["short", "shape", "nan", "equator"])
def test_bad_input_raises_apmcal_error(case):
    t, acc, gyr = still()
    kw = {}
    if case == "short":
        t, acc, gyr = t[:100], acc[:100], gyr[:100]
    elif case == "shape":
        gyr = gyr[:, :2]
    elif case == "nan":
        acc[5, 1] = np.nan
    else:
        kw["lat_deg"] = 0.0
    with pytest.raises(ApmcalError):
        one_position_calibration(t, acc, gyr, **kw)


def test_real_still_minute_from_dataflash(shared_data):
    from pymavlink import DFReader
    log = DFReader.DFReader_binary(str(shared_data / "ardupilot" / "pxf_copter_static_51.BIN"))
    rows = []
    while (m := log.recv_match(type="IMU")) is not None and len(rows) < 6000:
        rows.append((m.TimeMS / 1000.0, m.AccX, m.AccY, m.AccZ, m.GyrX, m.GyrY, m.GyrZ))
    a = np.array(rows)[2500:5500]                     # one minute inside the 600 s still stretch
    t, acc, gyr = a[:, 0], a[:, 1:4], a[:, 4:7]
    assert np.all(gyr.std(axis=0) < 0.01)             # still indeed (rad/s)
    cal = one_position_calibration(t, acc, gyr, lat_deg=40.4)
    m = acc.mean(axis=0)
    # the paper's bias on real data: the mean, minus the gravity reading on z
    np.testing.assert_allclose(cal.sensors["acc"].offset[:2], m[:2], atol=0.01)
    np.testing.assert_allclose(cal.sensors["gyr"].offset, gyr.mean(axis=0), atol=1e-4)
    assert cal.report.one_position.fs_hz == pytest.approx(50.0, rel=0.05)
    # |a| ≈ 8.4 m/s² here (uncalibrated accel): step 7 takes g := ‖mean‖ and hides it
    assert cal.report.one_position.acc.g == pytest.approx(np.linalg.norm(m))
    assert cal.report.one_position.acc.g < 9.0


def test_body_to_sensor_gives_the_same_calibrated_samples():
    from apmcal.ardupilot.orientation import rotation_matrix
    from apmcal.solvers.holds import body_to_sensor
    from apmcal.solvers.result import SensorCalibration

    rng = np.random.default_rng(3)
    body = SensorCalibration(offset=rng.normal(size=3), matrix=np.eye(3) + 0.01 * rng.normal(size=(3, 3)),
                             sigma={"offset": [1.0, 2.0, 3.0]})
    for code in (0, 8, 12, 16, 2, 43):
        R = rotation_matrix(code)
        sensor = body_to_sensor(body, R)
        m = rng.normal(size=(5, 3))
        np.testing.assert_allclose(R @ sensor.apply(m).T, body.apply(m @ R.T).T, atol=1e-12)
    R = rotation_matrix(2)                                    # yaw 90: body x is sensor -y
    np.testing.assert_allclose(body_to_sensor(body, R).sigma["offset"], [2.0, 1.0, 3.0])


def test_board_mounted_upside_down_on_a_level_vehicle_is_level():
    """AHRS_ORIENTATION = 8 (ROLL_180): a level vehicle's board reads z up. The one-position
    method must run in the vehicle's frame and return a sensor-frame result."""
    from apmcal.ardupilot.orientation import rotation_matrix
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.solvers.holds import one_position_on_holds

    t, acc_body, gyr_body = still(gyr_noise=1e-4)
    R = rotation_matrix(8)
    acc, gyr = acc_body @ R, gyr_body @ R                      # sensor = Rᵀ · body
    segments = find_static_segments(t, acc, gyr)
    with pytest.raises(ApmcalError, match="no level still period"):
        one_position_on_holds(t, acc, gyr, segments, KUMASI_LAT, None)
    cal = one_position_on_holds(t, acc, gyr, segments, KUMASI_LAT, None, board_rotation=R)
    ref = one_position_calibration(t, acc_body, gyr_body, lat_deg=KUMASI_LAT)
    np.testing.assert_allclose(cal.sensors["gyr"].offset, R.T @ ref.sensors["gyr"].offset,
                               rtol=1e-9, atol=1e-12)
