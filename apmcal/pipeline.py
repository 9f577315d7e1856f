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
MIN_ORIENTATIONS = 4        # holds ≥ 30° apart: fewer leave the ellipsoid undetermined


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
    if len(segments) >= MIN_ELLIPSOID_HOLDS and distinct_orientations(segments) >= MIN_ORIENTATIONS:
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


def calibrate_log(contents, method: str = "auto", lat_deg=None, lon_deg=None,
                  instance: int | None = None, generation: str | None = None):
    """Calibrate one IMU instance of a log (and its compass) and propose ArduPilot parameters.

    Returns (Calibration, ParamProposal or None); None when the source is not an ArduPilot log
    and no ``generation`` was given (a CSV file has no firmware to write parameters for).
    """
    from apmcal.preprocessing.firmware import firmware_generation
    from apmcal.vehicle.params import to_ardupilot_params, withhold_undetermined

    recording, mag_recording = pick_recording(contents, instance)
    cal = calibrate(recording, method, lat_deg, lon_deg)
    if mag_recording is not None:
        calibrate_magnetometer(cal, mag_recording, lat_deg, lon_deg)
    if not cal.sensors:
        raise ApmcalError("nothing could be calibrated: "
                          + "; ".join(cal.report.get("warnings", [])), contents.path)
    if generation is None and contents.format == "csv":
        return cal, None
    generation = generation or firmware_generation(contents.params, contents.firmware)
    proposal = to_ardupilot_params(cal, generation, instance=recording.instance,
                                   current_params=contents.params)
    withhold_undetermined(proposal, cal.report.get("undetermined", {}))
    cal.params = dict(proposal.values)
    return cal, proposal


def pick_recording(contents, instance: int | None):
    """(IMU recording, separate magnetometer recording of the same instance or None)."""
    candidates = [r for r in contents.recordings if r.has("acc")]
    if instance is not None:
        candidates = [r for r in candidates if r.instance == instance]
    if not candidates:
        which = "" if instance is None else f" for instance {instance}"
        raise ApmcalError(f"no accelerometer recording{which}", contents.path)
    recording = candidates[0]
    mags = [r for r in contents.recordings if r.has("mag") and r.instance == recording.instance]
    return recording, (mags[0] if mags and mags[0] is not recording else None)


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


LEVEL_TOLERANCE_DEG = 10.0     # seed 002 §3.2 levels the platform with a plumb line


def tilt_from_level_deg(acc_mean: np.ndarray) -> float:
    """Angle [deg] between the mean specific force and a level vehicle's (0, 0, −g)."""
    up = -np.asarray(acc_mean, dtype=float) / np.linalg.norm(acc_mean)
    return float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))


def longest_static_segment(t, acc, gyr, source: str):
    """The longest still period that is level (the one-position method's input)."""
    from apmcal.preprocessing.static import find_static_segments

    segments = find_static_segments(t, acc, gyr)
    level = [s for s in segments if tilt_from_level_deg(s.acc_mean) <= LEVEL_TOLERANCE_DEG]
    if not level:
        tilts = ", ".join(f"{tilt_from_level_deg(s.acc_mean):.0f}°" for s in segments[:5])
        found = f" (still periods found, tilted {tilts})" if segments else ""
        raise ApmcalError("one-position method: no level still period found; hold the vehicle "
                          f"level (z down, x north) for about a minute{found}", source)
    return max(level, key=lambda s: s.end - s.start)


def distinct_orientations(segments, min_chord: float = 0.5) -> int:
    """Number of hold orientations whose mean accelerometer vectors are at least ``min_chord``
    field radii apart (0.5 radius ≈ 30°), by greedy clustering.

    The radius is g when the samples are in m/s²; for raw counts (large offsets, unknown scale)
    it is half the largest distance between hold means, provided that distance stands well
    above the holds' own noise.
    """
    means = np.array([s.acc_mean for s in segments])
    if len(means) == 0:
        return 0
    radius = float(np.median(np.linalg.norm(means, axis=1)))
    if not 0.7 * STANDARD_GRAVITY < radius < 1.3 * STANDARD_GRAVITY:     # not m/s²: counts
        spread = max(np.linalg.norm(means[:, None] - means[None], axis=2).max() / 2, 0.0)
        noise = float(np.median([np.linalg.norm(s.acc_std) for s in segments]))
        if spread < 10 * noise:
            return 1
        radius = spread
    centres: list[np.ndarray] = []
    for m in means:
        if all(np.linalg.norm(m - c) >= min_chord * radius for c in centres):
            centres.append(m)
    return len(centres)


def accelerometer_ellipsoid(t, acc, gyr, lat_deg) -> Calibration:
    """Ellipsoid fit (seed 000) of the static-hold means; gyro offset from the held samples."""
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.solvers.ellipsoid import ellipsoid_calibration

    segments = find_static_segments(t, acc, gyr)
    n_orient = distinct_orientations(segments)
    if len(segments) < MIN_ELLIPSOID_HOLDS or n_orient < MIN_ORIENTATIONS:
        raise ApmcalError(f"ellipsoid fit needs at least {MIN_ELLIPSOID_HOLDS} static holds in "
                          f"{MIN_ORIENTATIONS} or more orientations; found {len(segments)} holds "
                          f"in {n_orient} orientation(s)")
    samples = {"acc": np.array([s.acc_mean for s in segments])}
    if gyr is not None:
        samples["gyr"] = np.concatenate([gyr[s.kept()] for s in segments])
    cal = ellipsoid_calibration(samples, {"acc": local_gravity(lat_deg)})
    cal.report["static_segments"] = len(segments)
    return cal


def local_gravity(lat_deg: float | None) -> float:
    """WGS-84 normal gravity at the latitude, or standard gravity when it is unknown [m/s²]."""
    return STANDARD_GRAVITY if lat_deg is None else normal_gravity(lat_deg)


def has_live_magnetometer(recording: Recording) -> bool:
    """True when mag columns exist and are not all zero (an absent compass logs zeros)."""
    return recording.has("mag") and bool(np.any(recording.xyz("mag")))
