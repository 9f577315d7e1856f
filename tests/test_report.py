"""The text report: user data printed literally, reader notes and solver report lines shown."""
import io

import numpy as np
import pandas as pd
from rich.console import Console

from apmcal import report
from apmcal.recording import LogContents, Recording
from apmcal.solvers.result import Calibration, SensorCalibration


def render(fn, *args) -> str:
    """Output of a report function on a console that DOES parse markup (the strict case)."""
    buf = io.StringIO()
    fn(*args, Console(file=buf, width=200, markup=True, emoji=True, highlight=False))
    return buf.getvalue()


def contents(fmt="bin", messages=(), path="logs/run[blue]:smile:.bin"):
    data = pd.DataFrame({"t": np.arange(5) * 0.02, "acc_x": 0.0, "acc_y": 0.0, "acc_z": -9.8})
    rec = Recording(data=data, message="IMU", instance=0)
    return LogContents(path=path, format=fmt, recordings=[rec], messages=list(messages))


def test_reader_notes_are_shown_and_vehicle_texts_are_not():
    c = contents(messages=["ArduCopter V3.1.1 (681dafcf)", "PreArm: GPS glitching",
                           "warning: parameter COMPASS_MOT_X is nan at PARM #200; ignored",
                           "note: MAG[0] mag is all zero; column(s) dropped"])
    summary = report.summarize(c)
    assert summary["notes"] == c.messages[2:]
    assert summary["messages"] == c.messages            # JSON keeps every text, as before
    out = render(report.print_summary, summary)
    assert "warning: parameter COMPASS_MOT_X is nan at PARM #200; ignored" in out
    assert "note: MAG[0] mag is all zero; column(s) dropped" in out
    assert "PreArm" not in out


def test_every_csv_message_is_a_reader_note():
    c = contents(fmt="csv", messages=["acc: raw sensor counts, not SI units (no scale known)"])
    assert report.summarize(c)["notes"] == c.messages
    assert "acc: raw sensor counts" in render(report.print_summary, report.summarize(c))


def test_notes_past_the_first_twenty_messages_are_not_lost():
    c = contents(messages=[f"vehicle text {i}" for i in range(30)] + ["note: IMU2 lacks x"])
    assert "note: IMU2 lacks x" in render(report.print_summary, report.summarize(c))


def test_file_name_and_units_are_literal_even_on_a_markup_console():
    out = render(report.print_summary, report.summarize(contents()))
    assert "logs/run[blue]:smile:.bin" in out and "rate [Hz]" in out and "duration [s]" in out
    cal = Calibration(method="ellipsoid", sensors={
        "acc": SensorCalibration(offset=[0.1, 0.2, 0.3], sigma={"offset": [0.01] * 3}),
        "gyr": SensorCalibration(drift=[1e-6, 0, 0])})
    out = render(report.print_calibration, cal, None)
    assert "acc: offset [m/s²] = (+0.1, +0.2, +0.3)" in out
    assert "gyr: offset [rad/s]" in out and "drift [rad/s/s]" in out


def test_solver_report_lines_and_warnings_are_printed():
    cal = Calibration(method="static", sensors={"acc": SensorCalibration()}, report={
        "lines": ["acc: b_x, F_xz cannot be separated [bold]", "acc: F_xx NOT determinable"],
        "warnings": ["magnetometer not calibrated [red]"]})
    out = render(report.print_calibration, cal, None)
    assert "acc: b_x, F_xz cannot be separated [bold]" in out
    assert "acc: F_xx NOT determinable" in out
    assert "warning: magnetometer not calibrated [red]" in out


def test_recording_date_and_its_source_are_shown():
    tlog, bin_ = contents(fmt="tlog"), contents(fmt="bin")
    tlog.start_unix_s = bin_.start_unix_s = 1_780_000_000.5
    assert "recorded: 2026-05-28T20:26:40+00:00 (ground station clock)" in render(
        report.print_summary, report.summarize(tlog))
    assert "recorded: 2026-05-28T20:26:40+00:00 (GPS time)" in render(
        report.print_summary, report.summarize(bin_))
    assert "recorded" not in render(report.print_summary, report.summarize(contents()))


def test_calibration_parameter_changes_are_warned_in_the_summary():
    from apmcal.recording import ParamChange

    c = contents()
    c.param_changes = [ParamChange("INS_ACCOFFS_X", 0.1, 0.25, 5.0, "PARM record at byte 99")]
    summary = report.summarize(c)
    assert summary["param_changes"] == [
        "INS_ACCOFFS_X changed from 0.1 to 0.25 at t=5.000 s (PARM record at byte 99)"]
    assert ("warning: while recording, INS_ACCOFFS_X changed from 0.1 to 0.25 at t=5.000 s "
            "(PARM record at byte 99)") in render(report.print_summary, summary)
