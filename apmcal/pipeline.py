"""From a recording to a calibration: undo the firmware correction, pick and run a solver.

This is the only place that joins the stages; readers never call solvers and solvers never read
files.
"""
from __future__ import annotations

import numpy as np

from apmcal.constants import STANDARD_GRAVITY, normal_gravity
from apmcal.errors import ApmcalError
from apmcal.preprocessing.timebase import monotonic
from apmcal.recording import Recording
from apmcal.solvers.result import Calibration

METHODS = ("auto", "ferraris", "static", "ellipsoid")


def raw_sensor_frame(recording: Recording) -> Recording:
    """The recording as the sensor produced it: firmware correction and orientation undone.

    ardupilot-facts.md "What the telemetry really carries": RAW_IMU and dataflash IMU/MAG are
    corrected with the parameters in force, so a fit on them must first undo that correction.
    """
    if not recording.corrected:
        return recording
    from apmcal.preprocessing.firmware import uncorrect

    return uncorrect(recording)


def choose_method(recording: Recording) -> str:
    """'ferraris' for six faces plus rotations, 'ellipsoid' for several poses, else 'static'."""
    from apmcal.preprocessing.rotations import find_rotations
    from apmcal.preprocessing.static import find_static_segments, label_poses

    t, acc = recording.t, recording.xyz("acc")
    gyr = recording.xyz("gyr") if recording.has("gyr") else None
    segments = find_static_segments(t, acc, gyr)
    faces = {k for k in label_poses(segments) if k in ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")}
    if len(faces) == 6 and gyr is not None and len(find_rotations(t, gyr, segments)) >= 3:
        return "ferraris"
    if len({s.pose for s in segments if s.pose}) >= 4:
        return "ellipsoid"
    if segments:
        return "static"
    raise ApmcalError("no static period found: hold the vehicle still for at least a few seconds",
                      recording.source)


def calibrate(recording: Recording, method: str = "auto", lat_deg: float | None = None,
              lon_deg: float | None = None) -> Calibration:
    """Run ``method`` on ``recording`` (raw or firmware-corrected) and return the calibration
    of the raw sensor-frame samples.

    With ``method="auto"`` a recording that suits no accelerometer method (a magnetometer tumble,
    say) still yields its magnetometer calibration, with a warning about the rest.
    """
    if method not in METHODS:
        raise ApmcalError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if not recording.has("acc"):
        raise ApmcalError("recording has no accelerometer samples", recording.source)
    recording, time_warnings = monotonic(recording)
    raw = raw_sensor_frame(recording)
    chosen = choose_method(raw) if method == "auto" else method
    try:
        cal = inertial_calibration(raw, chosen, lat_deg, lon_deg)
    except ApmcalError as err:
        if method != "auto":
            raise
        cal = Calibration(method="none", report={"warnings": [
            f"accelerometer and gyro not calibrated ({chosen} method): {err.why}"]})
    cal.report.setdefault("warnings", []).extend(time_warnings)
    if has_live_magnetometer(raw) and "mag" not in cal.sensors:
        add_magnetometer(cal, raw, lat_deg, lon_deg)
    return cal


def inertial_calibration(raw: Recording, method: str, lat_deg, lon_deg) -> Calibration:
    """Accelerometer and gyro calibration of raw sensor-frame samples by ``method``."""
    t, acc = raw.t, raw.xyz("acc")
    gyr = raw.xyz("gyr") if raw.has("gyr") else None
    if method == "ferraris":
        from apmcal.solvers.ferraris import ferraris_calibration

        return ferraris_calibration(t, acc, gyr, lat_deg=lat_deg, gravity=local_gravity(lat_deg))
    if method == "ellipsoid":
        return accelerometer_ellipsoid(t, acc, gyr, lat_deg)
    from apmcal.solvers.one_position import one_position_calibration

    still = longest_static_segment(t, acc, gyr, raw.source)
    part = slice(still.i0, still.i1)
    cal = one_position_calibration(t[part], acc[part], None if gyr is None else gyr[part],
                                   lat_deg=lat_deg, lon_deg=lon_deg)
    cal.report["static_segment_s"] = [still.start, still.end]
    # The paper's recipe runs, but one pose cannot separate accelerometer bias from tilt
    # (identifiability lines in the report): never send such offsets to a vehicle.
    cal.report["undetermined"] = {"acc": "one static pose cannot separate accelerometer "
                                  "bias from tilt (see the identifiability report)"}
    return cal


def add_magnetometer(cal: Calibration, raw: Recording, lat_deg, lon_deg) -> None:
    """Add the magnetometer fit to ``cal``, or a warning saying why it was not possible."""
    raw, time_warnings = monotonic(raw)
    cal.report.setdefault("warnings", []).extend(f"mag: {w}" for w in time_warnings)
    try:
        cal.sensors["mag"] = magnetometer_calibration(raw, lat_deg, lon_deg, cal.report)
    except ApmcalError as err:
        cal.report.setdefault("warnings", []).append(err.why)


def longest_static_segment(t, acc, gyr, source: str):
    """The longest still period (the one-position method's input), or a clear error."""
    from apmcal.preprocessing.static import find_static_segments

    segments = find_static_segments(t, acc, gyr)
    if not segments:
        raise ApmcalError("no static period found: hold the vehicle still (level, x north) "
                          "for about a minute", source)
    return max(segments, key=lambda s: s.end - s.start)


def accelerometer_ellipsoid(t, acc, gyr, lat_deg) -> Calibration:
    """Ellipsoid fit (seed 000) of the static-hold means; gyro offset from the held samples."""
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.solvers.ellipsoid import ellipsoid_calibration

    segments = find_static_segments(t, acc, gyr)
    if len(segments) < 4:
        raise ApmcalError(f"ellipsoid fit needs at least 4 static poses, found {len(segments)}")
    samples = {"acc": np.array([s.acc_mean for s in segments])}
    if gyr is not None:
        samples["gyr"] = np.concatenate([gyr[s.i0:s.i1] for s in segments])
    cal = ellipsoid_calibration(samples, {"acc": local_gravity(lat_deg)})
    cal.report["static_segments"] = len(segments)
    return cal


def local_gravity(lat_deg: float | None) -> float:
    """WGS-84 normal gravity at the latitude, or standard gravity when it is unknown [m/s²]."""
    return STANDARD_GRAVITY if lat_deg is None else normal_gravity(lat_deg)


def has_live_magnetometer(recording: Recording) -> bool:
    """True when mag columns exist and are not all zero (an absent compass logs zeros)."""
    return recording.has("mag") and bool(np.any(recording.xyz("mag")))


def magnetometer_calibration(raw: Recording, lat_deg, lon_deg, report: dict):
    """Robust ellipsoid fit of the magnetometer [mGauss].

    The field magnitude comes from the World Magnetic Model when the site is known; otherwise
    from a sphere fit, which fixes the calibration's overall scale to the data's own mean
    radius (offsets and shape are unaffected).
    """
    from apmcal.solvers.ellipsoid import fit_ellipsoid_robust, sphere_fit, verdict

    mag = raw.xyz("mag")
    check_magnetometer_coverage(mag, raw.source)
    if lat_deg is not None and lon_deg is not None:
        radius, origin = float(np.linalg.norm(earth_field_ned(lat_deg, lon_deg))), "WMM"
    else:
        radius, origin = sphere_fit(mag)[1], "sphere fit (no --lat/--lon)"
    info: dict = {}
    cal = fit_ellipsoid_robust(mag, radius, info=info)
    report.setdefault("lines", []).append(f"mag: field magnitude {radius:.1f} mGauss from {origin}")
    report["lines"] += verdict(mag, cal, radius, sensor="mag", info=info)
    return cal


def check_magnetometer_coverage(mag: np.ndarray, source: str,
                                min_spread: float = 0.25) -> None:
    """Refuse a magnetometer fit on samples that do not turn through space.

    A fit needs the field seen from many directions: each principal standard deviation of the
    raw samples must reach ``min_spread`` × their median magnitude (a uniform sphere gives
    1/√3 ≈ 0.58; one still pose gives only the noise).
    """
    spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(mag.T)), 0, None))
    scale = float(np.median(np.linalg.norm(mag, axis=1)))
    if scale <= 0 or spread[0] < min_spread * scale:
        raise ApmcalError(f"magnetometer not calibrated: samples span only "
                          f"{spread[0] / max(scale, 1e-9):.2f} of the field along their flattest "
                          f"direction (need {min_spread}); rotate the vehicle through all "
                          f"orientations", source)


def earth_field_ned(lat_deg: float, lon_deg: float, alt_m: float = 0.0) -> np.ndarray:
    """World Magnetic Model main field [mGauss] in NED (pygeomag gives nT; 1 mGauss = 100 nT)."""
    import datetime

    from pygeomag import GeoMag

    now = datetime.date.today()
    year = now.year + (now.timetuple().tm_yday - 1) / 365.25
    res = GeoMag().calculate(glat=lat_deg, glon=lon_deg, alt=alt_m / 1000.0, time=year)
    return np.array([res.x, res.y, res.z]) * 0.01
