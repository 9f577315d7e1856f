"""The compass from an ordinary flight: a health check of the calibration in force in heading
degrees, and a new COMPASS_* proposal with σ, per compass instance.

Steps (:func:`calibrate_flight`):

1. read the flight series (:func:`apmcal.sources.flight.read_flight`) and check it is a flight
   (:func:`flight_evidence`: attitude, compass, a position, movement, heading change);
2. the WMM field at the mean GPS position and the log's date (:mod:`apmcal.core.geomag`);
3. per compass: undo the correction in force, sample by sample with the logged offsets and
   motor compensation (ardupilot-facts.md "How the firmware applies the parameters": 4.x
   ``mag = SCALE·M·(raw + OFS) + MOT·x``; Copter 3.3/3.4 ``mag = M·(raw + OFS + MOT·x)``);
4. orientation: the fit is repeated with every ArduPilot rotation of the sensor
   (:func:`apmcal.solvers.compass_flight.orientation_scores`) and a rotation other than the one
   configured is named when it fits clearly better;
5. the fit itself (:func:`apmcal.solvers.compass_flight.fit_flight`: yaw-free, the logged yaw is
   never used), with COMPASS_MOT on the battery current when the log has one (MOTCT 2), else on
   the throttle (MOTCT 1); held at the value in force when the drive hardly varies;
6. heading health of the calibration in force and of the proposal
   (:mod:`apmcal.solvers.compass_heading`) and, for every parameter the flight could not
   determine, the manoeuvre that would.

:class:`FlightResult` prints itself (:meth:`FlightResult.lines`, verdict in heading degrees
first), gives its JSON (:meth:`FlightResult.to_dict`) and the parameters to write
(:meth:`FlightResult.params`).
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
from apmcal.solvers.compass_flight import PARAMS, corrected, fit_flight, orientation_scores
from apmcal.sources.flight import FlightData, MagSeries, read_flight

MAX_RATE_HZ = 25.0            # compass samples used per second at most
ORIENT_SAMPLES = 400          # samples per candidate in the orientation search
MIN_HEADING_SPAN_DEG = 90.0   # a flight turns at least this much
# the heading reference integrates the gyro between instants: a yaw turn of 90 °/s moves 9° per
# sample at 10 Hz, beyond which the integrated heading is no reference (telemetry's RAW_IMU is
# often streamed at 2-4 Hz)
MIN_GYRO_RATE_HZ = 10.0
FULL_TURNS_DEG = 360.0        # heading change below which the iron counts as not determined
MIN_CURRENT_SPAN_A = 5.0      # 5-95 % current span that lets COMPASS_MOT be fitted
MIN_THROTTLE_SPAN = 0.15
MOTOR_SIGMA_MGAUSS = 5.0      # σ of MOT·(drive span) above which MOT counts as not determined
OFS_SIGMA_MGAUSS = 5.0
DIA_SIGMA = 0.02
MAX_TILT = math.radians(45.0)   # samples steeper than this are left out (heading ill-defined)
ORIENT_RATIO = 1.5            # configured rms / best rms above which another rotation is named
ORIENT_MARGIN_MGAUSS = 3.0
MANOEUVRE = {"iron": "two full yaw turns (720°) in the hover",
             "vertical": "legs flown at speed in several directions (10° or more of pitch and roll)",
             "motor": "a climb at full throttle (and a slow descent), turning as it climbs"}


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


def undo(mag: MagSeries, params: dict, instance: int, after: bool,
         motor_in_force: np.ndarray | None = None) -> np.ndarray:
    """Uncorrected body-frame field (n, 3) [mGauss] of one compass: SCALE and M(DIA, ODI) in
    force, the offsets and the motor compensation of each sample taken back out.

    The MAG record logs offsets and motor compensation cut to whole mGauss (ardupilot-facts.md,
    "Flight records the flight compass check reads"); where they agree with the parameters in
    force (COMPASS_OFS; ``motor_in_force`` = COMPASS_MOT·drive) within 1 mGauss the exact
    values are used, else (offsets learnt in flight, another motor
    model) the logged ones.
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
    motor = mag.motor
    if motor_in_force is not None and np.percentile(np.abs(motor - motor_in_force), 95) <= 1.0:
        motor = motor_in_force
    inv = np.linalg.inv(m)
    if after:
        return (mag.field - motor) @ inv.T - offsets
    return mag.field @ inv.T - offsets - motor


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


def flight_evidence(fd: FlightData, site: tuple[float, float] | None = None) -> tuple[bool, str]:
    """(is a flight, why or why not): attitude (ATT), a compass (MAG), a position (a GPS fix or
    ``site``), movement (GPS speed over 1 m/s, or throttle over 0.2) and a heading change of
    at least ``MIN_HEADING_SPAN_DEG``."""
    if fd.att_t is None:
        return False, "no ATT attitude records"
    if not fd.mags:
        return False, "no MAG compass records"
    if fd.lat is None and site is None:
        return False, "no GPS fix (and no --lat/--lon) for the expected magnetic field"
    moving = ((fd.speed is not None and np.nanmax(fd.speed) > 1.0)
              or (fd.throttle is not None and np.nanmax(fd.throttle) > 0.2))
    if not moving:
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
class CompassFlight:
    """One compass: values in force and proposed (ArduPilot names), σ, health before/after,
    orientation, what was not identified and the manoeuvre that would identify it."""

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
                "sigma": self.sigma, "in_force_health": self.health_in_force.to_dict(),
                "proposed_health": self.health_proposed.to_dict(),
                "orientation": self.orientation.to_dict() if self.orientation else None,
                "motor_drive": self.drive, "motor_drive_span": self.drive_span,
                "fit_rms_mgauss": self.rms_mgauss, "proposal_valid": self.valid,
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
               f"{np.linalg.norm(b):.0f} mGauss, inclination {self.inclination_deg:.1f}°, "
               f"declination {self.declination_deg:.1f}°"]
        for c in self.compasses:
            hi, hp = c.health_in_force, c.health_proposed
            new = (f"proposed {hp.verdict.upper()} — 95 % {hp.p95_deg:.1f}° (rms "
                   f"{hp.rms_deg:.1f}°)" if c.valid else
                   "no proposal: the fit sits on ArduPilot's DIA/ODI limits")
            out.append(f"  compass {c.instance}: calibration in force {hi.verdict.upper()} — "
                       f"heading error 95 % {hi.p95_deg:.1f}° (rms {hi.rms_deg:.1f}°, max "
                       f"{hi.max_deg:.1f}°); {new}")
            out.append(f"    field residual against the WMM: {hi.field_rms_mgauss:.0f} → "
                       f"{hp.field_rms_mgauss:.0f} mGauss rms")
        out.append(f"  heading reference: {self.reference}")
        for c in self.compasses:
            if c.orientation is not None:
                out.append(f"  compass {c.instance}: {c.orientation.evidence()}")
            for what, how in c.unidentified:
                out.append(f"  compass {c.instance}: {what} not identified by this flight — "
                           f"fly {how}")
        out.append("Proposed parameters (in force → proposed ± σ):")
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
                "declination_deg": self.declination_deg, "inclination_deg": self.inclination_deg,
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


def _site_field(fd: FlightData, site, notes) -> tuple[np.ndarray, float]:
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
    b, note = geomag.earth_field_ned(lat, lon, alt, geomag.decimal_year(when))
    if note:
        notes.append(note)
    return b, lat


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


def _orientation(raw_sensor, roll, pitch, x, b_h, b_d, fit_motor, configured) -> Orientation:
    step = max(1, len(raw_sensor) // ORIENT_SAMPLES)
    s = slice(None, None, step)
    scores = orientation_scores(raw_sensor[s], _candidates(), roll[s], pitch[s], x[s], b_h[s],
                                b_d[s], fit_motor)
    cfg = next((k for k in scores if np.allclose(rotation_matrix(k),
                                                 rotation_matrix(configured), atol=1e-6)), None)
    best = min(scores, key=scores.get)
    cfg_rms = scores.get(cfg, math.inf) if cfg is not None else math.inf
    wrong = (best != cfg and (cfg_rms > ORIENT_RATIO * scores[best] + ORIENT_MARGIN_MGAUSS))
    return Orientation(configured, best if wrong else configured, scores, wrong)


def _unidentified(fit, span_deg, drive_kind, drive_span, motor_fitted) -> list[tuple[str, str]]:
    out = []
    sig = fit.sigma
    if span_deg < FULL_TURNS_DEG or np.any(sig[0:2] > OFS_SIGMA_MGAUSS) or np.any(
            sig[3:5] > DIA_SIGMA):
        if span_deg < FULL_TURNS_DEG or np.any(sig[[0, 1, 3, 4, 6]] > [OFS_SIGMA_MGAUSS] * 2
                                                + [DIA_SIGMA] * 3):
            out.append((f"hard and soft iron (heading turned over {span_deg:.0f}°)",
                        MANOEUVRE["iron"]))
    if sig[2] > OFS_SIGMA_MGAUSS or sig[5] > DIA_SIGMA or np.any(sig[7:9] > DIA_SIGMA):
        out.append(("the vertical axis (COMPASS_OFS_Z, DIA_Z, ODI_Y/Z)", MANOEUVRE["vertical"]))
    if not motor_fitted:
        unit = " A" if drive_kind == "current" else ""
        low = MIN_CURRENT_SPAN_A if drive_kind == "current" else MIN_THROTTLE_SPAN
        if drive_kind is None:
            what = "COMPASS_MOT (no current or throttle in the log)"
        elif drive_span < low:
            what = f"COMPASS_MOT ({drive_kind} varied only {drive_span:.2g}{unit}, 5-95 %)"
        else:
            what = (f"COMPASS_MOT (the {drive_kind} changes, {drive_span:.2g}{unit}, came with "
                    f"too little heading change to separate it from the offsets)")
        out.append((what, MANOEUVRE["motor"]))
    return out


def _fit_compass(fd, mag, params, generation, after, b_h, b_d, field_ned, decl,
                 ref_psi_rel, span_deg, check_orientation) -> tuple[CompassFlight, np.ndarray]:
    inst = mag.instance
    roll, pitch = attitude_at(fd, mag.t)
    x, kind, span = _drive(fd, mag.t)
    motct = int(params.get("COMPASS_MOTCT", 0))
    mot0 = np.array([float(params.get(n, 0.0)) for n in mag_param_names(inst)["mot"]])
    drive0 = _drive(fd, mag.t, "current" if motct == 2 else "throttle")[0] if motct in (1, 2) \
        else np.zeros(len(mag.t))
    raw_body = undo(mag, params, inst, after, np.outer(drive0, mot0))
    fit_motor = kind is not None and span >= (MIN_CURRENT_SPAN_A if kind == "current"
                                              else MIN_THROTTLE_SPAN)
    r_cfg = compass_rotation(params, generation, inst)
    raw_sensor = raw_body @ r_cfg                       # v_sensor = R_cfgᵀ·v_body, as rows
    configured = _configured_orientation(params, inst)
    orient = None
    r_use = r_cfg
    if check_orientation:
        orient = _orientation(raw_sensor, roll, pitch, x, np.full(len(x), b_h),
                              np.full(len(x), b_d), fit_motor, configured)
        if orient.wrong:
            r_use = rotation_matrix(orient.best)
    raw = raw_sensor @ r_use.T
    bh, bd = np.full(len(x), b_h), np.full(len(x), b_d)
    fit = fit_flight(raw, roll, pitch, x, bh, bd, fit_motor=fit_motor)
    if fit_motor:
        mot_sigma = fit.sigma[9:12] * span
        if np.any(mot_sigma > MOTOR_SIGMA_MGAUSS):
            fit_motor = False
    if not fit_motor:
        names = mag_param_names(inst)["mot"]
        same = kind is not None and int(params.get("COMPASS_MOTCT", 0)) == (
            2 if kind == "current" else 1)
        held = np.array([params.get(n, 0.0) for n in names]) if same else np.zeros(3)
        fit = fit_flight(raw, roll, pitch, x, bh, bd, fit_motor=False, motor_fixed=held)
    names = param_names(inst)
    s0 = compass_scale(params, inst)
    values = fit.x.copy()
    sig = fit.sigma.copy()
    values[3:9] /= s0
    sig[3:9] /= s0
    proposed = {names[p]: float(values[k]) for k, p in enumerate(PARAMS)
                if k < 9 or fit_motor}
    sigma = {names[p]: float(sig[k]) for k, p in enumerate(PARAMS) if k < 9 or fit_motor}
    if fit_motor:
        proposed["COMPASS_MOTCT"] = 2.0 if kind == "current" else 1.0
    if orient is not None and orient.wrong:
        n = mag_param_names(inst)
        proposed[n["orient"]] = float(orient.best)
        if not params.get(n["external"], 0):
            proposed[n["external"]] = 2.0        # ForcedExternal: COMPASS_ORIENTn then applies
    in_force = {k: float(params[k]) for k in proposed if k in params}
    b_new = corrected(fit.x, raw, x)
    # the reference heading is anchored to the proposal, or to the calibration in force when
    # the fit sits on its limits (then only the in-force spread is measured)
    anchor = b_new if not fit.at_limits else mag.field
    psi_anchor = heading.compass_heading(anchor, roll, pitch, decl)
    ref = heading.anchored_reference(mag.t, ref_psi_rel(mag.t), psi_anchor)
    h_old = heading.heading_health(mag.t, mag.field, roll, pitch, ref, field_ned, decl)
    h_new = heading.heading_health(mag.t, b_new, roll, pitch, ref, field_ned, decl)
    unid = _unidentified(fit, span_deg, kind, span, fit_motor)
    s_name = mag_param_names(inst)["scale"]
    if s_name in params:
        in_force[s_name] = float(params[s_name])
        proposed[s_name] = float(params[s_name])     # kept: M absorbs any scale (module doc)
    if fit.at_limits:
        unid.append(("a correction within ArduPilot's limits (the compass does not match the "
                     "WMM field)", "a flight away from steel and power lines, with the site known"))
    return CompassFlight(inst, in_force, proposed, sigma, h_old, h_new, orient, kind, span,
                         unid, fit.rms, not fit.at_limits), ref


def calibrate_flight(source, site: tuple[float, float] | None = None, *,
                     check_orientation: bool = True) -> FlightResult:
    """The flight compass check of a log path (or :class:`FlightData`); see the module doc.

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
    field_ned, _ = _site_field(fd, site, notes)
    b_h, b_d = float(np.hypot(field_ned[0], field_ned[1])), float(field_ned[2])
    decl = math.atan2(field_ned[1], field_ned[0])
    incl = math.degrees(math.atan2(b_d, b_h))
    generation = firmware_generation(fd.params, fd.firmware)
    after = motor_after_matrix(fd.firmware)
    if fd.gyr is not None and len(fd.gyr_t) > 2:
        def ref_rel(t):
            return heading.gyro_heading(fd.gyr_t, fd.gyr, fd.att_t, fd.roll, fd.pitch, t)
        reference = ("gyro-integrated heading change, anchored per 60 s to the proposed "
                     "calibration (a constant offset common to all calibrations is not seen)")
    else:
        yaw_u = np.unwrap(fd.yaw)

        def ref_rel(t):
            return np.interp(t, fd.att_t, yaw_u)
        reference = ("logged yaw change (no IMU gyro records; it used this compass), anchored "
                     "per 60 s to the proposed calibration")
    span = heading_span_deg(fd)
    compasses = []
    for mag in fd.mags:
        mag = _decimate(mag)
        inside = ((mag.t >= fd.att_t[0]) & (mag.t <= fd.att_t[-1])
                  & np.all(np.isfinite(mag.field), axis=1) & np.all(np.isfinite(mag.motor), axis=1)
                  & np.all(np.isfinite(mag.offsets), axis=1))
        if np.count_nonzero(inside) < 50 or not np.any(mag.field[inside]):
            notes.append(f"compass {mag.instance}: too few or all-zero samples, not fitted")
            continue
        roll, pitch = attitude_at(fd, mag.t)
        inside &= (np.abs(roll) < MAX_TILT) & (np.abs(pitch) < MAX_TILT)
        mag = MagSeries(mag.instance, mag.t[inside], mag.field[inside], mag.offsets[inside],
                        mag.motor[inside])
        c, _ = _fit_compass(fd, mag, fd.params, generation, after, b_h, b_d, field_ned, decl,
                            ref_rel, span, check_orientation)
        compasses.append(c)
    if not compasses:
        raise ApmcalError("no compass with usable samples in the flight", fd.path)
    duration = float(fd.att_t[-1] - fd.att_t[0])
    return FlightResult(fd.path, duration, field_ned, math.degrees(decl), incl, compasses,
                        reference, notes)


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
