"""What a hobbyist reads first, on every bundled sample and every real log of the test data
folder: the verdict in the first three lines, no line over 200 characters (none over 100 but
the file table's), no paper handle, no "±0.0000"; a flight log graded on what it measured."""
import re
from pathlib import Path

import pytest

from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SAMPLES = ["ferraris.tlog", "onepos.tlog", "tumble.bin", "ferraris_params33.tlog"]
REAL = ["ardupilot/pixhawk1_copter368.bin", "ardupilot/pxf_copter_mag.BIN",
        "ardupilot/ardusub_small.BIN", "ardupilot/sitl_vtol.tlog",
        "mpu6050/example_data_calibration.csv", "imucal/annotated_session.csv"]


def report_of(path: Path, capsys) -> list[str]:
    assert main(["log", str(path)]) in (0, 1)
    return capsys.readouterr().out.splitlines()


def check_plain(lines: list[str]) -> None:
    assert any(line.startswith("verdict: ") for line in lines[:3]), lines[:3]
    for line in lines:
        assert len(line) <= 200, line
        assert "±0.0000" not in line and "± 0.0000" not in line, line
        assert not re.search(r"seed 0\d\d|\[(Oppong|Chow|Niespodziany|Ferraris)\]", line), line
    long = [ln for ln in lines if len(ln) > 100 and "─" not in ln and not ln.startswith(
        ("message ", "IMU", "RAW_IMU", "MAG", "SCALED", "HIGHRES"))]
    assert not long, long


@pytest.mark.parametrize("name", SAMPLES)
def test_bundled_samples_read_plainly(capsys, name):
    check_plain(report_of(ROOT / "logs" / name, capsys))


@pytest.mark.parametrize("name", REAL)
def test_real_logs_read_plainly(capsys, name):
    path = DATA / name
    if not path.exists():
        pytest.skip(f"real recording {name} not here (the test data folder ../shared/data is "
                    "absent in a fresh clone)")
    check_plain(report_of(path, capsys))


def test_a_flight_log_is_graded_on_what_it_measured(capsys):
    """A real flight: one still moment measures the gyro offsets; the accelerometer and compass
    are "not measured", and since the vehicle re-measures its gyro offsets at every boot
    (INS_GYR_CAL 1) the overall verdict is not GOOD but NOTHING TO APPLY; the log is named a
    flight log."""
    path = DATA / "ardupilot" / "pixhawk1_copter368.bin"
    if not path.exists():
        pytest.skip("real recording absent (the test data folder ../shared/data)")
    lines = report_of(path, capsys)
    assert lines[0].startswith("verdict: NOTHING TO APPLY (gyroscope good; not measured:"), \
        lines[0]
    assert "this is a flight log" in lines[1]


# the real logs whose IMU path measures the gyro offsets only, and INS_GYR_CAL in force there
GYRO_ONLY = {"ardupilot/pixhawk1_copter368.bin": 1, "ardupilot/pxf_copter_mag.BIN": 1,
             "ardupilot/ardusub_small.BIN": 0, "ardupilot/ardusub_small.tlog": 0,
             "ardupilot/sitl_vtol.tlog": 0}


@pytest.mark.parametrize("name", sorted(GYRO_ONLY))
def test_gyro_offsets_alone_are_never_good_when_they_change_nothing(capsys, name):
    """Only gyro offsets measured: GOOD only where the vehicle keeps them (INS_GYR_CAL 0);
    where it re-measures them at every boot the verdict says there is nothing to apply and
    the apply lines never say "changes nothing" of a vehicle that keeps them."""
    path = DATA / name
    if not path.exists():
        pytest.skip("real recording absent (the test data folder ../shared/data)")
    lines = report_of(path, capsys)
    text = "\n".join(lines)
    if GYRO_ONLY[name]:
        assert lines[0].startswith("verdict: NOTHING TO APPLY (gyroscope good;"), lines[0]
        assert "changes nothing you will notice" in text
    else:
        assert lines[0].startswith("verdict: GOOD (gyroscope good;"), lines[0]
        assert "changes nothing" not in text
        assert "INS_GYR_CAL is 0 on this vehicle" in text
