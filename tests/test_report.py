"""The text report: user data printed literally, reader notes and solver report lines shown."""
import io

import numpy as np
import pandas as pd
from rich.console import Console

from apmcal.core.recording import LogContents, Recording
from apmcal.report import text as report
from apmcal.report.lines import calibration_lines
from apmcal.solvers.misfit import HoldMisfit
from apmcal.solvers.report_types import (
    CalibrationReport,
    Coverage,
    Debias,
    EllipsoidFit,
    MseScore,
    OnePositionAcc,
    OnePositionFit,
    OnePositionGyr,
    Residuals,
    SixFaceFit,
)
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
    assert "acc: offset [m/s²] = (+0.100, +0.200, +0.300) ± (0.01, 0.01, 0.01)" in out
    assert "gyr: offset [rad/s]" in out and "drift [rad/s/s]" in out


def print_verbose(calibration, proposal, console):
    report.print_calibration(calibration, proposal, console, verbose=True)


def one_position_fit(tilt_deg=1.7, g=9.8) -> OnePositionFit:
    """A one-position stage with made-up numbers (what [Oppong] §5 reports)."""
    z = np.zeros(3)
    acc = OnePositionAcc(mean=np.array([0, 0, -g]), g=g, R=z, R_f=z, bias=z, F=np.eye(3),
                         beta_gamma_mu=np.array([0, 0, 1.0]), mu_literal=0.0,
                         F_paper_convention=-np.eye(3), tilt_deg=tilt_deg)
    return OnePositionFit(acc=acc, gyr=OnePositionGyr(R=z, R_f=z, bias=z), fs_hz=50.0,
                          duration_s=60.0, cutoff_hz=0.5)


def mag_fit() -> EllipsoidFit:
    """A magnetometer fit's quality with made-up numbers, a note in markup-like brackets."""
    return EllipsoidFit(radius=500.0, method="robust", parameterisation="symmetric",
                        samples=23450, n_params=9, notes=["3 of 9 bootstrap refits failed [bold]"],
                        coverage=Coverage(0.84, np.array([0.6, 0.98, 1.34])),
                        residuals=Residuals(23450, 3.1, 3.0, 12),
                        held_out=MseScore(0.06, 8e-5, "held-out blocks", 20),
                        debias=Debias(np.array([1.0, 2.0, 3.0]), 1e-4, 4))


def test_solver_report_lines_and_warnings_are_printed():
    cal = Calibration(method="static", sensors={"acc": SensorCalibration()},
                      report=CalibrationReport(one_position=one_position_fit(tilt_deg=7.0),
                                               ellipsoids={"mag": mag_fit()},
                                               warnings=["magnetometer not calibrated [red]"]))
    out = render(print_verbose, cal, None)        # --verbose
    assert "acc: b_x, F_xz cannot be separated" in out
    assert "NOT determinable" in out
    assert "warning: magnetometer not calibrated [red]" in out
    plain = render(report.print_calibration, cal, None)
    assert "cannot be separated" not in plain and "NOT determinable" not in plain
    assert "acc: NOT LEVEL (7.0° > 5.0°)" in plain and "warning: magnetometer" in plain
    assert "mag: 3 of 9 bootstrap refits failed [bold]" in plain


JARGON = ("seed 0", "antithetic", "Jacobian", "rank", "second-order fit bias", "eigenvalues",
          "Birge", "χ²")


def test_jargon_only_with_verbose():
    """Every kind of specialist line the report writes stays out of the default report."""
    misfit = HoldMisfit(tau=np.full(3, 0.01), offset_spread=np.full(3, 0.02), chi2=61.44, dof=6,
                        n_holds=6, worst=0.04)
    six = SixFaceFit(u_plus=np.eye(3), u_minus=-np.eye(3), q=9.8, gravity=9.8,
                     gravity_source="given", misfit=misfit,
                     sigma_noise_only={"offset": np.full(3, 4e-4)})
    cal = Calibration(method="ferraris", sensors={"acc": SensorCalibration(
        sigma={"offset": [0.01] * 3, "matrix": np.full((3, 3), 1e-3)})},
        report=CalibrationReport(six_face=six, one_position=one_position_fit(),
                                 ellipsoids={"mag": mag_fit()}))
    lines = calibration_lines(cal.report, cal.sensors)
    assert any("antithetic" in line for line in lines) and any("Jacobian" in line
                                                                 for line in lines)
    plain = render(report.print_calibration, cal, None)
    assert not [j for j in JARGON if j in plain], plain
    verbose = render(print_verbose, cal, None)
    flat = " ".join(verbose.split())           # the console wraps lines beyond 200 columns
    assert all(" ".join(line.split()) in flat for line in lines)
    assert "Birge ratio 3.20" in verbose and "from the noise alone (0.0004" in verbose


def test_verdict_comes_before_the_numbers():
    cal = Calibration(method="ferraris", sensors={"acc": SensorCalibration(
        offset=[0.3, 0, 0], sigma={"offset": [0.01] * 3, "matrix": np.full((3, 3), 1e-3)})})
    out = render(report.print_calibration, cal, None)
    assert out.index("verdict: GOOD (accelerometer good)") < out.index("acc: offset")
    assert "accelerometer: good — offsets known to ±0.01 m/s² (a level error of 0.058°)" in out


def test_recording_date_and_its_source_are_shown():
    tlog, bin_ = contents(fmt="tlog"), contents(fmt="bin")
    tlog.start_unix_s = bin_.start_unix_s = 1_780_000_000.5
    assert "recorded: 2026-05-28T20:26:40+00:00 (ground station clock)" in render(
        report.print_summary, report.summarize(tlog))
    assert "recorded: 2026-05-28T20:26:40+00:00 (GPS time)" in render(
        report.print_summary, report.summarize(bin_))
    assert "recorded" not in render(report.print_summary, report.summarize(contents()))


def test_calibration_parameter_changes_are_warned_in_the_summary():
    from apmcal.core.recording import ParamChange

    c = contents()
    c.param_changes = [ParamChange("INS_ACCOFFS_X", 0.1, 0.25, 5.0, "PARM record at byte 99")]
    summary = report.summarize(c)
    assert summary["param_changes"] == [
        "INS_ACCOFFS_X changed from 0.1 to 0.25 at t=5.000 s (PARM record at byte 99)"]
    assert ("warning: while recording, INS_ACCOFFS_X changed from 0.1 to 0.25 at t=5.000 s "
            "(PARM record at byte 99)") in render(report.print_summary, summary)
