"""From a recording to a calibration: prepare the samples, pick and run a solver.

This is the only place that joins the stages; readers never call solvers and solvers never read
files. Preparation, in order: strictly increasing time; integer telemetry moved off its
truncation bias; the firmware's correction and board orientation undone, so that every solver
sees raw sensor-frame samples.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.constants import STANDARD_GRAVITY, normal_gravity
from apmcal.errors import ApmcalError
from apmcal.preprocessing.resolution import add_resolution_floor, telemetry_steps, undo_truncation
from apmcal.preprocessing.timebase import monotonic
from apmcal.recording import Recording
from apmcal.solvers.result import Calibration

METHODS = ("auto", "ferraris", "static", "ellipsoid")
FERRARIS_FACES = {"x_p", "x_a", "y_p", "y_a", "z_p", "z_a"}
MIN_ELLIPSOID_HOLDS = 7     # 9 parameters; the robust fit's prior carries the rest (seed 000)


@dataclass
class Prepared:
    raw: Recording                                   # raw sensor-frame samples
    steps: dict[str, float] = field(default_factory=dict)   # telemetry resolution per sensor
    warnings: list[str] = field(default_factory=list)


def prepare(recording: Recording) -> Prepared:
    """Monotonic time, truncation undone, firmware correction undone.

    ardupilot-facts.md "What the telemetry really carries": RAW_IMU and dataflash IMU/MAG are
    corrected with the parameters in force, so a fit on them must first undo that correction.
    """
    recording, warnings = monotonic(recording)
    steps = telemetry_steps(recording)
    recording = undo_truncation(recording)
    if recording.corrected:
        from apmcal.preprocessing.firmware import uncorrect

        recording = uncorrect(recording)
    return Prepared(recording, steps, warnings)


def choose_method(recording: Recording) -> str:
    """'ferraris' for six faces plus rotations, 'ellipsoid' for four poses or more, else 'static'."""
    from apmcal.preprocessing.rotations import find_rotations
    from apmcal.preprocessing.static import find_static_segments, label_poses

    t, acc = recording.t, recording.xyz("acc")
    gyr = recording.xyz("gyr") if recording.has("gyr") else None
    segments = find_static_segments(t, acc, gyr)
    faces = FERRARIS_FACES & set(label_poses(segments))
    if len(faces) == 6 and gyr is not None and len(find_rotations(t, gyr, segments)) >= 3:
        return "ferraris"
    if len(segments) >= MIN_ELLIPSOID_HOLDS and len({s.pose for s in segments if s.pose}) >= 4:
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
    prepared = prepare(recording)
    chosen = choose_method(prepared.raw) if method == "auto" else method
    try:
        cal = inertial_calibration(prepared.raw, chosen, lat_deg, lon_deg, prepared.steps)
    except ApmcalError as err:
        if method != "auto":
            raise
        cal = Calibration(method="none", report={"warnings": [
            f"accelerometer and gyro not calibrated ({chosen} method): {err.why}"]})
    cal.report.setdefault("warnings", []).extend(prepared.warnings)
    add_resolution_floor(cal, prepared.steps, {"acc": local_gravity(lat_deg)})
    if has_live_magnetometer(prepared.raw):
        add_magnetometer(cal, prepared, lat_deg, lon_deg)
    return cal


def inertial_calibration(raw: Recording, method: str, lat_deg, lon_deg,
                         steps: dict[str, float] | None = None) -> Calibration:
    """Accelerometer and gyro calibration of raw sensor-frame samples by ``method``.

    ``steps``: quantisation step per sensor of integer telemetry (see preprocessing.resolution).
    """
    t, acc = raw.t, raw.xyz("acc")
    gyr = raw.xyz("gyr") if raw.has("gyr") else None
    if method == "ferraris":
        from apmcal.solvers.ferraris import ferraris_calibration

        return ferraris_calibration(t, acc, gyr, lat_deg=lat_deg, gravity=local_gravity(lat_deg),
                                    gyro_step=(steps or {}).get("gyr", 0.0))
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


def calibrate_magnetometer(cal: Calibration, recording: Recording, lat_deg, lon_deg) -> None:
    """Add the magnetometer of a separate recording (dataflash MAG) to ``cal``."""
    if "mag" not in cal.sensors and has_live_magnetometer(recording):
        add_magnetometer(cal, prepare(recording), lat_deg, lon_deg)


def add_magnetometer(cal: Calibration, prepared: Prepared, lat_deg, lon_deg) -> None:
    """Add the magnetometer fit to ``cal``, or a warning saying why it was not possible."""
    from apmcal.solvers.magnetometer import calibrate_magnetometer as fit

    cal.report.setdefault("warnings", []).extend(f"mag: {w}" for w in prepared.warnings)
    try:
        cal.sensors["mag"] = fit(prepared.raw.xyz("mag"), lat_deg, lon_deg, cal.report)
    except ApmcalError as err:
        cal.report["warnings"].append(err.why)
        return
    add_resolution_floor(cal, {"mag": prepared.steps["mag"]} if "mag" in prepared.steps else {},
                         {"mag": cal.report["mag_field_mgauss"]})


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
    if len(segments) < MIN_ELLIPSOID_HOLDS:
        raise ApmcalError(f"ellipsoid fit needs at least {MIN_ELLIPSOID_HOLDS} static holds in "
                          f"different orientations, found {len(segments)}")
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
