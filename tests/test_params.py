"""Calibration → ArduPilot parameters (apmcal.ardupilot.params) and parameter files (.paramfile).

Truth: hand-worked algebra, the firmware formulas applied by apmcal.ardupilot.firmware
(itself tested against hand-worked examples), brute-force sampling of the sphere for the cost
figures, and pymavlink's own parameter-file loader (MAVProxy's) for the file format.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from apmcal.ardupilot import firmware as fw
from apmcal.ardupilot.orientation import rotation_matrix
from apmcal.ardupilot.paramfile import format_value, read_param_file, write_param_file
from apmcal.ardupilot.params import ParamProposal, cost_of_diagonal_only, to_ardupilot_params
from apmcal.core.constants import STANDARD_GRAVITY as G
from apmcal.core.errors import ApmcalError
from apmcal.solvers.result import Calibration, SensorCalibration

RIGHT_ANGLE_ROTATIONS = [0, 2, 4, 8, 12, 16, 20, 24, 25, 28, 33, 37]


def _cal(acc=None, gyr=None, mag=None) -> Calibration:
    sensors = {k: v for k, v in (("acc", acc), ("gyr", gyr), ("mag", mag)) if v is not None}
    return Calibration(method="test", sensors=sensors)


def _unit_vectors(n, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- cost
def test_cost_hand_worked():
    # A = I + 0.01·e_x e_yᵀ: diag(A) = I, so the error matrix is A⁻¹ − I, whose only non-zero
    # entry is −0.01 → largest singular value 0.01 → 0.01·g over the sphere.
    a = np.eye(3)
    a[0, 1] = 0.01
    assert cost_of_diagonal_only(a, G) == pytest.approx(0.01 * G, rel=1e-12)
    assert cost_of_diagonal_only(np.diag([1.1, 0.9, 1.0]), G) == 0.0


def test_cost_is_the_worst_case_over_the_sphere():
    rng = np.random.default_rng(3)
    a = np.eye(3) + rng.normal(0, 0.02, (3, 3))
    cost = cost_of_diagonal_only(a, G)
    v = G * _unit_vectors(200_000)
    err = np.linalg.norm(v @ (np.diag(np.diag(a)) @ np.linalg.inv(a) - np.eye(3)).T, axis=1)
    assert err.max() <= cost * (1 + 1e-12)
    assert err.max() == pytest.approx(cost, rel=2e-3)


# ----------------------------------------------------------------------------- accelerometer
def test_acc_hand_worked_33():
    cal = _cal(acc=SensorCalibration(offset=[0.1, -0.2, 0.3], matrix=np.diag([1.02, 0.98, 1.0])))
    prop = to_ardupilot_params(cal, "3.3+", current_params={"AHRS_ORIENTATION": 2})
    expected = {"INS_ACCOFFS_X": 0.1, "INS_ACCOFFS_Y": -0.2, "INS_ACCOFFS_Z": 0.3,
                "INS_ACCSCAL_X": 1.02, "INS_ACCSCAL_Y": 0.98, "INS_ACCSCAL_Z": 1.0}
    for name, value in expected.items():
        assert prop.values[name] == float(np.float32(value)), name
    assert isinstance(prop, ParamProposal) and prop.generation == "3.3+" and not prop.rejected


def test_acc_hand_worked_32():
    # YAW_90: body x = −sensor y, body y = sensor x. B = R A Rᵀ = diag(0.98, 1.02, 1.0);
    # o_b = R o = (0.2, 0.1, 0.3); OFFS = SCAL ⊙ o_b = (0.196, 0.102, 0.3)
    cal = _cal(acc=SensorCalibration(offset=[0.1, -0.2, 0.3], matrix=np.diag([1.02, 0.98, 1.0])))
    prop = to_ardupilot_params(cal, "3.2", current_params={"AHRS_ORIENTATION": 2})
    expected = {"INS_ACCOFFS_X": 0.196, "INS_ACCOFFS_Y": 0.102, "INS_ACCOFFS_Z": 0.3,
                "INS_ACCSCAL_X": 0.98, "INS_ACCSCAL_Y": 1.02, "INS_ACCSCAL_Z": 1.0}
    for name, value in expected.items():
        assert prop.values[name] == pytest.approx(value, abs=1e-7), name


@pytest.mark.parametrize("generation", fw.GENERATIONS)
@pytest.mark.parametrize("orientation", RIGHT_ANGLE_ROTATIONS)
def test_firmware_applies_per_axis_calibration_exactly(generation, orientation):
    """Per-axis truth: the firmware, fed the proposal, outputs R·A·(raw − o) (float32 precision)."""
    rng = np.random.default_rng(orientation)
    acc = SensorCalibration(offset=rng.uniform(-0.5, 0.5, 3), matrix=np.diag(rng.uniform(0.95, 1.05, 3)))
    gyr = SensorCalibration(offset=rng.uniform(-0.05, 0.05, 3))
    params = {"AHRS_ORIENTATION": float(orientation)}
    prop = to_ardupilot_params(_cal(acc, gyr), generation, current_params=params)
    assert not prop.rejected
    applied = params | prop.values
    r = rotation_matrix(orientation)
    raw = rng.normal(0, G, (100, 3))
    np.testing.assert_allclose(fw.correct_acc(raw, applied, generation), acc.apply(raw) @ r.T,
                               atol=2e-5 * G)
    np.testing.assert_allclose(fw.correct_gyr(raw, applied, generation), gyr.apply(raw) @ r.T,
                               atol=1e-6 * G)


@pytest.mark.parametrize("generation, orientation", [("3.3+", 0), ("3.3+", 1), ("3.2", 1),
                                                     ("3.2", 2), ("3.2", 38)])
def test_cross_axis_error_stays_within_reported_cost(generation, orientation):
    rng = np.random.default_rng(11)
    acc = SensorCalibration(offset=rng.uniform(-0.5, 0.5, 3),
                            matrix=np.eye(3) + rng.normal(0, 0.01, (3, 3)))
    params = {"AHRS_ORIENTATION": float(orientation)}
    prop = to_ardupilot_params(_cal(acc), generation, current_params=params)
    cost = prop.costs["acc_diagonal_only_ms2"]
    assert 0 < cost < 1.0
    # raw samples whose true calibrated value has magnitude g, all directions
    raw = acc.invert(G * _unit_vectors(20_000, seed=5))
    err = np.linalg.norm(fw.correct_acc(raw, params | prop.values, generation)
                         - acc.apply(raw) @ rotation_matrix(orientation).T, axis=1)
    assert err.max() <= cost + 1e-4          # float32 rounding of the parameters
    assert err.max() > 0.9 * cost            # and the bound is not loose
    assert any("m/s²" in n for n in prop.notes)


# ----------------------------------------------------------------------------- compass
@pytest.mark.parametrize("orientation", [0, 2, 16, 38])
def test_compass_33_reproduces_symmetric_matrix(orientation):
    rng = np.random.default_rng(orientation + 1)
    s = np.eye(3) + rng.normal(0, 0.03, (3, 3))
    mag = SensorCalibration(offset=rng.uniform(-200, 200, 3), matrix=(s + s.T) / 2)
    params = {"AHRS_ORIENTATION": float(orientation), "COMPASS_EXTERNAL": 0.0,
              "COMPASS_ORIENT": 0.0}
    params |= {n: 0.0 for key in ("ofs", "dia", "odi") for n in fw.mag_param_names(0)[key]}
    prop = to_ardupilot_params(_cal(mag=mag), "3.3+", current_params=params)
    assert not prop.rejected
    raw = rng.normal(0, 400, (100, 3))
    r = rotation_matrix(orientation)
    np.testing.assert_allclose(fw.correct_mag(raw, params | prop.values, "3.3+"),
                               mag.apply(raw) @ r.T, atol=1e-3)
    assert prop.costs["mag_rotation_dropped_deg"] < 1e-6


def test_compass_33_non_symmetric_keeps_magnitudes_and_reports_rotation():
    rot = rotation_matrix(0) @ np.array([[math.cos(0.05), -math.sin(0.05), 0],
                                         [math.sin(0.05), math.cos(0.05), 0], [0, 0, 1]])
    p = np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.0]])
    mag = SensorCalibration(offset=[50.0, -30.0, 120.0], matrix=rot @ p)
    prop = to_ardupilot_params(_cal(mag=mag), "3.3+", current_params=None)
    assert prop.costs["mag_rotation_dropped_deg"] == pytest.approx(math.degrees(0.05), rel=1e-6)
    raw = mag.invert(500 * _unit_vectors(1000))
    out = fw.correct_mag(raw, {"AHRS_ORIENTATION": 0} | prop.values, "3.3+")
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 500.0, rtol=1e-5)


def test_compass_32_offsets_only_and_sign():
    mag = SensorCalibration(offset=[120.0, -80.0, 40.0], matrix=np.diag([1.1, 1.0, 0.9]))
    prop = to_ardupilot_params(_cal(mag=mag), "3.2", current_params={"AHRS_ORIENTATION": 0})
    # the firmware ADDS COMPASS_OFS, so it is minus the offset
    assert [prop.values[f"COMPASS_OFS_{a}"] for a in "XYZ"] == [-120.0, 80.0, -40.0]
    assert not any("DIA" in n or "ODI" in n for n in prop.values)
    # dropping diag(1.1, 1.0, 0.9): a true field of 500 mGauss along z reads 500/0.9 uncorrected,
    # 55.6 mGauss too much (along x only 500 − 500/1.1 = 45.5 too little): the worst is z
    assert prop.costs["mag_matrix_dropped_mgauss"] == pytest.approx(500 / 0.9 - 500, rel=1e-9)


def test_compass_firmware_without_dia_gets_offsets_only():
    mag = SensorCalibration(offset=[10.0, 20.0, 30.0], matrix=np.diag([1.1, 1.0, 0.9]))
    current = {"AHRS_ORIENTATION": 0, "COMPASS_OFS_X": 0, "COMPASS_OFS_Y": 0, "COMPASS_OFS_Z": 0}
    prop = to_ardupilot_params(_cal(mag=mag), "3.3+", current_params=current)
    assert set(prop.values) == {"COMPASS_OFS_X", "COMPASS_OFS_Y", "COMPASS_OFS_Z"}
    assert any("no COMPASS_DIA/ODI" in n for n in prop.notes)


# ----------------------------------------------------------------------------- rejections
def _acc(offset=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    return SensorCalibration(offset=offset, matrix=np.diag(scale))


@pytest.mark.parametrize("generation, acc, name, reason", [
    ("3.3+", _acc(offset=(4.0, 0, 0)), "INS_ACCOFFS_X", "> 3.5"),
    ("3.3+", _acc(scale=(1, 1.25, 1)), "INS_ACCSCAL_Y", "outside 0.8..1.2"),
    ("3.2", _acc(scale=(1, 1, 0.85)), "INS_ACCSCAL_Z", "3.2 limit"),
    ("3.3+", _acc(offset=(0, float("nan"), 0)), "INS_ACCOFFS_Y", "not finite"),
])
def test_acc_rejections_withhold_the_whole_sensor(generation, acc, name, reason):
    cal = _cal(acc=acc, gyr=SensorCalibration(offset=[0.01, 0.0, 0.0]))
    prop = to_ardupilot_params(cal, generation, current_params={"AHRS_ORIENTATION": 0})
    assert reason in prop.rejected[name]
    assert not any(n.startswith("INS_ACC") for n in prop.values)     # no half calibration
    assert "withheld" in prop.rejected["INS_ACCSCAL_X" if name != "INS_ACCSCAL_X" else "INS_ACCOFFS_X"]
    assert prop.values["INS_GYROFFS_X"] == pytest.approx(0.01)     # other sensors unaffected


def test_scale_allowed_on_33_but_not_32():
    cal = _cal(acc=_acc(scale=(1.15, 1, 1)))
    assert not to_ardupilot_params(cal, "3.3+").rejected
    assert "INS_ACCSCAL_X" in to_ardupilot_params(cal, "3.2").rejected


@pytest.mark.parametrize("generation, current, ok", [
    ("3.2", {"AHRS_ORIENTATION": 0}, False),                    # 3.2 limit 400
    ("3.3+", None, True),                                       # default COMPASS_OFFS_MAX 1800
    ("3.3+", {"AHRS_ORIENTATION": 0, "COMPASS_OFFS_MAX": 450.0}, False),
])
def test_compass_offset_limits(generation, current, ok):
    cal = _cal(mag=SensorCalibration(offset=[-500.0, 0.0, 0.0]))
    if current:
        current = current | {n: 0.0 for n in fw.mag_param_names(0)["ofs"] + fw.mag_param_names(0)["dia"]
                             + fw.mag_param_names(0)["odi"]}
    prop = to_ardupilot_params(cal, generation, current_params=current)
    assert ("COMPASS_OFS_X" in prop.values) == ok
    assert ("COMPASS_OFS_X" in prop.rejected) != ok


@pytest.mark.parametrize("matrix, name", [
    (np.diag([6.0, 1.0, 1.0]), "COMPASS_DIA_X"),
    (np.diag([1.0, 0.1, 1.0]), "COMPASS_DIA_Y"),
    (np.array([[2.0, 1.2, 0.0], [1.2, 2.0, 0.0], [0.0, 0.0, 1.0]]), "COMPASS_ODI_X"),
])
def test_compass_matrix_limits(matrix, name):
    prop = to_ardupilot_params(_cal(mag=SensorCalibration(matrix=matrix)), "3.3+")
    assert name in prop.rejected and not any(n.startswith("COMPASS") for n in prop.values)


def test_unknown_names_and_instances():
    cal = _cal(acc=_acc(), gyr=SensorCalibration())
    current = {"AHRS_ORIENTATION": 0} | {f"INS_ACC{k}_{a}": 0 for k in ("OFFS", "SCAL") for a in "XYZ"}
    prop = to_ardupilot_params(cal, "3.3+", current_params=current)
    assert "no such parameter" in prop.rejected["INS_GYROFFS_X"]
    prop2 = to_ardupilot_params(cal, "3.3+", instance=1)
    assert {"INS_ACC2OFFS_X", "INS_ACC2SCAL_Z", "INS_GYR2OFFS_Y"} <= set(prop2.values)
    with pytest.raises(ApmcalError, match="single IMU"):
        to_ardupilot_params(cal, "3.2", instance=1)
    with pytest.raises(ApmcalError, match="generation"):
        to_ardupilot_params(cal, "3.4")


# ----------------------------------------------------------------------------- param files
def test_param_file_round_trip_float32(tmp_path):
    rng = np.random.default_rng(2)
    values = {f"P{i}_X": float(np.float32(v)) for i, v in
              enumerate(np.concatenate([rng.normal(0, 1, 200), rng.normal(0, 1e4, 50),
                                        rng.normal(0, 1e-6, 50), [0.1, 1.0, -3.5, 1800.0]]))}
    path = tmp_path / "cal.param"
    write_param_file(path, values, "apmcal test\nsecond line")
    text = path.read_text().splitlines()
    assert text[:2] == ["# apmcal test", "# second line"]
    back = read_param_file(path)
    assert back.keys() == values.keys()
    assert all(np.float32(back[k]) == np.float32(v) for k, v in values.items())
    assert format_value(0.1) == "0.100000001"


def test_param_file_readable_by_mavproxy_loader(tmp_path):
    from pymavlink.mavparm import MAVParmDict

    values = {"INS_ACCOFFS_X": 0.12345679104328156, "COMPASS_OFS_Y": -123.5, "AHRS_ORIENTATION": 2.0}
    path = tmp_path / "cal.param"
    write_param_file(path, values, "header")
    loaded = MAVParmDict()
    loaded.load(str(path))
    assert dict(loaded) == pytest.approx(values, rel=1e-8)


def test_read_param_file_formats(tmp_path):
    path = tmp_path / "mixed.param"
    path.write_text("# Mission Planner\n\nINS_ACCOFFS_X,0.25\nINS_ACCOFFS_Y 0.5   # note\n"
                    "INS_ACCOFFS_Z\t-1e-3\nCOMPASS_ORIENT 0x10\nINS_ACCOFFS_X 0.75\n")
    assert read_param_file(path) == {"INS_ACCOFFS_X": 0.75, "INS_ACCOFFS_Y": 0.5,
                                     "INS_ACCOFFS_Z": -0.001, "COMPASS_ORIENT": 16.0}


@pytest.mark.parametrize("text, line, why", [
    ("A 1\nINS_ACCOFFS_X\n", 2, "expected 'NAME VALUE'"),
    ("A 1\n\nB abc\n", 3, "not a number"),
    ("A nan\n", 1, "not finite"),
    ("A 1 2\n", 1, "expected 'NAME VALUE'"),
    ("BAD-NAME 1\n", 1, "not a valid parameter name"),
])
def test_read_param_file_errors_name_file_and_line(tmp_path, text, line, why):
    path = tmp_path / "bad.param"
    path.write_text(text)
    with pytest.raises(ApmcalError, match=why) as err:
        read_param_file(path)
    assert str(err.value).startswith(f"{path}: line {line}: ")


def test_write_param_file_refuses_bad_values(tmp_path):
    with pytest.raises(ApmcalError, match="param INS_ACCOFFS_X"):
        write_param_file(tmp_path / "x.param", {"INS_ACCOFFS_X": float("inf")}, "")
    with pytest.raises(ApmcalError, match="not a valid parameter name"):
        write_param_file(tmp_path / "x.param", {"A_VERY_LONG_PARAMETER_NAME": 1.0}, "")
    with pytest.raises(ApmcalError, match="no such"):
        read_param_file(tmp_path / "missing.param")
