"""Dataflash readers (.bin and text .log) against pymavlink's DFReader, plus format details."""
from __future__ import annotations

import struct

import numpy as np
import pymavlink_ref as ref
import pytest

from apmcal.core.errors import ApmcalError
from apmcal.sources import read_log
from apmcal.sources.dataflash import read_bin_messages

DATAFLASH = ["ardupilot/ardusub_small.BIN", "ardupilot/copter311_nan.log",
             "ardupilot/pixhawk1_copter368.bin", "ardupilot/pixhawk_3imu_log171.bin",
             "ardupilot/pxf_copter_mag.BIN", "ardupilot/pxf_copter_static_51.BIN"]


@pytest.mark.parametrize("name", DATAFLASH)
def test_matches_dfreader(shared_data, name):
    path = shared_data / name
    contents = read_log(path)
    msgs = ref.pymavlink_messages(path, None)
    n = ref.compare(contents, ref.df_expected(msgs))
    assert n > 5000
    assert contents.params == ref.expected_params(msgs)
    assert contents.format == ("log" if name.endswith(".log") else "bin")
    assert contents.bytes_skipped == 0
    for r in contents.recordings:
        assert r.corrected and r.frame == "body" and r.params == contents.params


def test_instance_numbered_ardusub(shared_data):
    c = read_log(shared_data / "ardupilot/ardusub_small.BIN")
    keys = sorted((r.message, r.instance) for r in c.recordings)
    assert keys == [("IMU", 0), ("MAG", 0), ("MAG", 1)]
    assert (c.vehicle, c.firmware) == ("ArduSub", "ArduSub V4.1.0")
    imu = c.recordings[0]
    assert imu.sensors == ["acc", "gyr"] and 30 < imu.data.temp.median() < 70


def test_three_imus(shared_data):
    c = read_log(shared_data / "ardupilot/pixhawk_3imu_log171.bin")
    imus = {r.instance: r for r in c.recordings if r.message.startswith("IMU")}
    mags = {r.instance: r for r in c.recordings if r.message.startswith("MAG")}
    assert sorted(imus) == [0, 1, 2] and sorted(mags) == [0, 1, 2]
    assert [imus[i].message for i in range(3)] == ["IMU", "IMU2", "IMU3"]
    assert c.firmware == "ArduCopter V3.3-dev" and c.vehicle == "ArduCopter"
    # TimeMS → s: 243 s log, 50 Hz
    assert 200 < imus[0].duration < 260 and 40 < imus[0].rate_hz < 60


def test_nan_params_text_log(shared_data):
    c = read_log(shared_data / "ardupilot/copter311_nan.log")
    assert (c.vehicle, c.firmware) == ("ArduCopter", "ArduCopter V3.1.1")
    for axis in "XYZ":
        assert f"COMPASS_MOT_{axis}" not in c.params
        assert any(f"COMPASS_MOT_{axis}" in m and "nan" in m for m in c.messages)
    assert all(np.isfinite(v) for v in c.params.values()) and len(c.params) > 300
    assert sorted((r.message, r.instance) for r in c.recordings) == [
        ("IMU", 0), ("IMU2", 1), ("MAG", 0), ("MAG2", 1)]


def test_all_zero_mag_is_dropped(shared_data):
    c = read_log(shared_data / "ardupilot/pxf_copter_static_51.BIN")
    assert [r.message for r in c.recordings] == ["IMU"]
    assert any("MAG[0] mag is all zero" in m for m in c.messages)


# --- a hand-built .bin exercising every format character against DFReader -------------------

NUM_FMT = "bBhHiIfdcCeELMqQ"     # a FMT format string holds at most 16 characters
STR_FMT = "nNZ"


def _fmt_record(t: int, name: str, fmt: str, cols: str, length: int) -> bytes:
    return struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, t, length, name.encode(),
                       fmt.encode(), cols.encode())


def _struct_of(fmt: str) -> str:
    m = {"b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d",
         "c": "h", "C": "H", "e": "i", "E": "I", "L": "i", "M": "b", "q": "q", "Q": "Q",
         "n": "4s", "N": "16s", "Z": "64s"}
    return "<" + "".join(m[c] for c in fmt)


def _random_values(rng, fmt: str) -> list:
    ranges = {"b": (-128, 127), "B": (0, 255), "h": (-32768, 32767), "H": (0, 65535),
              "i": (-2**31, 2**31 - 1), "I": (0, 2**32 - 1), "c": (-32768, 32767),
              "C": (0, 65535), "e": (-2**31, 2**31 - 1), "E": (0, 2**32 - 1),
              "L": (-1_800_000_000, 1_800_000_000), "M": (-128, 127), "q": (-2**62, 2**62),
              "Q": (0, 2**63)}
    text = {"n": b"ab", "N": b"NAME_X", "Z": b"hello world"}
    out = []
    for c in fmt:
        if c in ranges:
            out.append(int(rng.integers(*ranges[c])))
        elif c in "fd":
            out.append(float(rng.normal()) * 10.0 ** int(rng.integers(-3, 6)))
        else:
            out.append(text[c])
    return out


def test_every_format_char_equals_dfreader(tmp_path):
    """Decoding and multipliers (c, C, e, E: 0.01; L: 1e-7) equal DFReader's for all formats."""
    types = {"TST": (200, NUM_FMT), "TSS": (201, STR_FMT)}
    data = _fmt_record(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89)
    for name, (t, fmt) in types.items():
        cols = ",".join(f"F{i}" for i in range(len(fmt)))
        data += _fmt_record(t, name, fmt, cols, struct.calcsize(_struct_of(fmt)) + 3)
    rng = np.random.default_rng(7)
    for _ in range(50):
        for t, fmt in types.values():
            data += b"\xa3\x95" + bytes([t]) + struct.pack(_struct_of(fmt), *_random_values(rng, fmt))
    p = tmp_path / "all.bin"
    p.write_bytes(data)
    got, skipped, _ = read_bin_messages(p, want=lambda n: n in types)
    assert skipped == 0
    for name, (_, fmt) in types.items():
        msgs = ref.pymavlink_messages(p, [name])
        assert len(msgs) == 50 == len(got[name]["F0"])
        for i, c in enumerate(fmt):
            want = [getattr(m, f"F{i}") for m in msgs]
            have = list(got[name][f"F{i}"])
            assert have == want, f"format {c!r}"


def test_no_imu_bin_is_an_error(tmp_path):
    data = _fmt_record(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89)
    data += _fmt_record(129, "PARM", "Nf", "Name,Value", 23)
    data += b"\xa3\x95\x81" + struct.pack("<16sf", b"INS_ACCOFFS_X", 0.5)
    p = tmp_path / "noimu.bin"
    p.write_bytes(data)
    with pytest.raises(ApmcalError, match=r"no IMU messages \(found: .*PARM"):
        read_log(p)


def test_no_imu_text_log_is_an_error(tmp_path):
    p = tmp_path / "noimu.log"
    p.write_text("FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n"
                 "FMT, 129, 23, PARM, Nf, Name,Value\nPARM, INS_ACCOFFS_X, 0.5\n")
    with pytest.raises(ApmcalError, match=r"no IMU messages \(found: PARM\)"):
        read_log(p)


def test_acc_gyr_families_equal_dfreader(tmp_path):
    """Old ACC1/GYR1 and instance-numbered ACC/GYR messages become acc-only / gyr-only
    recordings with the right instance, values identical to DFReader's."""
    data = _fmt_record(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89)
    data += _fmt_record(150, "ACC1", "QQfff", "TimeUS,SampleUS,AccX,AccY,AccZ", 3 + 28)
    data += _fmt_record(151, "GYR2", "QQfff", "TimeUS,SampleUS,GyrX,GyrY,GyrZ", 3 + 28)
    data += _fmt_record(152, "ACC", "QBQfff", "TimeUS,I,SampleUS,AccX,AccY,AccZ", 3 + 29)
    rng = np.random.default_rng(11)
    for k in range(30):
        a = rng.normal(size=3).tolist()
        data += b"\xa3\x95" + bytes([150]) + struct.pack("<QQfff", 1000 * k, 1000 * k + 3, *a)
        data += b"\xa3\x95" + bytes([151]) + struct.pack("<QQfff", 1000 * k, 1000 * k + 2, *a)
        data += b"\xa3\x95" + bytes([152]) + struct.pack("<QBQfff", 1000 * k, k % 2, 1000 * k, *a)
    p = tmp_path / "accgyr.bin"
    p.write_bytes(data)
    c = read_log(p)
    keys = sorted((r.message, r.instance, tuple(r.sensors)) for r in c.recordings)
    assert keys == [("ACC", 0, ("acc",)), ("ACC", 1, ("acc",)), ("ACC1", 0, ("acc",)),
                    ("GYR2", 1, ("gyr",))]
    assert ref.compare(c, ref.df_expected(ref.pymavlink_messages(p, None))) == 3 * 30 * 4


# --- calibration parameters changed while the IMU samples were being recorded ----------------

def test_parm_change_after_imu_start_bin(tmp_path):
    """Written with the simulator's DataflashWriter (PARM with TimeUS). The whole list written
    again mid-log with the same values is no change; a new INS_GYROFFS_Z value after the first
    IMU record is, with the PARM's own time; a non-calibration parameter is not."""
    from apmcal_sim.logwriter import DataflashWriter

    listing = {"INS_GYROFFS_Z": 0.002, "INS_ACCSCAL_X": 1.02, "COMPASS_DIA_X": 1.0,
               "LOG_BITMASK": 830.0}
    p = tmp_path / "change.bin"
    with DataflashWriter(p) as w:
        for k, v in listing.items():
            w.parm(0, k, v)
        w.parm(0, "INS_ACCSCAL_X", 1.03)          # before the first sample: not a change
        for k in range(100):
            t_us = 10_000 * (k + 1)
            w.imu(t_us, (0, 0, 0), (0, 0, -9.8), 30.0)
            if k == 40:
                for name, v in listing.items():
                    w.parm(t_us, name, v if name != "INS_ACCSCAL_X" else 1.03)
                w.parm(t_us, "LOG_BITMASK", 0.0)
            if k == 60:
                at = w.f.tell()
                w.parm(t_us + 5, "INS_GYROFFS_Z", -0.001)
    c = read_log(p)
    (ch,) = c.param_changes
    assert (ch.name, ch.old, ch.new) == ("INS_GYROFFS_Z", float(np.float32(0.002)),
                                         float(np.float32(-0.001)))
    assert ch.time_s == pytest.approx(0.610005) and ch.where == f"PARM record at byte {at}"
    assert c.params["INS_GYROFFS_Z"] == ch.new and c.params["LOG_BITMASK"] == 0.0


def test_parm_change_without_timeus_bin(tmp_path):
    """Older logs: PARM has no time column; the change gets the time of the last IMU record
    before it (TimeMS), and a change back to the first value is a second change."""
    data = _fmt_record(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89)
    data += _fmt_record(129, "PARM", "Nf", "Name,Value", 23)
    data += _fmt_record(130, "IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", 31)
    parm = lambda n, v: b"\xa3\x95\x81" + struct.pack("<16sf", n.encode(), v)  # noqa: E731
    data += parm("COMPASS_OFS_X", 40.0) + parm("AHRS_ORIENTATION", 0.0)
    at = []
    for k in range(1, 31):
        data += b"\xa3\x95\x82" + struct.pack("<Iffffff", 20 * k, 0, 0, 0, 0, 0, -9.8)
        if k in (10, 20):
            at.append(len(data))
            data += parm("COMPASS_OFS_X", 41.0 if k == 10 else 40.0)
    p = tmp_path / "old.bin"
    p.write_bytes(data)
    c = read_log(p)
    assert [(ch.name, ch.old, ch.new, ch.time_s, ch.where) for ch in c.param_changes] == [
        ("COMPASS_OFS_X", 40.0, 41.0, 0.2, f"PARM record at byte {at[0]}"),
        ("COMPASS_OFS_X", 41.0, 40.0, 0.4, f"PARM record at byte {at[1]}")]


def test_parm_change_text_log(tmp_path):
    """The text reader: PARM without time (Copter 3.1-style), IMU with TimeMS; the change is
    placed by line, with the time of the IMU line before it."""
    lines = ["FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
             "FMT, 129, 23, PARM, Nf, Name,Value",
             "FMT, 130, 31, IMU, Iffffff, TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
             "PARM, INS_ACCOFFS_Y, 0.05", "PARM, RATE_RLL_P, 0.15"]
    for k in range(1, 21):
        lines.append(f"IMU, {100 * k}, 0, 0, 0, 0, 0, -9.8")
        if k == 5:
            lines += ["PARM, INS_ACCOFFS_Y, 0.05", "PARM, RATE_RLL_P, 0.2"]   # no change / not cal
        if k == 12:
            lines.append("PARM, INS_ACCOFFS_Y, -0.3")
            line_no = len(lines)
    p = tmp_path / "change.log"
    p.write_text("\n".join(lines) + "\n")
    c = read_log(p)
    assert [(ch.name, ch.old, ch.new, ch.time_s, ch.where) for ch in c.param_changes] == [
        ("INS_ACCOFFS_Y", 0.05, -0.3, 1.2, f"PARM at line {line_no}")]
    assert c.params["INS_ACCOFFS_Y"] == -0.3


@pytest.mark.parametrize("name", DATAFLASH)
def test_no_param_change_in_real_dataflash(shared_data, name):
    assert read_log(shared_data / name).param_changes == []


@pytest.mark.parametrize("name", DATAFLASH)
def test_start_date_equals_dfreaders_gps_clock(shared_data, name):
    """The log's date comes from its first GPS fix (week + ms of week, both record layouts);
    pymavlink's DFReader dates its records from GPS the same way, independently. A log whose
    GPS never has a fix has no date (DFReader's clock then counts from boot)."""
    from pymavlink import mavutil

    path = shared_data / name
    first = mavutil.mavlink_connection(str(path)).recv_match(type=list(_SENSOR_TYPES))
    ours = read_log(path).start_unix_s
    if first._timestamp < 1e9:          # no GPS time: DFReader's clock is the boot clock
        assert ours is None
    else:
        assert ours == pytest.approx(first._timestamp, abs=0.05)


_SENSOR_TYPES = ("IMU", "IMU2", "IMU3", "ACC1", "GYR1", "ACC", "GYR", "MAG", "MAG2")


def test_simulated_log_is_dated_by_its_gps_records():
    """logs/tumble.bin: the simulator's GPS records (GWk/GMS layout) carry its start time."""
    from pathlib import Path

    log = Path(__file__).resolve().parents[1] / "logs" / "tumble.bin"
    assert read_log(log).start_unix_s == pytest.approx(1_780_000_000.0, abs=1e-3)
