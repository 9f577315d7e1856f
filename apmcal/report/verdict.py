"""Good / usable / redo: a calibration's numbers turned into a verdict a hobbyist can act on.

Solvers return numbers (σ, misfit, coverage, what they could not determine); this module alone
turns them into words: per sensor a grade, the reason in plain words and the next step, and an
overall grade (the worst sensor's). The report prints it before the numbers.

Thresholds, and why (1σ values, as reported):

* Accelerometer offset: an offset error δ tilts the level the autopilot holds by δ/g rad.
  good ≤ 0.05 m/s² (0.3° of level: below what a pilot notices in a hover), usable ≤ 0.2 m/s²
  (1.2°: drifts, but trims out), else redo.
* Accelerometer scale/cross-axis (matrix entries): good ≤ 0.005 (0.5 %), usable ≤ 0.02 (2 %,
  the spread ArduPilot's own six-face fit leaves), else redo.
* Six-face model misfit (:mod:`apmcal.solvers.misfit`): when the holds disagree with the model
  more than MISFIT_BIRGE times beyond their noise, the σ above already covers it, but the grade
  is at most usable and the user is told why (warm-up, faces not square, non-linear sensor).
* Gyro offset: good ≤ 0.002 rad/s (0.1 °/s, the stillness ArduPilot's own boot calibration
  demands), usable ≤ 0.01 rad/s, else redo. A gyro matrix left at identity (no full turns) is
  usable: ArduPilot has no gyro scale parameter, only the report loses it.
* Compass: coverage first. Samples nearly in one plane (smallest direction eigenvalue below
  MIN_SCATTER_FULL, the ellipsoid fit's own limit for trusting cross-axis terms) is redo; under
  MIN_MAG_FRACTION of the sphere within 20° of a sample is usable. Offset σ: good ≤ 1 % of the
  field (a 0.6° heading error at most), usable ≤ 5 % (3°), else redo.
* Plausibility before grading: a gyro offset beyond ±GYR_OFFSET_PLAUSIBLE_RAD_S (20 °/s, the
  largest zero-rate offset MPU-6000-class datasheets allow) is not a bias, it is motion or the wrong
  unit: redo whatever its σ.
* What the sensors read at rest with the calibration in force (the median |specific force| of
  the still periods against gravity, the compass's |field| against the WMM with --lat/--lon),
  whatever the method: a sensor the session could not measure but whose reading is implausible
  (|a| off g by ACC_AT_REST_MS2 or more, the same limit as ``apmcal fleet``'s; |B| off the WMM by
  MAG_AT_REST_FRACTION or more) is redo, not "not measured": the vehicle is wrong as it stands.
* Grade only what the session measured: a sensor the session could not determine (one still pose
  cannot tell the accelerometer's offset from a tilt; a compass that was not turned) is
  "not measured" — with the session that would measure it — and left out of the overall grade.
  A sensor whose parameters the firmware would refuse is redo.
* The overall grade is never "good" for a session whose proposal changes nothing the vehicle
  keeps: gyro offsets alone, which ArduPilot measures itself at every boot unless INS_GYR_CAL=0
  (ardupilot-facts.md). It is then NOTHING_TO_APPLY, naming what the session would need.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.solvers.coverage import MIN_SCATTER_FULL
from apmcal.solvers.magnetometer import NOT_MEASURED as MAG_NOT_MEASURED
from apmcal.solvers.report_types import CalibrationReport, MagneticField

GRADES = ("good", "usable", "redo")
NOT_MEASURED = "not measured"         # outside GRADES: left out of the overall grade
NOTHING_TO_APPLY = "nothing to apply"  # overall only: what was measured changes nothing
NAMES = {"acc": "accelerometer", "gyr": "gyroscope", "mag": "compass"}

ACC_OFFSET_SIGMA = (0.05, 0.2)        # m/s²: good, usable limits
ACC_MATRIX_SIGMA = (0.005, 0.02)      # dimensionless
GYR_OFFSET_SIGMA = (0.002, 0.01)      # rad/s
MAG_OFFSET_SIGMA = (0.01, 0.05)       # fraction of the field magnitude
MISFIT_BIRGE = 3.0                    # checks beyond 3× their noise: the model does not fit
MIN_MAG_FRACTION = 0.5                # half the sphere within 20° of a sample
GYR_OFFSET_PLAUSIBLE_RAD_S = 0.35     # 20 °/s: beyond any MEMS gyro's zero-rate offset at rest
ACC_AT_REST_MS2 = 0.3                 # | |a| − g | at rest, in force: apmcal fleet's limit too
MAG_AT_REST_FRACTION = 0.2            # | |B| − WMM | / WMM, in force: a heading error of ~10°+

SIX_FACES = ("hold the vehicle still on each of its six faces (level, on its back, each side, "
             "nose up, nose down) for 10 s or more")
SIX_FACE_SESSION = ("a six-face session measures it (apmcal live LINK --guide ardupilot6, or a "
                    "log of the vehicle held still on each of its six faces)")
COMPASS_SESSION = ("a compass session measures it: turn the vehicle slowly through every "
                   "direction while logging")
TURN_COMPASS = ("turn the vehicle slowly through every direction: nose up and down, each side "
                "down, upside down, and a full turn about each axis")


@dataclass
class Verdict:
    """One grade with its reason and next step (plain words).

    Attributes
    ----------
    grade : {"good", "usable", "redo", "not measured"}
    reason : str
        Why, in plain words.
    next_step : str
        What to do about it ("" when nothing is needed).
    """

    grade: str
    reason: str
    next_step: str = ""

    def to_dict(self) -> dict:
        """grade, reason and next_step as a plain dict."""
        return {"grade": self.grade, "reason": self.reason, "next_step": self.next_step}

    @property
    def measured(self) -> bool:
        """False for "not measured by this session" (left out of the overall grade)."""
        return self.grade != NOT_MEASURED


def not_measured(why: str, session: str) -> Verdict:
    """A sensor this session could not measure: why, and the session that would."""
    return Verdict(NOT_MEASURED, plain(why), session)


def plain(text: str) -> str:
    """A solver's message without pointers to lines only --verbose prints."""
    return text.replace(" (see the identifiability report)", " (--verbose shows why)")


def _grade(value: float, limits: tuple[float, float]) -> str:
    """good / usable / redo for ``value`` against its (good, usable) upper limits."""
    if not np.isfinite(value) or value > limits[1]:
        return "redo"
    return "good" if value <= limits[0] else "usable"


def worst(verdicts: list[Verdict]) -> Verdict:
    """The verdict with the worst grade (the first of equals): a chain is as good as its worst.

    Parameters
    ----------
    verdicts : list of Verdict
        At least one.

    Returns
    -------
    Verdict
    """
    return max(verdicts, key=lambda v: GRADES.index(v.grade))


def accelerometer(cal, report: CalibrationReport) -> Verdict:
    """Verdict on an accelerometer calibration (see the module doc for the thresholds).

    Parameters
    ----------
    cal : SensorCalibration
        Its sigma: "offset" (3,) [m/s²], "matrix" (3, 3) (dimensionless).
    report : CalibrationReport
        The run's findings (undetermined, six-face misfit, warnings).

    Returns
    -------
    Verdict
    """
    if "acc" in report.undetermined:
        return not_measured(report.undetermined["acc"], SIX_FACE_SESSION)
    sig = cal.sigma
    if "offset" not in sig:
        return Verdict("redo", "no uncertainty could be given for the offsets", SIX_FACES)
    off = float(np.max(sig["offset"]))
    mat = float(np.max(sig["matrix"])) if "matrix" in sig else 0.0
    found = [Verdict(_grade(off, ACC_OFFSET_SIGMA),
                     f"offsets known to {pm(off)} m/s² (a level error of "
                     f"{pm(np.degrees(off / 9.81))[1:]}°)",
                     "" if off <= ACC_OFFSET_SIGMA[0] else SIX_FACES),
             Verdict(_grade(mat, ACC_MATRIX_SIGMA), f"scales known to {pm(100 * mat)} %",
                     "" if mat <= ACC_MATRIX_SIGMA[0] else SIX_FACES)]
    misfit = report.six_face.misfit if report.six_face is not None else None
    if misfit is not None and misfit.birge_ratio > MISFIT_BIRGE:
        found.append(Verdict(
            "usable", f"the model does not fit: the holds disagree {misfit.birge_ratio:.0f}× "
                      f"more than their noise allows (up to {misfit.worst:.3f} m/s²), "
                      "so the ± values were widened to cover it (a board warming up between "
                      "holds, faces not square, or a sensor not quite linear)",
            "let the board warm up for 5 minutes before calibrating, then hold each face "
            "square and still"))
    noisy = [w for w in report.warnings if w.startswith("hold ")]
    if noisy:
        found.append(Verdict("usable", noisy[0], "hold each face still and square"))
    return worst(found)


def gyroscope(cal, report: CalibrationReport) -> Verdict:
    """Verdict on a gyro calibration (offset σ; a missing or odd full turn).

    Parameters
    ----------
    cal : SensorCalibration
        Its sigma: "offset" (3,) [rad/s].
    report : CalibrationReport
        The run's findings (undetermined, warnings).

    Returns
    -------
    Verdict
    """
    if "gyr" in report.undetermined:
        return not_measured(report.undetermined["gyr"], "keep the vehicle still for 10 s or more")
    big = float(np.max(np.abs(np.asarray(cal.offset, dtype=float))))
    if not np.isfinite(big) or big > GYR_OFFSET_PLAUSIBLE_RAD_S:
        return Verdict("redo", f"an offset of {np.degrees(big):.0f} °/s is beyond what a working "
                               "gyro reads at rest (±"
                               f"{np.degrees(GYR_OFFSET_PLAUSIBLE_RAD_S):.0f} °/s): the vehicle was "
                               "turning, the gyro is faulty, or the data are not in rad/s",
                       "keep the vehicle still; give a CSV's gyro in rad/s (or name the column "
                       "gyr_x[deg/s])")
    sig = cal.sigma.get("offset")
    if sig is None:
        return Verdict("redo", "no uncertainty could be given for the offsets",
                       "keep the vehicle still for a minute")
    off = float(np.max(sig))
    found = [Verdict(_grade(off, GYR_OFFSET_SIGMA),
                     f"offsets known to {pm(np.degrees(off))} °/s",
                     "" if off <= GYR_OFFSET_SIGMA[0] else "keep the vehicle stiller, longer")]
    turns = [w for w in report.warnings if w.startswith(("no 360° rotation", "rotation about"))]
    if turns:
        # ArduPilot stores gyro offsets only: a missing turn costs the report's gyro scale, not
        # the vehicle, so it neither lowers the grade nor asks for another session
        found[0].reason += "; gyro scale not reported (no full turns; ArduPilot has no gyro scale)"
    return worst(found)


def pm(sigma: float) -> str:
    """± σ with the two significant digits σ supports; never "±0.0000" (σ 0: "< 1e-9")."""
    if not np.isfinite(sigma):
        return "± ?"
    if sigma <= 0:
        return "± < 1e-9"
    return f"±{sigma:.2g}"


def compass(cal, report: CalibrationReport) -> Verdict:
    """Verdict on a compass calibration (coverage of directions, offset σ vs the field).

    Parameters
    ----------
    cal : SensorCalibration
        Its sigma: "offset" (3,) [mGauss].
    report : CalibrationReport
        The run's findings (magnetic field [mGauss] and its coverage, warnings).

    Returns
    -------
    Verdict
    """
    mf = report.magnetic_field or MagneticField(np.nan, "")
    field = float(mf.mgauss)
    min_eig = 1.0 if mf.coverage_min_eig is None else mf.coverage_min_eig
    fraction = 1.0 if mf.coverage_fraction is None else mf.coverage_fraction
    found = []
    if min_eig < MIN_SCATTER_FULL:
        return not_measured("the compass was barely turned: its readings lie close to one "
                            "plane, so offsets and soft iron across it would be guesses",
                            COMPASS_SESSION)
    elif fraction < MIN_MAG_FRACTION:
        found.append(Verdict("usable", f"the compass saw only {100 * fraction:.0f} % "
                                       "of the directions", TURN_COMPASS))
    sig = cal.sigma.get("offset")
    if sig is not None and field > 0:
        rel = float(np.max(sig)) / field
        found.append(Verdict(_grade(rel, MAG_OFFSET_SIGMA),
                             f"offsets known to {pm(float(np.max(sig)))} mGauss "
                             f"({100 * rel:.2g} % of the field)",
                             "" if rel <= MAG_OFFSET_SIGMA[0] else TURN_COMPASS))
    mismatch = [w for w in report.warnings if "field magnitude is" in w]
    if mismatch:
        found.append(Verdict("usable", "the field the compass saw differs from the model's at "
                                       "this site", "check --lat/--lon, then look for iron or "
                                                    "magnets near the vehicle"))
    return worst(found) if found else Verdict("usable", "no uncertainty could be given",
                                              TURN_COMPASS)


JUDGES = {"acc": accelerometer, "gyr": gyroscope, "mag": compass}


def judge(calibration, proposal=None, raw_counts=(), gyro_cal_at_boot=None
          ) -> dict[str, Verdict]:
    """Per-sensor verdicts and an "overall" one (the worst), in report order.

    ``proposal`` (ParamProposal or None): a sensor whose parameters the firmware would refuse
    is redo whatever its numbers. ``raw_counts``: sensors whose data are raw counts of no known
    unit (a CSV layout without a scale): their σ cannot be graded against thresholds in m/s² or
    rad/s, so they are "not measured" with the way to declare the unit. ``gyro_cal_at_boot``:
    the vehicle re-measures its gyro offsets at every boot (INS_GYR_CAL not 0; None: unknown):
    a proposal of gyro offsets alone then changes nothing (overall NOTHING_TO_APPLY).

    Parameters
    ----------
    calibration : Calibration
    proposal : ParamProposal, optional
    raw_counts : iterable of str, optional
    gyro_cal_at_boot : bool, optional

    Returns
    -------
    dict
        "acc", "gyr", "mag" (those calibrated or not calibrated) and "overall" → Verdict;
        empty when there is no sensor.
    """
    report = calibration.report
    out = {name: JUDGES[name](cal, report) for name, cal in calibration.sensors.items()
           if name in JUDGES}
    for name, why in report.not_calibrated.items():
        session = COMPASS_SESSION if name == "mag" else SIX_FACE_SESSION
        why = why.removeprefix("magnetometer not calibrated: ").removeprefix(
            f"{MAG_NOT_MEASURED}: ")
        # not measured: the session did not turn it enough (nothing wrong with the sensor);
        # any other failure is one of the data, and counts
        out[name] = (not_measured(why, session) if name in report.not_measured
                     else Verdict("redo", plain(why), session))
    for name in raw_counts:
        if name in out:
            out[name] = Verdict(NOT_MEASURED, "the data are raw counts of no known unit, so its "
                                              "offsets cannot be graded in physical units",
                                "declare the unit (a CSV header such as acc_x[g] or "
                                "gyr_x[deg/s]) to have it graded")
    for name, verdict in implausible_at_rest(report.at_rest).items():
        if name not in raw_counts and (name not in out or not out[name].measured):
            out[name] = verdict
    for name in _refused(proposal):
        out[name] = Verdict("redo", "the firmware would refuse its parameters (listed below)",
                            "check the mounting and the data, then calibrate again")
    if out:
        out["overall"] = overall(out)
        if changes_nothing(proposal, gyro_cal_at_boot) and out["overall"].grade != "redo":
            out["overall"] = Verdict(
                NOTHING_TO_APPLY, "this session measured the gyro offsets only, and ArduPilot "
                                  "measures those itself at every boot (INS_GYR_CAL)",
                next((v.next_step for v in out.values() if not v.measured),
                     SIX_FACE_SESSION))
    return out


def changes_nothing(proposal, gyro_cal_at_boot) -> bool:
    """True when every value proposed is a gyro offset and the vehicle re-measures those at
    every boot (ardupilot-facts.md: INS_GYROFFS, INS_GYR_CAL)."""
    values = {} if proposal is None else proposal.values
    return bool(gyro_cal_at_boot) and bool(values) and all(
        n.startswith(("INS_GYROFFS", "INS_GYR2OFFS", "INS_GYR3OFFS")) for n in values)


def implausible_at_rest(at_rest) -> dict[str, Verdict]:
    """"redo" verdicts for sensors whose reading at rest with the calibration in force is
    implausible (:class:`~apmcal.solvers.report_types.AtRest`; thresholds ACC_AT_REST_MS2,
    MAG_AT_REST_FRACTION), by sensor name; empty when all read plausibly or nothing is known."""
    out = {}
    if at_rest is None:
        return out
    acc, g = at_rest.acc_ms2, at_rest.gravity_ms2
    if acc is not None and g and abs(acc - g) >= ACC_AT_REST_MS2:
        out["acc"] = Verdict("redo", f"at rest it reads {acc:.2f} m/s² with the calibration in "
                                     f"force, {100 * abs(acc - g) / g:.0f} % "
                                     f"{'below' if acc < g else 'above'} gravity "
                                     f"({g:.2f} m/s²): the calibration in force is far off, or "
                                     "the accelerometer is faulty", SIX_FACE_SESSION)
    mag, wmm = at_rest.mag_mgauss, at_rest.wmm_mgauss
    if mag is not None and wmm and abs(mag - wmm) >= MAG_AT_REST_FRACTION * wmm:
        out["mag"] = Verdict("redo", f"it reads a field of {mag:.0f} mGauss with the calibration "
                                     f"in force where the World Magnetic Model has {wmm:.0f} "
                                     f"({100 * abs(mag - wmm) / wmm:.0f} % "
                                     f"{'less' if mag < wmm else 'more'}): the calibration in "
                                     "force is far off, or iron or a magnet is near the compass",
                             COMPASS_SESSION)
    return out


def overall(verdicts: dict[str, Verdict]) -> Verdict:
    """The worst grade of the sensors this session measured, naming the sensor; "not measured"
    when it measured none."""
    measured = {n: v for n, v in verdicts.items() if v.measured}
    if not measured:
        return Verdict(NOT_MEASURED, "this session measured no sensor",
                       next(iter(verdicts.values())).next_step)
    first = worst(list(measured.values()))
    who = next(NAMES[n] for n, v in measured.items() if v is first)
    return Verdict(first.grade, f"{who}: {first.reason}", first.next_step)


def _refused(proposal) -> list[str]:
    """Sensors with a parameter the firmware would refuse ("acc", "gyr", "mag")."""
    if proposal is None:
        return []
    prefixes = {"acc": "INS_ACC", "gyr": "INS_GYR", "mag": "COMPASS_"}
    return [s for s, p in prefixes.items() if any(n.startswith(p) for n in proposal.rejected)]


def redo_params(verdicts: dict[str, Verdict], proposal) -> dict[str, str]:
    """name → why, for the proposed values of a sensor graded redo (the values
    :class:`apmcal.ardupilot.limits.Writable` withholds unless the user accepts them)."""
    from apmcal.ardupilot.params import SENSOR_PARAM_PREFIXES

    out = {}
    for sensor, prefixes in SENSOR_PARAM_PREFIXES.items():
        v = verdicts.get(sensor)
        if proposal is None or v is None or v.grade != "redo":
            continue
        why = f"the {NAMES[sensor]} is graded REDO"
        out |= {n: why for n in proposal.values if n.startswith(prefixes)}
    return out
