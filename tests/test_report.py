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


def print_verbose(calibration, proposal, console):
    report.print_calibration(calibration, proposal, console, verbose=True)


def test_solver_report_lines_and_warnings_are_printed():
    cal = Calibration(method="static", sensors={"acc": SensorCalibration()}, report={
        "lines": ["acc: b_x, F_xz cannot be separated [bold]", "acc: F_xx NOT determinable",
                  "acc: tilt from level 1.7° [dim]"],
        "warnings": ["magnetometer not calibrated [red]"]})
    out = render(print_verbose, cal, None)        # --verbose
    assert "acc: b_x, F_xz cannot be separated [bold]" in out
    assert "acc: F_xx NOT determinable" in out
    assert "warning: magnetometer not calibrated [red]" in out
    plain = render(report.print_calibration, cal, None)
    assert "cannot be separated" not in plain and "NOT determinable" not in plain
    assert "acc: tilt from level 1.7° [dim]" in plain and "warning: magnetometer" in plain


JARGON = ("seed 0", "antithetic", "Jacobian", "rank", "second-order fit bias", "eigenvalues",
          "Birge", "χ²")


def test_jargon_only_with_verbose():
    """Every kind of specialist line the solvers write stays out of the default report."""
    lines = ["mag: second-order fit bias removed (4 antithetic refit pairs): offset by [1 2 3]",
             "mag: relative MSE of |calibrated| (seed 000) raw 0.06 → 8e-05 on held-out samples",
             "acc: 1 pose(s), 9 parameters: Jacobian rank 3 of 9, condition number inf",
             "mag: 23450 samples, directions cover 84% of the sphere (20° cones), coverage "
             "eigenvalues [0.6 0.98 1.34] (1 = uniform)"]
    cal = Calibration(method="ferraris", sensors={"acc": SensorCalibration(
        sigma={"offset": [0.01] * 3, "matrix": np.full((3, 3), 1e-3)})}, report={
        "lines": lines, "acc_misfit": {"n_holds": 6, "chi2": 60.0, "dof": 6, "birge_ratio": 3.2,
                                       "worst_residual": 0.04, "tau": [0.01] * 3,
                                       "offset_spread": [0.02] * 3},
        "acc_sigma_noise_only": {"offset": [4e-4] * 3}})
    plain = render(report.print_calibration, cal, None)
    assert not [j for j in JARGON if j in plain], plain
    verbose = render(print_verbose, cal, None)
    assert all(line in verbose for line in lines)
    assert "Birge ratio 3.20" in verbose and "from the noise alone (0.0004" in verbose


def test_verdict_comes_before_the_numbers():
    cal = Calibration(method="ferraris", sensors={"acc": SensorCalibration(
        offset=[0.3, 0, 0], sigma={"offset": [0.01] * 3, "matrix": np.full((3, 3), 1e-3)})})
    out = render(report.print_calibration, cal, None)
    assert out.index("verdict: GOOD (accelerometer good)") < out.index("acc: offset")
    assert "accelerometer: good — offsets known to ±0.010 m/s²" in out


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
