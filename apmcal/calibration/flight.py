"""The compass from an ordinary flight: a health check of the calibration in force in heading
degrees, and a new COMPASS_* proposal with σ, per compass instance.

Steps (:func:`calibrate_flight`):

1. read the flight series (:func:`apmcal.sources.flight.read_flight`) and check it is a flight
   (:func:`flight_evidence`: attitude, compass, a position, movement or a level vehicle turned
   a full circle, heading change);
2. the WMM field at the mean GPS position and the log's date, with the model's own
   uncertainty (:mod:`apmcal.core.geomag`): the prior of the local field, which is fitted;
3. per compass: undo the correction in force, sample by sample with the logged offsets and
   motor compensation (ardupilot-facts.md "How the firmware applies the parameters": 4.x
   ``mag = SCALE·M·(raw + OFS) + MOT·x``; Copter 3.3/3.4 ``mag = M·(raw + OFS + MOT·x)``);
4. orientation: the fit is repeated with every ArduPilot rotation of the sensor
   (:func:`apmcal.solvers.compass_flight.orientation_scores`) and a rotation other than the one
   configured is named when it fits clearly better;
5. the fit itself (:func:`apmcal.solvers.compass_flight.fit_flight`: yaw-free, the logged yaw is
   never used), with COMPASS_MOT on the battery current when the log has one (MOTCT 2), else on
   the throttle (MOTCT 1); then every parameter the flight does not determine (σ over its
   limit, :data:`SIGMA_LIMITS`) is held at its value in force (soft iron first, then the motor
   term, then the offsets: :func:`apmcal.solvers.compass_flight.select_free`), named with the
   manoeuvre that would determine it, and never proposed;
6. the heading reference (:func:`apmcal.solvers.compass_heading.fit_reference`): the gyro's
   heading with its drift and the compass's sample delay fitted, anchored to the proposal; the
   fit is repeated once with the attitude at the instants the samples stand for;
7. heading health of the calibration in force and of the proposal
   (:mod:`apmcal.solvers.compass_heading`).

:class:`FlightResult` prints itself (:meth:`FlightResult.lines`, verdict in heading degrees
first), gives its JSON (:meth:`FlightResult.to_dict`) and the parameters to write
(:meth:`FlightResult.params`). Per compass (:class:`CompassFlight`): ``health_in_force`` and
``health_proposed`` (:class:`~apmcal.solvers.compass_heading.HeadingHealth`: ``p95_deg``,
``rms_deg``, ``verdict``), ``proposed`` and ``sigma`` (ArduPilot names; only identified
parameters), ``held`` (the parameters kept at their values in force) and ``local_field``.
"""
from __future__ import annotations

import datetime
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apmcal.ardupilot.firmware import (
    compass_matrix,
    compass_rotation,
    compass_scale,
    firmware_generation,
    mag_param_names,
)
from apmcal.ardupilot.orientation import ROTATIONS, rotation_matrix, rotation_name
from apmcal.core import geomag
from apmcal.core.errors import ApmcalError
from apmcal.solvers import compass_heading as heading
from apmcal.solvers.compass_flight import (
    ALL_PARAMS,
    PARAMS,
    FieldPrior,
    FlightFit,
    corrected,
    fit_flight,
    orientation_scores,
    select_free,
)
from apmcal.sources.flight import FlightData, MagSeries, read_flight

MAX_RATE_HZ = 25.0            # compass samples used per second at most
ORIENT_SAMPLES = 400          # samples per candidate in the orientation search
MIN_HEADING_SPAN_DEG = 90.0   # a flight turns at least this much
GROUND_TURN_DEG = 360.0       # a vehicle that never moved but turned this much, level: checked
MAX_GROUND_TILT = math.radians(30.0)
# the heading reference integrates the gyro between instants: a yaw turn of 90 °/s moves 9° per
# sample at 10 Hz, beyond which the integrated heading is no reference (telemetry's RAW_IMU is
# often streamed at 2-4 Hz)
MIN_GYRO_RATE_HZ = 10.0
MIN_CURRENT_SPAN_A = 5.0      # 5-95 % current span that lets COMPASS_MOT be fitted
MIN_THROTTLE_SPAN = 0.15
# σ above which a parameter counts as not determined by the flight: about 2.5° of heading for
# an offset in a 240 mGauss horizontal field, the same for DIA/ODI; the motor term over the
# drive's span
OFS_SIGMA_MGAUSS = 10.0
DIA_SIGMA = 0.04
MOTOR_SIGMA_MGAUSS = 5.0
SIGMA_LIMITS = np.array([OFS_SIGMA_MGAUSS] * 3 + [DIA_SIGMA] * 6 + [np.inf] * 5)
SOFT_IRON, OFFSETS, MOTOR = list(range(3, 9)), list(range(0, 3)), list(range(9, 12))
MAX_REFITS = 4                # refits with more parameters held, at most
RULE_OUT_SIGMAS = 3.0         # a value in force this many σ from the fit is not kept
MIN_DELAY_REFIT_S = 0.005     # a sample delay at least this large: the fit is repeated with it
MAX_TILT = math.radians(45.0)   # samples steeper than this are left out (heading ill-defined)
# samples this soon after boot are left out: the gyro is calibrated and the attitude aligned
# then (a log that starts at boot, LOG_DISARMED 1; one that starts at arming is not touched)
BOOT_SETTLE_S = 15.0
ORIENT_RATIO = 1.5            # configured rms / best rms above which another rotation is named
ORIENT_MARGIN_MGAUSS = 3.0
MANOEUVRE = {"iron": "two full turns of heading (720°), in the hover or driven in circles",
             "vertical": ("tilts of 10° or more, nose up and down and to either side, at several "
                          "headings (legs flown at speed in several directions; on the ground, a "
                          "slope driven up and down in several directions)"),
             "motor": "a climb at full throttle (and a slow descent), turning as it climbs"}
# which manoeuvre determines each parameter (index in ALL_PARAMS)
DETERMINED_BY = {0: "iron", 1: "iron", 3: "iron", 4: "iron", 6: "iron",
                 2: "vertical", 5: "vertical", 7: "vertical", 8: "vertical"}


def param_names(instance: int) -> dict[str, str]:
    """``PARAMS`` entry → ArduPilot parameter name for one compass instance."""
    n = mag_param_names(instance)
    out = dict(zip(PARAMS[0:3], n["ofs"]))
    out.update(zip(PARAMS[3:6], n["dia"]))
    out.update(zip(PARAMS[6:9], n["odi"]))
    out.update(zip(PARAMS[9:12], mag_param_names(instance)["mot"]))
    return out


def motor_after_matrix(firmware: str | None) -> bool:
    """True for 4.x ``correct_field`` (MOT added after the matrix), False for Copter 3.3/3.4
    (inside it); unknown firmware counts as current."""
    if firmware:
        import re
        m = re.search(r"V(\d+)\.(\d+)", firmware)
        if m and (int(m.group(1)), int(m.group(2))) < (3, 5):
            return False
    return True


def undo(mag: MagSeries, params: dict, instance: int, after: bool) -> np.ndarray:
    """Uncorrected body-frame field (n, 3) [mGauss] of one compass: SCALE and M(DIA, ODI) in
    force, the offsets and the motor compensation of each sample taken back out.

    The MAG record logs offsets and motor compensation cut to whole mGauss (ardupilot-facts.md,
    "Flight records the flight compass check reads"). The offsets: where the logged ones agree
    with COMPASS_OFS within 1 mGauss the exact parameter values are used, else (offsets learnt
    in flight) the logged ones. The motor compensation: the logged one, untruncated
    (:func:`untruncated`), always — it is the firmware's own at the instant of the sample,
    where COMPASS_MOT times a current logged apart (BAT, 10 Hz) would be off by COMPASS_MOT
    times the current's change in between.
    """
    m = compass_matrix(params, instance) * compass_scale(params, instance)
    if abs(np.linalg.det(m)) < 1e-9:
        raise ApmcalError("compass matrix from COMPASS_DIA/ODI is singular, cannot undo it",
                          where=f"compass {instance}")
    names = mag_param_names(instance)["ofs"]
    offsets = mag.offsets
    if all(n in params for n in names):
        ofs = np.array([float(params[n]) for n in names])
        if np.all(np.abs(mag.offsets - ofs) <= 1.0):
            offsets = np.broadcast_to(ofs, mag.offsets.shape)
    motor = untruncated(mag.motor)
    inv = np.linalg.inv(m)
    logged = untruncated(mag.field)
    if after:
        return (logged - motor) @ inv.T - offsets
    return logged @ inv.T - offsets - motor


def untruncated(values: np.ndarray) -> np.ndarray:
    """The mean of what whole-mGauss MAG values stand for: the firmware casts each field
    component to int16, which truncates toward zero (libraries/AP_Compass/
    AP_Compass_logging.cpp, ``Compass::Write_Compass_instance``: ``(int16_t)mag_field.x``), so
    a logged v ≠ 0 stands for v + ½·sign(v) on average (0 for 0). Left as they are, the
    truncation biases every component by half a mGauss toward zero: the vertical one by a
    constant (OFS_Z), the horizontal ones by a shrink of the heading circle (DIA)."""
    return values + 0.5 * np.sign(values)


# ----------------------------------------------------------------------------- recognising
def heading_span_deg(fd: FlightData) -> float:
    """Range of the heading change along the log [deg]: from the gyro when logged, else from
    the logged yaw (unwrapped; only the change is used, not its absolute value)."""
    if fd.att_t is None:
        return 0.0
    if fd.gyr is not None and len(fd.gyr_t) > 2:
        psi = heading.gyro_heading(fd.gyr_t, fd.gyr, fd.att_t, fd.roll, fd.pitch, fd.gyr_t)
    else:
        psi = np.unwrap(fd.yaw)
    return float(np.degrees(psi.max() - psi.min()))


def turned_on_the_ground(fd: FlightData) -> bool:
    """True for a vehicle that stayed level (roll and pitch within ``MAX_GROUND_TILT``) and
    turned its heading through ``GROUND_TURN_DEG`` or more: a large copter or a boat yawed on
    the spot, which never moves but whose turns determine the horizontal iron."""
    if fd.att_t is None or len(fd.att_t) < 2:
        return False
    level = np.all(np.abs(fd.roll) < MAX_GROUND_TILT) and np.all(np.abs(fd.pitch) < MAX_GROUND_TILT)
    return bool(level and heading_span_deg(fd) >= GROUND_TURN_DEG)


def flight_evidence(fd: FlightData, site: tuple[float, float] | None = None) -> tuple[bool, str]:
    """(is a flight, why or why not): attitude (ATT), a compass (MAG), a position (a GPS fix or
    ``site``), movement (GPS speed over 1 m/s, or throttle over 0.2; or a vehicle turned a
    full circle while level, :func:`turned_on_the_ground`) and a heading change of at least
    ``MIN_HEADING_SPAN_DEG``."""
    if fd.att_t is None:
        return False, "no ATT attitude records"
    if not fd.mags:
        return False, "no MAG compass records"
    if fd.lat is None and site is None:
        return False, "no GPS fix (and no --lat/--lon) for the expected magnetic field"
    moving = ((fd.speed is not None and np.nanmax(fd.speed) > 1.0)
              or (fd.throttle is not None and np.nanmax(fd.throttle) > 0.2))
    if not moving and not turned_on_the_ground(fd):
        return False, "the vehicle never moved (GPS speed ≤ 1 m/s, throttle ≤ 0.2)"
    if fd.gyr_t is not None and len(fd.gyr_t) > 2:
        rate = (len(fd.gyr_t) - 1) / max(float(fd.gyr_t[-1] - fd.gyr_t[0]), 1e-9)
        if rate < MIN_GYRO_RATE_HZ:
            return False, (f"the gyro is logged at {rate:.1f} Hz, too slow to follow the heading "
                           f"(need {MIN_GYRO_RATE_HZ:g} Hz)")
    span = heading_span_deg(fd)
    if span < MIN_HEADING_SPAN_DEG:
        return False, f"the heading changed only {span:.0f}° (need {MIN_HEADING_SPAN_DEG:.0f}°)"
    return True, f"a flight: heading changed over {span:.0f}°, attitude, compass and position"


# ----------------------------------------------------------------------------- results
@dataclass
class Orientation:
    """The orientation search of one compass: configured code, best code, rms [mGauss] of
    each candidate, and whether the best one replaces the configured one."""

    configured: int
    best: int
    scores: dict[int, float]
    wrong: bool

    def evidence(self) -> str:
        """One line naming the rotation that fits and the numbers behind it."""
        cfg, best = self.scores.get(self.configured, math.inf), self.scores[self.best]
        if not math.isfinite(best) and not math.isfinite(cfg):
            return ("no ArduPilot rotation lets a soft-iron matrix within limits match the WMM "
                    "field: check the site (--lat/--lon) and look for magnetic disturbance")
        ranked = sorted((v, k) for k, v in self.scores.items() if k != self.best)
        nxt = (f"; next best {rotation_name(ranked[0][1])} {ranked[0][0]:.1f}"
               if ranked and math.isfinite(ranked[0][0]) else "")
        if len(self.scores) == 1:
            nxt = (f"; no other rotation can fit {ORIENT_MARGIN_MGAUSS:g} mGauss better, none "
                   "tried")
        if not self.wrong:
            return (f"orientation {rotation_name(self.configured)} ({self.configured}) confirmed:"
                    f" {cfg:.1f} mGauss rms{nxt}")
        cfg_s = (f"{cfg:.1f} as configured" if math.isfinite(cfg) else
                 "no soft-iron matrix within limits fits as configured")
        return (f"mounted as {rotation_name(self.best)} ({self.best}), not "
                f"{rotation_name(self.configured)} ({self.configured}): {best:.1f} mGauss rms, "
                f"{cfg_s}{nxt}")

    def to_dict(self) -> dict:
        """JSON form."""
        return {"configured": self.configured, "best": self.best, "wrong": self.wrong,
                "rms_mgauss": {rotation_name(k): v for k, v in sorted(self.scores.items())},
                "evidence": self.evidence()}


@dataclass
class LocalField:
    """The Earth field of the flight: the model's (prior) and the fitted intensity [mGauss] and
    inclination [deg], each with σ, and the model's declination [deg]."""

    model_mgauss: float
    model_sigma_mgauss: float
    model_inclination_deg: float
    model_sigma_inclination_deg: float
    declination_deg: float
    fitted_mgauss: float = float("nan")
    fitted_sigma_mgauss: float = float("nan")
    fitted_inclination_deg: float = float("nan")
    fitted_sigma_inclination_deg: float = float("nan")

    def ned(self) -> np.ndarray:
        """The fitted field (the model's where not fitted) [mGauss, NED]."""
        f = self.fitted_mgauss if math.isfinite(self.fitted_mgauss) else self.model_mgauss
        i = math.radians(self.fitted_inclination_deg if math.isfinite(self.fitted_inclination_deg)
                         else self.model_inclination_deg)
        d = math.radians(self.declination_deg)
        return f * np.array([math.cos(i) * math.cos(d), math.cos(i) * math.sin(d), math.sin(i)])

    def line(self) -> str:
        """One line: fitted beside the model."""
        return (f"local field {self.fitted_mgauss:.1f} ± {self.fitted_sigma_mgauss:.1f} mGauss, "
                f"inclination {self.fitted_inclination_deg:.2f} ± "
                f"{self.fitted_sigma_inclination_deg:.2f}° (WMM {self.model_mgauss:.1f} ± "
                f"{self.model_sigma_mgauss:.1f}, {self.model_inclination_deg:.2f} ± "
                f"{self.model_sigma_inclination_deg:.2f}°)")

    def to_dict(self) -> dict:
        """JSON form."""
        return dict(self.__dict__)


@dataclass
class CompassFlight:
    """One compass: values in force and proposed (ArduPilot names; only what the flight
    identified), σ, the parameters held at their values in force (with the σ they would have
    had), health before/after, orientation, the local field, the heading reference, and what
    was not identified with the manoeuvre that would identify it."""

    instance: int
    in_force: dict[str, float]
    proposed: dict[str, float]
    sigma: dict[str, float]
    health_in_force: heading.HeadingHealth
    health_proposed: heading.HeadingHealth
    orientation: Orientation | None
    drive: str | None                     # "current" [A], "throttle" or None
    drive_span: float
    unidentified: list[tuple[str, str]] = field(default_factory=list)   # (what, manoeuvre)
    rms_mgauss: float = float("nan")
    valid: bool = True          # False: the fit sits on ArduPilot's limits, nothing proposed
    held: dict[str, float] = field(default_factory=dict)          # name → value in force
    held_sigma: dict[str, float] = field(default_factory=dict)    # name → σ had it been fitted
    local_field: LocalField | None = None
    reference: str = ""
    sample_delay_s: float = 0.0
    correlation_factor: float = 1.0

    def series(self, max_points: int = 600) -> dict:
        """Heading error along the flight [deg], in force and proposed, at most ``max_points``
        samples (t [s] on the log's clock): what a report plots."""
        h0, h1 = self.health_in_force, self.health_proposed
        step = max(1, -(-len(h0.t) // max_points))
        return {"t_s": h0.t[::step], "in_force_deg": h0.error_deg[::step],
                "proposed_deg": h1.error_deg[::step]}

    def to_dict(self) -> dict:
        """JSON form (no per-sample arrays except the decimated heading errors)."""
        return {"instance": self.instance, "heading_error_series": self.series(),
                "in_force": self.in_force, "proposed": self.proposed,
                "sigma": self.sigma, "held_in_force": self.held,
                "held_sigma_if_fitted": self.held_sigma,
                "in_force_health": self.health_in_force.to_dict(),
                "proposed_health": self.health_proposed.to_dict(),
                "orientation": self.orientation.to_dict() if self.orientation else None,
                "motor_drive": self.drive, "motor_drive_span": self.drive_span,
                "fit_rms_mgauss": self.rms_mgauss, "proposal_valid": self.valid,
                "local_field": self.local_field.to_dict() if self.local_field else None,
                "heading_reference": self.reference, "sample_delay_s": self.sample_delay_s,
                "sigma_correlation_factor": self.correlation_factor,
                "not_identified": [{"what": w, "manoeuvre": m} for w, m in self.unidentified]}


@dataclass
class FlightResult:
    """The flight compass check of one log (see the module docstring)."""

    path: str
    duration_s: float
    field_ned: np.ndarray
    declination_deg: float
    inclination_deg: float
    compasses: list[CompassFlight]
    reference: str
    notes: list[str] = field(default_factory=list)
    field_sigma_mgauss: float = float("nan")
    inclination_sigma_deg: float = float("nan")

    @property
    def verdict(self) -> str:
        """The first compass's verdict on the calibration in force."""
        return self.compasses[0].health_in_force.verdict if self.compasses else "redo"

    def params(self) -> dict[str, float]:
        """Every proposed COMPASS_* value (all compasses)."""
        out = {}
        for c in self.compasses:
            if c.valid:
                out.update(c.proposed)
        return out

    def lines(self) -> list[str]:
        """The console report: verdict in heading degrees first, then the parameters."""
        b = self.field_ned
        out = [f"Compass in flight: {Path(self.path).name}, {self.duration_s:.0f} s; WMM "
               f"{np.linalg.norm(b):.0f} ± {self.field_sigma_mgauss:.1f} mGauss, inclination "
               f"{self.inclination_deg:.1f} ± {self.inclination_sigma_deg:.1f}°, declination "
               f"{self.declination_deg:.1f}°"]
        for c in self.compasses:
            hi, hp = c.health_in_force, c.health_proposed
            new = (f"proposed {hp.verdict.upper()} — 95 % {hp.p95_deg:.1f}° (rms "
                   f"{hp.rms_deg:.1f}°)" if c.valid else
                   "no proposal: no correction within ArduPilot's DIA/ODI limits matches "
                   "the field")
            out.append(f"  compass {c.instance}: calibration in force {hi.verdict.upper()} — "
                       f"heading error 95 % {hi.p95_deg:.1f}° (rms {hi.rms_deg:.1f}°, max "
                       f"{hi.max_deg:.1f}°); {new}")
            out.append(f"    field residual against the fitted field: {hi.field_rms_mgauss:.0f} → "
                       f"{hp.field_rms_mgauss:.0f} mGauss rms")
            if c.local_field is not None and c.valid:
                out.append(f"    {c.local_field.line()}")
        for c in self.compasses:
            out.append(f"  compass {c.instance} heading reference: {c.reference}")
        for c in self.compasses:
            if c.orientation is not None:
                out.append(f"  compass {c.instance}: {c.orientation.evidence()}")
            for what, how in c.unidentified:
                out.append(f"  compass {c.instance}: {what} — what determines it: {how}")
        out.append("Proposed parameters (in force → proposed ± σ; only what the flight "
                   "identified):")
        for c in (c for c in self.compasses if c.valid):
            for name, value in c.proposed.items():
                old = c.in_force.get(name)
                old_s = "—" if old is None else f"{old:g}"
                sig = c.sigma.get(name)
                sig_s = f" ± {sig:.3g}" if sig else ""
                out.append(f"  {name:<18} {old_s:>10} → {value:.4g}{sig_s}")
        out += [f"  note: {n}" for n in self.notes]
        return out

    def to_dict(self) -> dict:
        """JSON form."""
        return {"method": "flight", "path": self.path, "duration_s": self.duration_s,
                "verdict": self.verdict, "earth_field_ned_mgauss": self.field_ned.tolist(),
                "earth_field_sigma_mgauss": self.field_sigma_mgauss,
                "declination_deg": self.declination_deg, "inclination_deg": self.inclination_deg,
                "inclination_sigma_deg": self.inclination_sigma_deg,
                "heading_reference": self.reference, "params": self.params(),
                "compasses": [c.to_dict() for c in self.compasses], "notes": self.notes}

    def save_json(self, path) -> None:
        """Write :meth:`to_dict` as JSON."""
        from apmcal.core.json_file import jsonable
        try:
            Path(path).write_text(json.dumps(jsonable(self.to_dict(), nan_as_null=True),
                                             indent=2) + "\n")
        except OSError as e:
            raise ApmcalError(f"cannot write JSON: {e.strerror or e}", str(path)) from None


# ----------------------------------------------------------------------------- the fit
def _decimate(mag: MagSeries) -> MagSeries:
    if len(mag.t) < 3:
        return mag
    rate = 1.0 / max(float(np.median(np.diff(mag.t))), 1e-6)
    step = max(1, int(round(rate / MAX_RATE_HZ)))
    s = slice(None, None, step)
    return MagSeries(mag.instance, mag.t[s], mag.field[s], mag.offsets[s], mag.motor[s])


def _drive(fd: FlightData, t: np.ndarray,
           only: str | None = None) -> tuple[np.ndarray, str | None, float]:
    """(drive at t, "current"/"throttle"/None, its 5-95 % span); current first unless ``only``
    names one."""
    for kind, tt, vv in (("current", fd.current_t, fd.current),
                         ("throttle", fd.throttle_t, fd.throttle)):
        if only not in (None, kind):
            continue
        if tt is not None and len(tt) > 1:
            x = np.interp(t, tt, np.nan_to_num(vv))
            lo, hi = np.percentile(x, [5, 95])
            return x, kind, float(hi - lo)
    return np.zeros(len(t)), None, 0.0


def _site_field(fd: FlightData, site, notes) -> tuple[np.ndarray, FieldPrior]:
    """The WMM field [mGauss, NED] at the flight's site and date, and the prior of the local
    field (its intensity and inclination with the WMM's own σ)."""
    if fd.lat is not None:
        lat, lon, alt = float(np.median(fd.lat)), float(np.median(fd.lon)), float(np.median(fd.alt))
    else:
        lat, lon, alt = site[0], site[1], 0.0
    if fd.boot_unix_s is not None:
        when = datetime.datetime.fromtimestamp(fd.boot_unix_s + float(fd.att_t[0]),
                                               tz=datetime.timezone.utc)
    else:
        when = datetime.datetime.now(datetime.timezone.utc)
        notes.append("the log carries no GPS date: the WMM field of today is used")
    year = geomag.decimal_year(when)
    b, note = geomag.earth_field_ned(lat, lon, alt, year)
    if note:
        notes.append(note)
    sigma_f, sigma_i_deg, _ = geomag.field_uncertainty(lat, lon, alt, year)
    return b, FieldPrior.from_ned(b, sigma_f, math.radians(sigma_i_deg))


def _candidates() -> dict[int, np.ndarray]:
    out: dict[int, np.ndarray] = {}
    for code in ROTATIONS:
        r = rotation_matrix(code)
        if not any(np.allclose(r, q, atol=1e-6) for q in out.values()):
            out[code] = r
    return out


def attitude_at(fd: FlightData, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Logged roll and pitch [rad] interpolated to ``t`` (unwrapped first, so that a roll
    through ±180° is not interpolated through 0), wrapped to (−π, π]."""
    def at(a):
        v = np.interp(t, fd.att_t, np.unwrap(a))
        return (v + np.pi) % (2 * np.pi) - np.pi
    return at(fd.roll), at(fd.pitch)


def _configured_orientation(params: dict, instance: int) -> int:
    n = mag_param_names(instance)
    if params.get(n["external"], 0):
        return int(params.get(n["orient"], 0))
    return int(params.get("AHRS_ORIENTATION", 0))


def _orientation(raw_sensor, roll, pitch, x, prior, fixed, configured) -> Orientation:
    """The orientation search; skipped (only the configured rotation scored) when the
    configured one leaves at most ``ORIENT_MARGIN_MGAUSS`` rms, which no other rotation can
    beat by the margin that names it."""
    step = max(1, len(raw_sensor) // ORIENT_SAMPLES)
    s = slice(None, None, step)
    own = orientation_scores(raw_sensor[s], {configured: rotation_matrix(configured)}, roll[s],
                             pitch[s], x[s], prior, fixed)
    if own[configured] <= ORIENT_MARGIN_MGAUSS:
        return Orientation(configured, configured, own, False)
    scores = orientation_scores(raw_sensor[s], _candidates(), roll[s], pitch[s], x[s], prior,
                                fixed)
    cfg = next((k for k in scores if np.allclose(rotation_matrix(k),
                                                 rotation_matrix(configured), atol=1e-6)), None)
    best = min(scores, key=scores.get)
    cfg_rms = scores.get(cfg, math.inf) if cfg is not None else math.inf
    wrong = (best != cfg and (cfg_rms > ORIENT_RATIO * scores[best] + ORIENT_MARGIN_MGAUSS))
    return Orientation(configured, best if wrong else configured, scores, wrong)


def in_force_vector(params: dict, instance: int, prior: FieldPrior) -> np.ndarray:
    """The calibration in force in the fit's parameters (``ALL_PARAMS``: M includes SCALE),
    the field at its prior."""
    names = mag_param_names(instance)
    m = compass_matrix(params, instance) * compass_scale(params, instance)
    x = np.zeros(len(ALL_PARAMS))
    x[0:3] = [float(params.get(n, 0.0)) for n in names["ofs"]]
    x[3:6] = np.diag(m)
    x[6:9] = m[0, 1], m[0, 2], m[1, 2]
    x[9:12] = [float(params.get(n, 0.0)) for n in names["mot"]]
    x[12:14] = prior.mean
    return x


@dataclass
class _Drives:
    """The drive the motor term is fitted on (the log's best) and the one in force (its
    COMPASS_MOTCT), each at the compass samples, with the kind, span and whether the log's
    drive varies enough to try fitting it."""

    fit: np.ndarray
    kind: str | None
    span: float
    in_force: np.ndarray
    in_force_mot: np.ndarray        # COMPASS_MOT in force, or zeros when no drive carries it
    possible: bool


def _drives(fd: FlightData, t: np.ndarray, params: dict, instance: int) -> _Drives:
    x, kind, span = _drive(fd, t)
    motct = int(params.get("COMPASS_MOTCT", 0))
    mot0 = np.array([float(params.get(n, 0.0)) for n in mag_param_names(instance)["mot"]])
    drive0, kind0 = np.zeros(len(t)), None
    if motct in (1, 2):
        drive0, kind0, _ = _drive(fd, t, "current" if motct == 2 else "throttle")
    if kind0 is None:
        mot0 = np.zeros(3)
    possible = kind is not None and span >= (MIN_CURRENT_SPAN_A if kind == "current"
                                             else MIN_THROTTLE_SPAN)
    return _Drives(x, kind, span, drive0, mot0, possible)


@dataclass
class _Identified:
    """:func:`_identified_fit`'s answer: the final fit, the iron parameters held at their values
    in force (indices) with the σ each would have had, whether the motor term was fitted, the
    drive the fit used, and the motor term's σ [per unit of drive] when it was tried."""

    fit: FlightFit
    held: list[int]
    would_be_sigma: dict[int, float]
    motor: bool
    drive: np.ndarray
    motor_sigma: np.ndarray | None
    limits: np.ndarray

    def weak(self) -> list[int]:
        """Fitted parameters whose σ is over its limit: kept fitted because the flight rules
        the value in force out, but determined no better than that σ."""
        sig = self.fit.sigma
        return [k for k in range(12) if k not in self.fit.fixed and sig[k] > self.limits[k]]


def _identified_fit(raw, roll, pitch, drives: _Drives, prior: FieldPrior, x_force: np.ndarray,
                    t: np.ndarray, x0=None) -> _Identified:
    """Fit everything, hold what the flight does not determine at its value in force (soft
    iron first, then the motor term as a whole, then offsets), refit with it held."""
    motor_fixed = {k: float(v) for k, v in zip(MOTOR, drives.in_force_mot)}
    limits = SIGMA_LIMITS.copy()
    motor_sigma = None
    force = x_force.copy()
    force[MOTOR] = drives.in_force_mot
    if drives.possible:
        limits[MOTOR] = MOTOR_SIGMA_MGAUSS / max(drives.span, 1e-9)
        fit = fit_flight(raw, roll, pitch, drives.fit, prior, x0=x0, t=t)
        motor_sigma = fit.sigma[MOTOR]
        held = select_free(fit, limits, [SOFT_IRON, MOTOR, OFFSETS], force)
        if any(k in MOTOR for k in held):
            # one compensation: held as a whole where the flight cannot rule the value in
            # force out, else fitted as a whole
            sig = fit.conditional_sigma([k for k in held if k not in MOTOR])
            if np.all(np.abs(fit.x[MOTOR] - force[MOTOR]) <= RULE_OUT_SIGMAS * sig[MOTOR]):
                held = MOTOR + select_free(_conditioned(fit, MOTOR), limits,
                                           [SOFT_IRON, OFFSETS], force)
            else:
                held = select_free(fit, limits, [SOFT_IRON, OFFSETS], force)
    else:
        fit = fit_flight(raw, roll, pitch, drives.in_force, prior, fixed=motor_fixed, x0=x0,
                         t=t)
        held = select_free(fit, limits, [SOFT_IRON, OFFSETS], force)
    motor = drives.possible and MOTOR[0] not in held
    iron = [k for k in held if k not in MOTOR]
    would = {k: float(fit.conditional_sigma([j for j in held if j != k])[k]) for k in iron}
    drive = drives.fit if motor else drives.in_force
    refits = 0
    while held:
        fixed = {k: float(x_force[k]) for k in iron}
        if not motor:
            fixed.update(motor_fixed)
        fit = fit_flight(raw, roll, pitch, drive, prior, fixed=fixed, x0=fit.x, t=t)
        refits += 1
        # held values in force that fit worse widen the others' σ: hold any now over its limit
        more = (select_free(fit, limits, [SOFT_IRON, OFFSETS], force) if refits < MAX_REFITS
                else [])
        if not more:
            break
        would.update({k: float(fit.conditional_sigma([j for j in more if j != k])[k])
                      for k in more})
        iron += more
    return _Identified(fit, iron, would, motor, drive, motor_sigma, limits)


def _conditioned(fit: FlightFit, held: list[int]) -> FlightFit:
    """The same fit seen with ``held`` fixed too (for :func:`select_free`'s σ)."""
    return FlightFit(fit.x, fit.cov, fit.rms, fit.n_used, fit.correlation_factor,
                     tuple(sorted(set(fit.fixed) | set(held))), fit.bread, fit.meat)

def _unidentified(ident: _Identified, names: dict[str, str], in_force: dict[str, float],
                  drives: _Drives) -> list[tuple[str, str]]:
    """(what, manoeuvre) for every parameter held at its value in force, grouped by the
    manoeuvre that would determine it, each with its value and the σ it would have had."""
    out = []
    weak = ident.weak()
    for how in ("iron", "vertical"):
        items = [k for k in ident.held if DETERMINED_BY[k] == how]
        if items:
            listed = ", ".join(f"{names[PARAMS[k]]} {in_force[names[PARAMS[k]]]:g} (σ would be "
                               f"{_fmt_sigma(ident.would_be_sigma[k], k)})" for k in items)
            out.append((f"kept at the value in force, not identified by this flight: {listed}",
                        MANOEUVRE[how]))
        items = [k for k in weak if DETERMINED_BY.get(k) == how]
        if items:
            listed = ", ".join(f"{names[PARAMS[k]]} ± {_fmt_sigma(ident.fit.sigma[k], k)}"
                               for k in items)
            out.append((f"proposed but weakly determined (the flight rules the value in force "
                        f"out, no more): {listed}", MANOEUVRE[how]))
    if ident.motor and any(k in MOTOR for k in weak):
        out.append((f"COMPASS_MOT proposed but weakly determined (σ of MOT × span "
                    f"{float(np.max(ident.fit.sigma[MOTOR])) * drives.span:.2g} mGauss; the "
                    f"flight rules the value in force out, no more)", MANOEUVRE["motor"]))
    if not ident.motor:
        kind, span = drives.kind, drives.span
        unit = " A" if kind == "current" else ""
        if kind is None:
            what = "no current or throttle in the log"
        elif not drives.possible:
            what = f"the {kind} varied only {span:.2g}{unit}, 5-95 %"
        else:
            worst = float(np.max(ident.motor_sigma)) * span
            what = (f"the {kind} changes, {span:.2g}{unit}, came with too little else changing "
                    f"to separate it from the offsets: σ of MOT × span {worst:.2g} mGauss")
        out.append((f"COMPASS_MOT kept at the value in force, not identified by this flight "
                    f"({what})", MANOEUVRE["motor"]))
    return out


def _fmt_sigma(s: float, k: int) -> str:
    if not math.isfinite(s) or s > 1e3:
        return "unbounded"
    return f"{s:.2g} mGauss" if k in OFFSETS else f"{s:.2g}"


def _heading_of(fd, t, field_of, decl):
    """delay [s] → compass headings [rad] of ``field_of`` (n, 3) with the attitude at
    t − delay."""
    def at(delay):
        roll, pitch = attitude_at(fd, t - delay)
        return heading.compass_heading(field_of, roll, pitch, decl)
    return at


def _fit_compass(fd, mag, params, generation, after, prior, field_ned, decl, source,
                 check_orientation) -> CompassFlight:
    inst = mag.instance
    t = mag.t
    roll, pitch = attitude_at(fd, t)
    drives = _drives(fd, t, params, inst)
    raw_body = undo(mag, params, inst, after)
    r_cfg = compass_rotation(params, generation, inst)
    raw_sensor = raw_body @ r_cfg                       # v_sensor = R_cfgᵀ·v_body, as rows
    configured = _configured_orientation(params, inst)
    x_force = in_force_vector(params, inst, prior)
    orient = None
    r_use = r_cfg
    if check_orientation:
        fixed = {} if drives.possible else dict(zip(MOTOR, drives.in_force_mot))
        drive = drives.fit if drives.possible else drives.in_force
        orient = _orientation(raw_sensor, roll, pitch, drive, prior, fixed, configured)
        if orient.wrong:
            r_use = rotation_matrix(orient.best)
    raw = raw_sensor @ r_use.T
    # no rotation lets a matrix within limits fit (the orientation search says so), or the
    # fit sits on them: the compass does not match the field, nothing is proposed, and the
    # reference is anchored to the calibration in force instead
    nowhere = orient is not None and not any(map(math.isfinite, orient.scores.values()))

    def anchor(ident):
        if nowhere or ident.fit.at_limits:
            return mag.field
        return corrected(ident.fit.x, raw, ident.drive)

    ident = _identified_fit(raw, roll, pitch, drives, prior, x_force, t)
    # the reference, then the fit again with the attitude at the instants the samples stand for
    ref = heading.fit_reference(t, None, source, _heading_of(fd, t, anchor(ident), decl))
    if abs(ref.delay_s) >= MIN_DELAY_REFIT_S:
        roll, pitch = attitude_at(fd, t - ref.delay_s)
        drives = _drives(fd, t - ref.delay_s, params, inst)
        ident = _identified_fit(raw, roll, pitch, drives, prior, x_force, t, x0=ident.fit.x)
        ref = heading.fit_reference(t, None, source, _heading_of(fd, t, anchor(ident), decl),
                                    delays_s=np.array([ref.delay_s]))
        roll, pitch = attitude_at(fd, t - ref.delay_s)
    fit = ident.fit
    names = param_names(inst)
    s0 = compass_scale(params, inst)
    values, sig = fit.x.copy(), fit.sigma.copy()
    values[3:9] /= s0
    sig[3:9] /= s0
    free = [k for k in range(12) if k not in fit.fixed]
    proposed = {names[PARAMS[k]]: float(values[k]) for k in free}
    sigma = {names[PARAMS[k]]: float(sig[k]) for k in free}
    if ident.motor:
        proposed["COMPASS_MOTCT"] = 2.0 if drives.kind == "current" else 1.0
    if orient is not None and orient.wrong:
        n = mag_param_names(inst)
        proposed[n["orient"]] = float(orient.best)
        if not params.get(n["external"], 0):
            proposed[n["external"]] = 2.0        # ForcedExternal: COMPASS_ORIENTn then applies
    held_names = {names[PARAMS[k]]: float(x_force[k] / (s0 if 3 <= k < 9 else 1.0))
                  for k in ident.held}
    if not ident.motor:
        held_names.update({names[PARAMS[k]]: float(drives.in_force_mot[i])
                           for i, k in enumerate(MOTOR)})
    in_force = {k: float(params[k]) for k in list(proposed) + list(held_names) if k in params}
    in_force.update({k: v for k, v in held_names.items() if k not in in_force})
    would = {names[PARAMS[k]]: v / (s0 if 3 <= k < 9 else 1.0)
             for k, v in ident.would_be_sigma.items()}
    b_new = corrected(fit.x, raw, ident.drive)
    local = LocalField(prior.intensity_mgauss, prior.sigma_intensity_mgauss,
                       math.degrees(prior.inclination_rad),
                       math.degrees(prior.sigma_inclination_rad), math.degrees(decl),
                       float(fit.x[12]), float(fit.sigma[12]), math.degrees(fit.x[13]),
                       math.degrees(fit.sigma[13]))
    expected = local.ned()
    h_old = heading.heading_health(t, mag.field, roll, pitch, ref, expected, decl)
    h_new = heading.heading_health(t, b_new, roll, pitch, ref, expected, decl)
    unid = _unidentified(ident, names, in_force, drives)
    s_name = mag_param_names(inst)["scale"]
    if s_name in params:
        in_force[s_name] = float(params[s_name])
        proposed[s_name] = float(params[s_name])     # kept: M absorbs any scale (module doc)
    valid = not (fit.at_limits or nowhere)
    if not valid:
        unid = [("a correction within ArduPilot's limits (the compass does not match the field)",
                 "a flight away from steel and power lines, with the site known")]
    return CompassFlight(inst, in_force, proposed, sigma, h_old, h_new, orient, drives.kind,
                         drives.span, unid, fit.rms, valid, held_names, would, local,
                         ref.describe("the proposed calibration" if valid else
                                      "the calibration in force"),
                         ref.delay_s, fit.correlation_factor)


def _rate_source(fd: FlightData) -> heading.RateSource:
    if fd.gyr is not None and len(fd.gyr_t) > 2:
        return heading.RateSource.from_gyro(fd.gyr_t, fd.gyr, fd.att_t, fd.roll, fd.pitch)
    return heading.RateSource.from_heading(fd.att_t, fd.yaw)


def calibrate_flight(source, site: tuple[float, float] | None = None, *,
                     check_orientation: bool = True) -> FlightResult:
    """The flight compass check of a log path (or :class:`FlightData`); see the module doc.

    Returns
    -------
    FlightResult
        Per compass (``compasses``): the heading error of the calibration in force and of the
        proposal (``health_in_force.p95_deg``, ``.verdict``...), the proposed COMPASS_* values
        with their σ (``proposed``, ``sigma``: only what the flight identified), the
        parameters kept in force (``held``), the fitted local field.

    Raises
    ------
    ApmcalError
        Not a flight (the reason named), or a calibration in force that cannot be undone.
    """
    fd = source if isinstance(source, FlightData) else read_flight(source)
    ok, why = flight_evidence(fd, site)
    if not ok:
        raise ApmcalError(f"not a flight the compass can be checked on: {why}", fd.path)
    notes = list(fd.notes)
    field_ned, prior = _site_field(fd, site, notes)
    decl = math.atan2(field_ned[1], field_ned[0])
    generation = firmware_generation(fd.params, fd.firmware)
    after = motor_after_matrix(fd.firmware)
    rates = _rate_source(fd)
    compasses = []
    for mag in fd.mags:
        mag = _decimate(mag)
        inside = ((mag.t >= max(fd.att_t[0], BOOT_SETTLE_S)) & (mag.t <= fd.att_t[-1])
                  & np.all(np.isfinite(mag.field), axis=1) & np.all(np.isfinite(mag.motor), axis=1)
                  & np.all(np.isfinite(mag.offsets), axis=1))
        if np.count_nonzero(inside) < 50 or not np.any(mag.field[inside]):
            notes.append(f"compass {mag.instance}: too few or all-zero samples, not fitted")
            continue
        roll, pitch = attitude_at(fd, mag.t)
        inside &= (np.abs(roll) < MAX_TILT) & (np.abs(pitch) < MAX_TILT)
        mag = MagSeries(mag.instance, mag.t[inside], mag.field[inside], mag.offsets[inside],
                        mag.motor[inside])
        compasses.append(_fit_compass(fd, mag, fd.params, generation, after, prior, field_ned,
                                      decl, rates, check_orientation))
    if not compasses:
        raise ApmcalError("no compass with usable samples in the flight", fd.path)
    duration = float(fd.att_t[-1] - fd.att_t[0])
    return FlightResult(fd.path, duration, field_ned, math.degrees(decl),
                        math.degrees(prior.inclination_rad), compasses,
                        compasses[0].reference, notes, prior.sigma_intensity_mgauss,
                        math.degrees(prior.sigma_inclination_rad))


# ----------------------------------------------------------------------------- the log command
def calibrate_flight_log(path, site: tuple[float, float] | None = None):
    """The compass check of a dataflash flight log, or what the flight lacked for it.

    Returns ``(result, None)`` on a flight (:func:`calibrate_flight`'s :class:`FlightResult`:
    printed with :meth:`FlightResult.lines`, saved with :meth:`FlightResult.save_json`, its
    parameters :meth:`FlightResult.params`); ``(None, why)`` on a log that flew (attitude,
    compass, movement) but cannot be checked, ``why`` naming what it lacked and how to supply
    it; ``(None, None)`` on anything else (no dataflash log, a bench session), which the caller
    calibrates the ordinary way.

    Parameters
    ----------
    path : str or Path
    site : (lat, lon) [deg], optional
        For the WMM field when the log has no GPS fix.

    Raises
    ------
    ApmcalError
        A flight whose calibration in force cannot be undone.
    """
    from apmcal.sources import sniff_format

    if sniff_format(path) not in ("bin", "log", "tlog"):
        return None, None
    fd = read_flight(path)
    flew, why = flight_evidence(fd, site)
    if flew:
        return calibrate_flight(fd, site), None
    return None, lacking(why)


def lacking(why: str) -> str | None:
    """What a flown log lacked for the compass check, with the remedy; None when it did not
    fly (no attitude, no compass, never moved: not a flight at all)."""
    if why.startswith(("no ATT", "no MAG", "the vehicle never moved")):
        return None
    if why.startswith("no GPS fix"):
        return "no GPS fix to place the field model: give the flying site with --lat/--lon"
    if why.startswith("the gyro is logged at"):
        return f"{why}: use the flight's dataflash log, or stream the IMU faster (SRn_RAW_SENS)"
    return f"{why}: fly {MANOEUVRE['iron']}"
