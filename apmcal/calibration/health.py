"""The health of the calibration in force, measured on one log as logged: the one computation
``apmcal log`` and ``apmcal fleet`` share, so that both say the same of the same log.

- compass on a flight: the flight compass check (:func:`flight_compass`, which runs
  :func:`apmcal.calibration.flight.calibrate_flight_log`, what ``apmcal log FLIGHT`` prints):
  per compass the heading error of the calibration in force along the flight (95th percentile)
  with its verdict, the proposal's, and the hard iron the flight fits (the proposed COMPASS_OFS,
  which does not depend on the calibration in force) with its σ;
- compass on a session that turns it through every direction (not a flight): the logged field's
  sphere-fit centre [mGauss, body frame] is the offset the calibration in force leaves
  ([Niespodziany] Fig. 2 step 1, :func:`apmcal.solvers.ellipsoid.paper.sphere_fit`); its radius
  against the WMM's intensity at the site and date (:mod:`apmcal.core.geomag`) is the field
  residual. The heading error it implies, at worst over all headings of a level vehicle, is
  asin(horizontal residual / horizontal field);
- gyro: the bias in the first and last still period [°/s, body frame]: the logged mean plus the
  boot offsets in force (INS_GYROFFS, ardupilot-facts.md "How the firmware applies the
  parameters"), with the board temperature [°C] there; the noise (median std of still periods).
  A "still" period whose mean rate differs from the first one's by more than
  :data:`MAX_STILL_RATE_DPS` is a steady turn (a yaw in the hover has a small moving std too),
  not a still period: the first one is on the ground, and the reference is that period rather
  than zero because an uncalibrated gyro logs tens of °/s at rest (pxf_copter_static_51.BIN);
- accelerometer: |mean specific force| − g [m/s²] in still periods (median), the tilt of the
  first still period from level [deg], the noise [m/s²];
- vibration: the VIBE record's mean VibeX/Y/Z [m/s²] and clip count, where logged (.bin;
  ardupilot-facts.md "Identity and vibration records").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.core.errors import ApmcalError

STD_GRAVITY = 9.80665
# least principal spread of the compass samples (fraction of the field) for a residual: lower
# than a calibration's 0.25, since only the centre is fitted here (no shape), and a flight's
# turns rarely cover a sphere
MIN_SPREAD = 0.15
# a logged field whose distance from the fitted centre scatters more than this fraction of the
# radius is no offset sphere (soft iron, motor currents, a wrong DIA/ODI): no heading error then
MAX_FIT_RMS_FRACTION = 0.10
# largest difference [°/s] between a still period's mean rate and the first one's: a gyro's
# bias moves by tenths of a degree per second over a flight; a copter yawing steadily in the
# hover turns tens of degrees per second
MAX_STILL_RATE_DPS = 3.0


def still_segments(recording):
    """Still periods (:func:`apmcal.preprocessing.static.find_static_segments`) of an IMU
    recording with accelerometer and gyro [rad/s], without the steady turns (a mean rate more
    than :data:`MAX_STILL_RATE_DPS` from the first period's); [] when it has too few samples."""
    from apmcal.preprocessing.static import find_static_segments

    if not (recording.has("acc") and recording.has("gyr")) or len(recording) < 20:
        return []
    try:
        segments = find_static_segments(recording.t, recording.xyz("acc"), recording.xyz("gyr"))
    except ApmcalError:
        return []
    if not segments:
        return []
    limit, rest = np.radians(MAX_STILL_RATE_DPS), segments[0].gyr_mean
    return [s for s in segments if np.linalg.norm(s.gyr_mean - rest) <= limit]


def _temp_of(recording, seg) -> float:
    if "temp" not in recording.data.columns:
        return float("nan")
    temp = recording.data["temp"].to_numpy(dtype=float)[seg.kept()]
    temp = temp[np.isfinite(temp)]
    return float(np.mean(temp)) if len(temp) else float("nan")


def boot_offsets_body(recording, params: dict, firmware: str | None) -> np.ndarray:
    """INS_GYROFFS [rad/s] in force, in the body frame (3.2: already body; 3.3+: sensor frame
    rotated by AHRS_ORIENTATION); zeros when not logged."""
    from apmcal.ardupilot.firmware import firmware_generation
    from apmcal.calibration.log import board_rotation

    offs = np.array([params.get(f"INS_GYROFFS_{a}", 0.0) for a in "XYZ"], dtype=float)
    offs = np.where(np.isfinite(offs), offs, 0.0)
    if firmware_generation(params, firmware) == "3.2":
        return offs
    return board_rotation(recording) @ offs


def gyro_health(recording, segments, params: dict, firmware: str | None) -> dict:
    """Gyro bias at the first and last still period [°/s] with their temperatures [°C], and
    the gyro noise [°/s]."""
    out: dict = {}
    if not segments:
        return out
    boot = boot_offsets_body(recording, params, firmware)
    for tag, seg in (("start", segments[0]), ("end", segments[-1])):
        bias = np.degrees(seg.gyr_mean + boot)
        for a, v in zip("xyz", bias):
            out[f"gyro_bias_{tag}_{a}_dps"] = float(v)
        out[f"temp_{tag}_c"] = _temp_of(recording, seg)
        out[f"still_{tag}_t_s"] = float(seg.t_mean)
    out["gyro_noise_dps"] = float(np.degrees(np.median([np.linalg.norm(s.gyr_std)
                                                        for s in segments])))
    return out


def acc_health(segments, gravity: float) -> dict:
    """|a| − g [m/s²] (median over still periods), first still period's tilt [deg], noise."""
    if not segments:
        return {}
    norms = np.array([np.linalg.norm(s.acc_mean) for s in segments])
    first = segments[0].acc_mean
    level = np.degrees(np.arccos(np.clip(-first[2] / np.linalg.norm(first), -1, 1)))
    return {"acc_norm_err_ms2": float(np.median(norms) - gravity), "acc_level_deg": float(level),
            "acc_noise_ms2": float(np.median([np.linalg.norm(s.acc_std) for s in segments])),
            "still_periods": len(segments),
            "still_s": float(sum(s.duration for s in segments))}


def sphere_centre_sigma(mag: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """1-σ of the sphere-fit centre [mGauss] from the linear model of
    :func:`~apmcal.solvers.ellipsoid.paper.sphere_fit` (|s|² = 2·c·s + k): σ²·(XᵀX)⁻¹ of its
    least squares, halved for c. Hand-written: the library fit returns no covariance."""
    X = np.column_stack([mag, np.ones(len(mag))])
    y = np.sum(mag ** 2, axis=1)
    beta = np.concatenate([2 * centre, [radius ** 2 - centre @ centre]])
    r = y - X @ beta
    dof = max(len(mag) - 4, 1)
    cov = (r @ r / dof) * np.linalg.inv(X.T @ X)
    return np.sqrt(np.clip(np.diag(cov)[:3], 0, None)) / 2.0


def compass_health(mag_recording, site: tuple[float, float, float] | None, year: float | None
                   ) -> tuple[dict, list[str]]:
    """Residual offset [mGauss] of the compass as logged, field residual against the WMM,
    and the heading error it implies [deg] with its σ; notes saying what could not be done."""
    from apmcal.core.geomag import earth_field_ned
    from apmcal.solvers.ellipsoid.paper import sphere_fit
    from apmcal.solvers.magnetometer import check_coverage

    mag = mag_recording.xyz("mag")
    mag = mag[np.all(np.isfinite(mag), axis=1)]
    try:
        check_coverage(mag, MIN_SPREAD)
        centre, radius = sphere_fit(mag)
    except ApmcalError as err:
        return {}, [f"compass residual not measured: {err.why}"]
    sigma = sphere_centre_sigma(mag, centre, radius)
    out = {f"mag_residual_{a}_mgauss": float(v) for a, v in zip("xyz", centre)}
    out.update({f"mag_residual_{a}_sigma_mgauss": float(v) for a, v in zip("xyz", sigma)})
    out["mag_field_mgauss"] = float(radius)
    # the compass's noise and what the centre cannot explain: rms distance from the sphere
    out["mag_fit_rms_mgauss"] = float(np.sqrt(np.mean((np.linalg.norm(mag - centre, axis=1)
                                                       - radius) ** 2)))
    horiz = float(np.hypot(centre[0], centre[1]))
    out["mag_residual_horizontal_mgauss"] = horiz
    if out["mag_fit_rms_mgauss"] > MAX_FIT_RMS_FRACTION * radius:
        return out, [f"heading error not measured: the logged field is no offset sphere (rms "
                     f"{out['mag_fit_rms_mgauss']:.0f} mGauss, "
                     f"{100 * out['mag_fit_rms_mgauss'] / radius:.0f} % of its radius): soft "
                     f"iron, motor interference or a poor calibration"]
    if site is None or year is None:
        return out, ["heading error not measured: the site is unknown (no GPS fix; give "
                     "--lat/--lon)"]
    field, note = earth_field_ned(site[0], site[1], site[2], year)
    b_h = float(np.hypot(field[0], field[1]))
    out["wmm_field_mgauss"] = float(np.linalg.norm(field))
    out["wmm_horizontal_mgauss"] = b_h
    out["field_residual_mgauss"] = float(radius - np.linalg.norm(field))
    ratio = min(horiz / b_h, 1.0)
    heading = np.arcsin(ratio)
    s_h = (np.hypot(centre[0] * sigma[0], centre[1] * sigma[1]) / horiz if horiz > 0
           else float(np.hypot(*sigma[:2])))
    out["heading_error_deg"] = float(np.degrees(heading))
    out["heading_error_sigma_deg"] = float(np.degrees(s_h / (b_h * max(np.cos(heading), 1e-3))))
    return out, [note] if note else []


def vibration(msgs: dict) -> dict:
    """Mean VibeX/Y/Z [m/s²] and the clip count of the first IMU's VIBE records; {} when absent
    (ardupilot-facts.md "Identity and vibration records": "Clip" per instance on newer logs,
    Clip0..2 on older ones; both are running counts, so their maximum is the total)."""
    vibe = msgs.get("VIBE", {})
    if not all(c in vibe for c in ("VibeX", "VibeY", "VibeZ")) or len(vibe["VibeX"]) == 0:
        return {}
    first = np.ones(len(vibe["VibeX"]), dtype=bool)
    if "IMU" in vibe:
        first = np.asarray(vibe["IMU"]) == np.min(vibe["IMU"])
    out = {f"vibe_{a.lower()}_ms2": float(np.nanmean(np.asarray(vibe[f"Vibe{a}"], float)[first]))
           for a in "XYZ"}
    clips = [np.asarray(vibe[c], float)[first] for c in ("Clip", "Clip0", "Clip1", "Clip2")
             if c in vibe]
    out["vibe_clips"] = float(sum(np.nanmax(c) for c in clips if len(c))) if clips else 0.0
    return out


def gps_site(msgs: dict) -> tuple[float, float, float] | None:
    """Median latitude, longitude [deg] and altitude [m] of the GPS records with a 3D fix."""
    gps = msgs.get("GPS", {})
    lat = gps.get("Lat")
    lng = gps.get("Lng", gps.get("Lon"))
    if lat is None or lng is None or "Status" not in gps:
        return None
    fix = np.asarray(gps["Status"]) >= 3
    lat, lng = np.asarray(lat, float)[fix], np.asarray(lng, float)[fix]
    ok = np.isfinite(lat) & np.isfinite(lng) & ((lat != 0) | (lng != 0))
    if not ok.any():
        return None
    alt = np.asarray(gps.get("Alt", np.zeros(len(fix))), float)[fix][ok]
    return float(np.median(lat[ok])), float(np.median(lng[ok])), float(np.nanmedian(alt))


def gravity_at(site) -> float:
    """Normal gravity [m/s²] at the site's latitude, standard gravity when unknown."""
    from apmcal.core.constants import normal_gravity

    return STD_GRAVITY if site is None else float(normal_gravity(site[0]))


# ----------------------------------------------------------------------------- compass in flight
@dataclass(frozen=True)
class CompassHealth:
    """One compass on one flight, as ``apmcal log FLIGHT`` reports it: the heading error of the
    calibration in force (95th percentile along the flight [deg]) and its verdict (good /
    usable / redo, :func:`apmcal.solvers.compass_heading.verdict`), the proposal's, and the
    hard iron the flight fits [mGauss, COMPASS_OFS convention] with its 1-σ (None when the fit
    sits on ArduPilot's limits and proposes nothing)."""

    instance: int
    heading_p95_deg: float
    verdict: str
    proposed_p95_deg: float
    proposed_verdict: str
    hard_iron_mgauss: tuple[float, float, float] | None
    hard_iron_sigma_mgauss: tuple[float, float, float] | None


@dataclass
class FlightCompass:
    """The flight compass check of one log: the :class:`~apmcal.calibration.flight.FlightResult`
    (None when the log is no flight the check can use) and, for a log that flew but cannot be
    checked, what it lacked (``lacking``), as :func:`~apmcal.calibration.flight.
    calibrate_flight_log` returns them."""

    result: object | None
    lacking: str | None

    @property
    def compasses(self) -> list[CompassHealth]:
        """One :class:`CompassHealth` per compass checked."""
        if self.result is None:
            return []
        from apmcal.ardupilot.firmware import mag_param_names

        out = []
        for c in self.result.compasses:
            ofs = mag_param_names(c.instance)["ofs"]
            fitted = c.valid and all(n in c.proposed and n in c.sigma for n in ofs)
            out.append(CompassHealth(
                c.instance, float(c.health_in_force.p95_deg), c.health_in_force.verdict,
                float(c.health_proposed.p95_deg), c.health_proposed.verdict,
                tuple(float(c.proposed[n]) for n in ofs) if fitted else None,
                tuple(float(c.sigma[n]) for n in ofs) if fitted else None))
        return out

    def figures(self, in_use: set[int] | None = None) -> dict:
        """Flat record fields (``compass<i>_...`` per compass, and the headline
        ``heading_error_deg``: the worst heading error of the compasses ``in_use``, all when
        None); {} when there is no result."""
        if self.result is None:
            return {}
        b = np.asarray(self.result.field_ned, dtype=float)
        out: dict = {"heading_error_method": "flight", "wmm_field_mgauss": float(np.linalg.norm(b)),
                     "wmm_horizontal_mgauss": float(np.hypot(b[0], b[1]))}
        worst = None
        for c in self.compasses:
            k = f"compass{c.instance}"
            out.update({f"{k}_heading_p95_deg": c.heading_p95_deg, f"{k}_verdict": c.verdict,
                        f"{k}_proposed_p95_deg": c.proposed_p95_deg,
                        f"{k}_proposed_verdict": c.proposed_verdict,
                        f"{k}_in_use": in_use is None or c.instance in in_use})
            if c.hard_iron_mgauss is not None:
                for a, v, s in zip("xyz", c.hard_iron_mgauss, c.hard_iron_sigma_mgauss):
                    out[f"{k}_hard_iron_{a}_mgauss"] = v
                    out[f"{k}_hard_iron_sigma_{a}_mgauss"] = s
            if out[f"{k}_in_use"] and (worst is None or c.heading_p95_deg > worst.heading_p95_deg):
                worst = c
        if worst is not None:
            out["heading_error_deg"] = worst.heading_p95_deg
            out["heading_error_compass"] = worst.instance
        return out


def flight_compass(path, site: tuple[float, float] | None = None) -> FlightCompass:
    """The flight compass check of a log (:func:`apmcal.calibration.flight.
    calibrate_flight_log`, exactly as ``apmcal log FLIGHT`` runs it).

    Parameters
    ----------
    path : str or Path
    site : (lat, lon) [deg], optional
        For the WMM field when the log has no GPS fix.

    Raises
    ------
    ApmcalError
        A flight whose calibration in force cannot be undone, or whose compasses have no
        usable samples.
    """
    from apmcal.calibration.flight import calibrate_flight_log

    return FlightCompass(*calibrate_flight_log(path, site))


COMPASS_USE_PARAMS = ("COMPASS_USE", "COMPASS_USE2", "COMPASS_USE3")


def compasses_in_use(params: dict) -> set[int]:
    """Compass instances the firmware uses (COMPASS_USE, USE2, USE3 not 0; absent counts as in
    use: older firmware without the parameter uses every compass)."""
    return {i for i, name in enumerate(COMPASS_USE_PARAMS) if params.get(name, 1) != 0}
