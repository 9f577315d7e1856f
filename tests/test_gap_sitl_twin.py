"""``--write-twin FILE.parm``: the twin as ArduPilot SITL parameters, checked on hand-worked values
and by running SITL's own sensor equations (docs/ardupilot-facts.md "ArduPilot SITL (its own
simulator) and its SIM_* parameters", written out here apart from the mapping) against the
twin's error model on the same inputs."""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.ardupilot.paramfile import read_param_file
from apmcal.diagnosis.twin.sitl_params import (
    REST_ACC_SIGMA,
    REST_GYR_SIGMA,
    sitl_parameters,
    write_sitl_params,
)
from apmcal.sensor_model.imu import ImuErrorModel
from apmcal.sensor_model.truth import NOMINAL_EFFECTS, Truth

SOFT = np.array([[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]])


def board() -> Truth:
    """A board with every mappable error on and the noise off (its own parameters)."""
    t = Truth().with_effects(disable=["all"], enable=[
        "acc_bias", "acc_scale", "gyro_bias", "gyro_scale", "temperature_drift",
        "triangle_drift", "mag_hard_iron", "mag_soft_iron", "mag_interference"])
    t.acc_bias, t.acc_scale = [0.1, -0.2, 0.3], [1.02, 0.98, 1.0]
    t.gyro_bias, t.gyro_scale = [0.01, -0.02, 0.005], [1.01, 1.0, 0.99]
    t.temperature = {"ambient_c": 30.0, "rise_k": 10.0, "tau_s": 200.0,
                     "acc_coef": [2e-3, -1e-3, 0.0], "gyro_coef": [1.7e-4, 0.0, -3e-4]}
    t.triangle_drift = {"speed_dps_per_min": 0.05, "time_min": 5.0}
    t.mag_hard_iron, t.mag_soft_iron = [10.0, -20.0, 30.0], SOFT.tolist()
    t.mag_interference = [20.0, 40.0, -60.0]        # per full throttle: [1, 2, −3] mGauss/A
    return t


def test_hand_worked_values():
    values, comments = sitl_parameters(board(), compass=True,
                                       sigma={"acc": np.full(3, 0.02), "gyr": np.full(3, 1e-3),
                                              "mag": np.full(3, 2.0)})
    assert values["SIM_ACC1_BIAS_Y"] == -0.2
    assert values["SIM_ACC1_SCAL_X"] == pytest.approx(1 / 1.02)     # SITL divides by it
    assert values["SIM_GYR1_SCALE_X"] == pytest.approx(1.0)         # percent
    assert values["SIM_GYR1_SCALE_Z"] == pytest.approx(-1.0)
    assert values["SIM_GYR1_BIAS_Y"] == -0.02                       # rad/s
    assert values["SIM_DRIFT_SPEED"] == 0.05 and values["SIM_DRIFT_TIME"] == 5.0
    assert (values["SIM_IMUT_START"], values["SIM_IMUT_END"], values["SIM_IMUT_TCONST"]) == \
        (30.0, 40.0, 200.0)
    assert values["SIM_IMUT1_ENABLE"] == 1
    assert 0.5 * (values["SIM_IMUT1_TMIN"] + values["SIM_IMUT1_TMAX"]) == 30.0   # tmid = ambient
    assert values["SIM_IMUT1_ACC1_X"] == pytest.approx(2000.0)      # 1e6 × 2e-3 m/s² per K
    assert values["SIM_IMUT1_GYR1_X"] == pytest.approx(170.0 / 1.01)   # before SITL's scale
    assert values["SIM_IMUT1_GYR2_X"] == 0 and values["SIM_IMUT1_ACC3_Z"] == 0
    m = np.linalg.inv(SOFT)
    assert values["SIM_MAG1_DIA_Y"] == pytest.approx(m[1, 1])
    assert values["SIM_MAG1_ODI_Z"] == pytest.approx(m[1, 2])
    assert values["SIM_MAG1_OFS_Z"] == -30.0                        # SITL subtracts it
    np.testing.assert_allclose([values[f"SIM_MAG_MOT_{a}"] for a in "XYZ"], m @ [1.0, 2.0, -3.0])
    assert values["SIM_MAG_RND"] == pytest.approx(2.0 * np.sqrt(3))   # uniform ±RND
    assert "INS_GYRO_FILTER" not in values                          # no filter selected
    assert any("acc white noise" in c and f"{REST_ACC_SIGMA:.3g}" in c for c in comments)
    assert any("gyr white noise" in c and f"{REST_GYR_SIGMA:.3g}" in c for c in comments)
    # SITL's rest noise, hand-worked: ±0.01 m/s² uniform; two uniform ±0.04 °/s draws
    assert REST_ACC_SIGMA == pytest.approx(0.01 / np.sqrt(3))
    assert REST_GYR_SIGMA == pytest.approx(np.radians(0.04) * np.sqrt(2 / 3))


def test_sitl_equations_on_the_parameters_give_the_twins_readings():
    truth = board()
    values, _ = sitl_parameters(truth, compass=True, sigma={})
    p = lambda name: np.array([values[f"{name}_{a}"] for a in "XYZ"])  # noqa: E731
    rng = np.random.default_rng(3)
    n = 50
    t = np.sort(rng.uniform(0, 1500, n))        # across turns of the triangle (10 min cycle)
    temp = rng.uniform(25, 45, n)
    f = rng.normal(0, 5, (n, 3))
    w = rng.normal(0, 0.5, (n, 3))
    b = rng.normal(0, 300, (n, 3))
    current = rng.uniform(0, 20, n)
    model = ImuErrorModel(truth, 100.0, 0)
    # SITL, AP_InertialSensor_SITL::generate_accel / generate_gyro, noise aside
    tmid = 0.5 * (values["SIM_IMUT1_TMIN"] + values["SIM_IMUT1_TMAX"])
    d = (temp - tmid)[:, None]
    acc = f / p("SIM_ACC1_SCAL") + p("SIM_ACC1_BIAS") + 1e-6 * p("SIM_IMUT1_ACC1") * d
    period = 2 * values["SIM_DRIFT_TIME"]
    minutes = np.fmod(t / 60, period)
    drift = np.where(minutes < period / 2, minutes, period - minutes) * \
        np.radians(values["SIM_DRIFT_SPEED"])
    gyr = (w + drift[:, None] + 1e-6 * p("SIM_IMUT1_GYR1") * d) * \
        (1 + 0.01 * p("SIM_GYR1_SCALE")) + p("SIM_GYR1_BIAS")
    np.testing.assert_allclose(acc, model.accel(t, f, temperature=temp), atol=1e-12)
    # the one residual: SITL scales its triangle drift by 1 + SIM_GYR1_SCALE/100 per axis, the
    # twin does not, and SIM_DRIFT_SPEED is one value for all axes (docs/sitl-twin.md)
    twin = model.gyro(t, w, f, temperature=temp)
    np.testing.assert_allclose(gyr - twin, drift[:, None] * 0.01 * p("SIM_GYR1_SCALE"),
                               atol=1e-12)
    # AP_Compass_SITL / SIM_Compass: M⁻¹·(B + SIM_MAG_MOT·I) − SIM_MAG1_OFS
    dia, odi = p("SIM_MAG1_DIA"), p("SIM_MAG1_ODI")
    m_sim = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]],
                      [odi[1], odi[2], dia[2]]])
    mag = (b + np.outer(current, p("SIM_MAG_MOT"))) @ np.linalg.inv(m_sim).T - p("SIM_MAG1_OFS")
    np.testing.assert_allclose(mag, model.mag(b, current / 20.0), atol=1e-9)


def test_unmappable_effects_are_said_and_absent_ones_switched_off(tmp_path):
    t = Truth.random(4).with_effects(disable=["all"], enable=list(NOMINAL_EFFECTS) + [
        "bias_random_walk", "g_sensitivity", "cross_axis", "lowpass_filter"], prefer="diagnosis")
    path = tmp_path / "twin.parm"
    write_sitl_params(path, t, compass=False, sigma={}, source="x.bin",
                      selected=["bias_random_walk", "g_sensitivity", "cross_axis",
                                "lowpass_filter"])
    values = read_param_file(path)
    text = path.read_text()
    assert values["SIM_DRIFT_SPEED"] == 0           # ArduPilot's default 0.05 is a drift
    assert values["SIM_IMUT1_ENABLE"] == 0
    assert values["INS_GYRO_FILTER"] == values["INS_ACCEL_FILTER"] == 20.0
    assert not any(name.startswith("SIM_MAG") for name in values)
    unmapped = [line for line in text.splitlines() if line.startswith("# not mapped: ")]
    for what in ("random walk", "g-sensitivity", "cross-axis"):
        assert any(what in line for line in unmapped), what
