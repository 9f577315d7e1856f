"""CSV readers (apmcal.sources.csv).

Truth: files written here with known values; imucal's own expected results for its example data
(tests_snapshot_example_cal.json and tests_ferraris_example.csv) reproduced by imucal from what
our reader returns; the MPU-6050 datasheet sensitivities against tomisuarez2's reference results.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from apmcal.core.errors import ApmcalError
from apmcal.sources.csv import (
    MPU6050_ACC_PER_COUNT,
    MPU6050_GYR_PER_COUNT,
    read_csv,
    read_imu_tk,
    sniff_layout,
)

HEADER = "t,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z"


def _write(tmp_path, text, name="rec.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


# ----------------------------------------------------------------------------- own layout
def test_default_layout_si(tmp_path):
    p = _write(tmp_path, f"{HEADER},mag_x,mag_y,mag_z,temp,extra\n"
                         "0.00,0.1,0.2,-9.8,0.01,0.02,0.03,100,200,300,25.5,7\n"
                         "0.01,0.1,0.2,-9.7,0.01,0.02,0.03,101,201,301,25.5,7\n")
    contents = read_csv(p)
    pd.testing.assert_frame_equal(read_csv(p, layout="si").recordings[0].data,
                                  contents.recordings[0].data)
    assert contents.format == "csv" and contents.path == str(p) and len(contents.recordings) == 1
    rec = contents.recordings[0]
    assert (rec.corrected, rec.frame, rec.message) == (False, "sensor", "csv")
    assert rec.sensors == ["acc", "gyr", "mag"] and "temp" in rec.data and "extra" not in rec.data
    np.testing.assert_allclose(rec.xyz("acc")[1], [0.1, 0.2, -9.7])
    np.testing.assert_allclose(rec.xyz("mag")[0], [100, 200, 300])
    assert rec.rate_hz == pytest.approx(100.0)


def test_units_are_converted(tmp_path):
    p = _write(tmp_path, f"{HEADER}\n0,0,0,-1,90,0,0\n0.5,0.001,0,-1,0,-180,0\n")
    rec = read_csv(p, acc_unit="g", gyr_unit="deg/s").recordings[0]
    np.testing.assert_allclose(rec.xyz("acc")[0], [0, 0, -9.80665])
    np.testing.assert_allclose(rec.xyz("gyr")[:, :2], [[math.pi / 2, 0], [0, -math.pi]])
    rec = read_csv(p, acc_unit=2.0, gyr_unit="mrad/s").recordings[0]
    np.testing.assert_allclose(rec.xyz("acc")[1], [0.002, 0, -2])
    np.testing.assert_allclose(rec.xyz("gyr")[0], [0.09, 0, 0])
    with pytest.raises(ApmcalError, match="unknown acc unit"):
        read_csv(p, acc_unit="furlong")


@pytest.mark.parametrize("body, line, why", [
    ("0,0,0,-9.8,0,0,0\n0.01,0,abc,-9.8,0,0,0\n", 3, "acc_y = 'abc' is not a finite number"),
    # a time written as nan places no sample (a sensor value nan or inf is data: dropped later,
    # tests/test_earned_answers.py)
    ("0,0,0,-9.8,0,0,0\nnan,0,0,-9.8,0,0,0\n", 3, "t = 'nan' is not a finite number"),
    ("0,0,0,-9.8,0,0,0\n0.01,0,,-9.8,0,0,0\n", 3, "acc_y is empty"),
    ("0,0,0,-9.8,0,0,0\n0.01,0,0,-9.8,0,0\n", 3, "6 fields, header has 7"),     # short row
    ("0,0,0,-9.8,0,0,0\n0.01,0,0,-9.8\n", 3, "4 fields, header has 7"),
    ("0,0,0,-9.8,0,0,0\n0.01,0,0,-9.8,0,0,0,5\n", 3, "8 fields, header has 7"),   # extra
    ("0,0,0,-9.8,0,0,0\n0.01,0,0,-9.8,0,0,0,5,6\n0.02,0,0\n", 3, "9 fields, header has 7"),
    # an extra field in the first row: pandas would silently make column 1 an index
    ("0,0,0,-9.8,0,0,0,5\n0.01,0,0,-9.8,0,0,0,5\n", 2, "8 fields, header has 7"),
    ("0,0,0,-9.8,0,0,0,\n0.01,0,0,-9.8,0,0,0,\n", 2, "8 fields, header has 7"),   # trailing ,
    ("0,0,0,-9.8,0,0,0\n0.01,0,abc,-9.8,0,0,0\n0.02,0,0\n", 3, "acc_y = 'abc'"),  # first bad
    ("0,0,0,-9.8,0,0,0\n0.01,0,0,-9.8,0\n0.02,0,abc,-9.8,0,0,0\n", 3, "5 fields"),
    ("0,0,0,-9.8,0,0,0\n0.01,0,0,-9.8,0,0,0\n0.01,0,0,-9.8,0,0,0\n", 4,
     r"time 0\.01 s does not increase \(previous 0\.01 s\)"),
    ("0,0,0,-9.8,0,0,0\n-0.5,0,0,-9.8,0,0,0\n", 3, "does not increase"),
    ("0,0,0,-9.8,0,0,0\n\n0.02,0,0,-9.8,0,0,0\n", 3, "empty line"),
])
def test_bad_rows_name_file_and_line(tmp_path, body, line, why):
    """One line: the file, "line N", then the reason (field counts against the header's, the
    raw text of a bad value)."""
    p = _write(tmp_path, f"{HEADER}\n{body}")
    with pytest.raises(ApmcalError, match=why) as err:
        read_csv(p)
    assert str(err.value).startswith(f"{p}: line {line}: ") and "\n" not in str(err.value)
    assert "np.float64" not in str(err.value)


def test_utf8_byte_order_mark_is_skipped(tmp_path):
    """Excel and Windows tools start UTF-8 files with a byte order mark (EF BB BF)."""
    body = "0,0,0,-9.8,0,0,0\n0.01,0,0,-9.7,0,0,0\n"
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf" + f"{HEADER}\n{body}".encode())
    assert sniff_layout(p) == "apmcal"
    rec = read_csv(p).recordings[0]
    pd.testing.assert_frame_equal(rec.data, read_csv(_write(tmp_path, f"{HEADER}\n{body}"))
                                  .recordings[0].data)
    p.write_bytes(b"\xef\xbb\xbf" + f"{HEADER}\n0,0,0,-9.8,0,0,0\n0.01,0,0\n".encode())
    with pytest.raises(ApmcalError, match="line 3: 3 fields, header has 7"):
        read_csv(p)
    m = tmp_path / "mpu.csv"
    m.write_bytes(b"\xef\xbb\xbfFs,50\nLogging Type,0\nInitialization time,1\nWaiting time,1\n"
                  b"ax,ay,az,gx,gy,gz\n1,2,3,4,5,6\n1,2,3,4,5,6\n")
    assert sniff_layout(m) == "mpu6050" and read_csv(m).recordings[0].rate_hz == 50.0
    acc = _write(tmp_path, "0.00 1 2 3\n0.01 1 2 3\n", "b_acc.txt")
    acc.write_bytes(b"\xef\xbb\xbf" + acc.read_bytes())
    _write(tmp_path, "0.00 1 2 3\n0.01 1 2 3\n", "b_gyro.txt")     # the partner file
    assert read_csv(acc).recordings[0].data.t.tolist() == [0.0, 0.01]


def test_field_counts_in_other_layouts(tmp_path):
    """Whitespace tables (imu_tk) count against their 4 columns; mpu6050 lines count from the
    top of the file, its 4 key,value lines included."""
    acc = _write(tmp_path, "0.00 1 2 3\n0.01 1 2 3 4\n0.02 1 2 3\n", "c_acc.txt")
    gyr = _write(tmp_path, "0.00 1 2 3\n0.01 1 2 3\n0.02 1 2 3\n", "c_gyro.txt")
    with pytest.raises(ApmcalError, match="c_acc.txt: line 2: 5 fields, expected 4"):
        read_imu_tk(acc, gyr)
    acc.write_text("0.00 1 2 3 9\n0.01 1 2 3 9\n0.02 1 2 3 9\n")      # would become an index
    with pytest.raises(ApmcalError, match="line 1: 5 fields, expected 4"):
        read_imu_tk(acc, gyr)
    gyr.write_text("0.00 1 2 3\n0.01 1 2\n0.02 1 2 3\n")
    acc.write_text("0.00 1 2 3\n0.01 1 2 3\n0.02 1 2 3\n")
    with pytest.raises(ApmcalError, match="c_gyro.txt: line 2: 3 fields, expected 4"):
        read_imu_tk(acc, gyr)
    p = _write(tmp_path, "Fs,100\nLogging Type,0\nInitialization time,1\nWaiting time,1\n"
                         "ax,ay,az,gx,gy,gz\n1,2,3,4,5,6\n1,2,3,4,5,6,7\n")
    with pytest.raises(ApmcalError, match="line 7: 7 fields, header has 6"):
        read_csv(p)


def test_trailing_blank_lines_are_fine(tmp_path):
    p = _write(tmp_path, f"{HEADER}\n0,0,0,-9.8,0,0,0\n0.01,0,0,-9.8,0,0,0\n\n\n")
    assert len(read_csv(p).recordings[0]) == 2


@pytest.mark.parametrize("text, where, why", [
    ("time,ax,ay\n1,2,3\n", "line 1", "unrecognised CSV layout"),
    ("", None, "empty"),
    ("t,acc_x,acc_y,acc_z\n0,1,2,3\n", "line 1", "gyr_x"),
])
def test_unusable_files(tmp_path, text, where, why):
    p = _write(tmp_path, text)
    with pytest.raises(ApmcalError, match=why) as err:
        read_csv(p, layout="auto" if "gyr_x" not in why else "apmcal")
    assert err.value.path == str(p) and err.value.where == where


def test_binary_and_missing_files(tmp_path):
    p = tmp_path / "x.csv"
    p.write_bytes(b"\xff\xfe\x00\x81garbage\x00")
    with pytest.raises(ApmcalError, match="not a text file"):
        read_csv(p)
    with pytest.raises(ApmcalError, match="no such file"):
        read_csv(tmp_path / "missing.csv")
    with pytest.raises(ApmcalError, match="unknown CSV layout"):
        read_csv(p, layout="excel")


# ----------------------------------------------------------------------------- imucal
def test_imucal_session(shared_data):
    path = shared_data / "imucal" / "example_ferraris_session.csv"
    assert sniff_layout(path) == "imucal"
    contents = read_csv(path)
    rec = contents.recordings[0]
    raw = pd.read_csv(path)
    assert len(rec) == len(raw) == 10376
    assert rec.rate_hz == pytest.approx(102.4)
    assert rec.duration == pytest.approx(10375 / 102.4)
    np.testing.assert_allclose(rec.xyz("gyr"), np.radians(raw[["gyr_x", "gyr_y", "gyr_z"]]))
    assert any("102.4" in m for m in contents.messages)


def test_imucal_reproduces_its_own_example_results(shared_data):
    """imucal's example: a Ferraris calibration from the session, applied to its first 50 rows,
    gives tests_ferraris_example.csv. Done on our reader's output (rad/s back to imucal's deg/s,
    sample numbers back from t) it must give the same numbers."""
    from imucal import FerrarisCalibration
    from imucal.ferraris_calibration import ferraris_regions_from_section_list

    folder = shared_data / "imucal"
    rec = read_csv(folder / "example_ferraris_session.csv").recordings[0]
    data = rec.data.copy()
    data[["gyr_x", "gyr_y", "gyr_z"]] = np.degrees(rec.xyz("gyr"))
    data.index = np.rint(rec.t * 102.4).astype(int)
    data = data.drop(columns="t")
    sections = pd.read_json(folder / "example_ferraris_session_list.json").T
    cal = FerrarisCalibration().compute(ferraris_regions_from_section_list(data, sections), 102.4,
                                        from_acc_unit="m/s^2", from_gyr_unit="deg/s")
    out = cal.calibrate_df(data.head(50), "m/s^2", "deg/s")
    expected = read_csv(folder / "tests_ferraris_example.csv").recordings[0]
    np.testing.assert_allclose(out[["acc_x", "acc_y", "acc_z"]], expected.xyz("acc"), atol=1e-9)
    np.testing.assert_allclose(np.radians(out[["gyr_x", "gyr_y", "gyr_z"]]), expected.xyz("gyr"),
                               atol=1e-12)


def test_imucal_annotated_session_reproduces_snapshot(shared_data):
    """Sorted rows and kept 'part' labels are exactly what imucal needs to reproduce its own
    regression snapshot (tests_snapshot_example_cal.json, 204.8 Hz, counts)."""
    from imucal import FerrarisCalibration, FerrarisCalibrationInfo
    from imucal.ferraris_calibration import ferraris_regions_from_df

    folder = shared_data / "imucal"
    contents = read_csv(folder / "annotated_session.csv")
    rec = contents.recordings[0]
    assert np.all(np.diff(rec.t) > 0) and set(rec.data["part"]) >= {"x_p", "z_rot"}
    assert any("raw sensor counts" in m for m in contents.messages)
    df = rec.data.assign(samples=np.rint(rec.t * 204.8).astype(int)).set_index(["part", "samples"])
    cal = FerrarisCalibration().compute(ferraris_regions_from_df(df), 204.8,
                                        from_acc_unit="a.u.", from_gyr_unit="a.u.")
    assert cal == FerrarisCalibrationInfo.from_json_file(folder / "tests_snapshot_example_cal.json")


# ----------------------------------------------------------------------------- mpu6050
def test_mpu6050_file(shared_data):
    path = shared_data / "mpu6050" / "example_data_calibration.csv"
    assert sniff_layout(path) == "mpu6050"
    contents = read_csv(path)
    rec = contents.recordings[0]
    assert len(rec) == 10245 and rec.rate_hz == pytest.approx(100.0)
    assert any("initialization time 36.5 s" in m for m in contents.messages)
    counts = read_csv(path, acc_unit="counts", gyr_unit="counts").recordings[0]
    np.testing.assert_array_equal(counts.xyz("acc")[0], [-12, -812, 15032])     # first data line
    np.testing.assert_allclose(rec.xyz("acc"), counts.xyz("acc") * 9.80665 / 16384)
    np.testing.assert_allclose(rec.xyz("gyr"), counts.xyz("gyr") * math.pi / 180 / 131)
    # the repo's reference calibration (Tedaldi 2014: a = T·K·(counts + b)) applied to our counts
    # gives |a| = g on each of its reference static intervals (row index start, end)
    p = np.loadtxt(shared_data / "mpu6050" / "ref_params_acc.csv")
    intervals = np.loadtxt(shared_data / "mpu6050" / "ref_static_intervals.csv", delimiter=",")
    t_mat = np.array([[1, -p[0], p[1]], [0, 1, -p[2]], [0, 0, 1]])
    calibrated = (counts.xyz("acc") + p[6:9]) @ (t_mat @ np.diag(p[3:6])).T
    for start, end in intervals.T.astype(int):
        assert np.linalg.norm(calibrated[start:end].mean(axis=0)) == pytest.approx(9.81, abs=0.02)


def test_mpu6050_reference_results_use_si_units(shared_data):
    """tomisuarez2's reference scales (m/s² and rad/s per count) match the ±2 g / ±250 °/s
    datasheet sensitivities within a few per cent: the units our conversion assumes."""
    acc = np.loadtxt(shared_data / "mpu6050" / "ref_params_acc.csv")
    gyr = np.loadtxt(shared_data / "mpu6050" / "ref_params_gyro.csv")
    np.testing.assert_allclose(acc[3:6] / MPU6050_ACC_PER_COUNT, 1.0, atol=0.05)
    np.testing.assert_allclose(gyr[6:9] / MPU6050_GYR_PER_COUNT, 1.0, atol=0.05)


def test_mpu6050_bad_header(tmp_path):
    p = _write(tmp_path, "Fs,100\nLogging Type,zero\nInitialization time,1\nWaiting time,1\n"
                         "ax,ay,az,gx,gy,gz\n1,2,3,4,5,6\n")
    with pytest.raises(ApmcalError, match="line 2"):
        read_csv(p, layout="mpu6050")
    p = _write(tmp_path, "Fs,100\nLogging Type,0\nInitialization time,1\nWaiting time,1\n"
                         "ax,ay,az,gx,gy,gz\n1,2,3,4,5,6\n1,2,x,4,5,6\n")
    with pytest.raises(ApmcalError, match="line 7"):
        read_csv(p)


# ----------------------------------------------------------------------------- imu_tk
def test_imu_tk_pair(shared_data):
    folder = shared_data / "imu_tk"
    contents = read_imu_tk(folder / "xsens_acc.mat", folder / "xsens_gyro.mat")
    rec = contents.recordings[0]
    assert len(rec) == 51175 and rec.rate_hz == pytest.approx(100.0, rel=1e-3)
    np.testing.assert_array_equal(rec.data.iloc[0][["acc_x", "gyr_z"]], [33108.0, 32499.0])
    assert sum("raw sensor counts" in m for m in contents.messages) == 2
    # either file finds its partner through read_csv's auto layout
    for name in ("xsens_acc.mat", "xsens_gyro.mat"):
        other = read_csv(folder / name).recordings[0]
        pd.testing.assert_frame_equal(other.data, rec.data)
    scaled = read_imu_tk(folder / "xsens_acc.mat", folder / "xsens_gyro.mat", acc_unit=0.5)
    np.testing.assert_allclose(scaled.recordings[0].xyz("acc"), rec.xyz("acc") * 0.5)


def test_imu_tk_mismatch(tmp_path):
    acc = _write(tmp_path, "0.00 1 2 3\n0.01 1 2 3\n0.02 1 2 3\n", "a_acc.txt")
    gyr = _write(tmp_path, "0.00 1 2 3\n0.01 1 2 3\n0.03 1 2 3\n", "a_gyro.txt")
    with pytest.raises(ApmcalError, match="line 3: time differs"):
        read_imu_tk(acc, gyr)
    gyr.write_text("0.00 1 2 3\n0.01 1 2 3\n")
    with pytest.raises(ApmcalError, match="3 accelerometer rows but 2"):
        read_imu_tk(acc, gyr)
