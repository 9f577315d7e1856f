"""From a recording to a calibration: prepare the samples, pick and run a solver.

This is the only place that joins the stages; readers never call solvers and solvers never read
files. Preparation, in order: strictly increasing time; integer telemetry moved off its
truncation bias; the firmware's correction and board orientation undone, so that every solver
sees raw sensor-frame samples. Static holds are found once and shared by the methods.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.core.options import Options
from apmcal.core.recording import Recording
from apmcal.preprocessing.prepare import (
    Prepared,
    has_live_magnetometer,
    pick_recording,
    prepare,
    recording_date,
)
from apmcal.solvers.holds import MIN_ELLIPSOID_HOLDS, MIN_ORIENTATIONS, distinct_orientations
from apmcal.solvers.report_types import CalibrationReport
from apmcal.solvers.resolution_floor import with_resolution_floor
from apmcal.solvers.result import Calibration

METHODS = ("auto", "ferraris", "static", "ellipsoid", "joint")
FERRARIS_FACES = {"x_p", "x_a", "y_p", "y_a", "z_p", "z_a"}
FERRARIS_MAX_TILT_DEG = 10.0    # Ferraris assumes each hold has one axis along gravity


def choose_method(segments, gyro_and_compass: bool = False) -> str:
    """'ferraris' for the six axis-aligned faces; for holds in four orientations or more,
    'joint' when ``gyro_and_compass`` (see :func:`has_gyro_and_compass`),
    else 'ellipsoid'; 'static' otherwise.

    Parameters
    ----------
    segments : list of StaticSegment
        The still periods.
    gyro_and_compass : bool

    Returns
    -------
    str
    """
    from apmcal.preprocessing.static import label_poses

    aligned = [s for s in segments if s.tilt_deg <= FERRARIS_MAX_TILT_DEG]
    if FERRARIS_FACES <= set(label_poses(aligned)):
        # six faces suffice for the accelerometer part; without a full turn about each axis the
        # gyro keeps an identity matrix (with a warning) and only its offset is calibrated
        return "ferraris"
    if len(segments) >= MIN_ELLIPSOID_HOLDS and distinct_orientations(segments) >= MIN_ORIENTATIONS:
        # hand-held poses with turns between them: [Chow]'s joint fit also calibrates the
        # gyro's scale and misalignment from the turns (out of sample, 0.4° against the
        # ellipsoid's 10.7° on sitl's hand-held session: benchmarks/joint_validation.py)
        return "joint" if gyro_and_compass else "ellipsoid"
    return "static"


def has_gyro_and_compass(prepared: Prepared, mag_recording: Recording | None) -> bool:
    """True when the session has what auto needs to pick the joint method: gyro samples and a
    live compass (in the IMU's own record or a separate one). Whether the holds are turned
    between is the joint fit's own check; auto falls back to the ellipsoid when it fails."""
    if not prepared.raw.has("gyr"):
        return False
    return has_live_magnetometer(prepared.raw) or (mag_recording is not None
                                                   and has_live_magnetometer(mag_recording))


def calibrate(recording: Recording, opts: Options | None = None,
              mag_recording: Recording | None = None) -> Calibration:
    """Calibrate ``recording`` (raw or firmware-corrected): the result is for the raw
    sensor-frame samples.

    ``method="auto"`` picks by the still periods (:func:`choose_method`): Ferraris for the six
    faces, the joint method for holds in four orientations or more with gyro and compass (the
    ellipsoid, with a warning, when the joint fit refuses the session), the ellipsoid without a
    compass, the one-position method else. A recording that suits no accelerometer method (a
    magnetometer tumble, say) still yields its magnetometer calibration, with a warning.
    ``mag_recording`` (a separate compass record, dataflash MAG) is only used by the joint
    method, which calibrates the compass together with the IMU.

    Parameters
    ----------
    recording : Recording
    opts : Options, optional
    mag_recording : Recording, optional

    Returns
    -------
    Calibration
        For raw sensor-frame samples (m/s², rad/s, mGauss), sigmas widened by the resolution.

    Raises
    ------
    ApmcalError
        For an unknown method, a recording without accelerometer, or a method given explicitly
        that cannot calibrate the session.
    """
    opts = opts or Options()
    if opts.method not in METHODS:
        raise ApmcalError(f"unknown method {opts.method!r}; choose one of {', '.join(METHODS)}")
    if not recording.has("acc"):
        raise ApmcalError("recording has no accelerometer samples", recording.source)
    prepared = prepare(recording, opts.generation)
    if opts.method == "joint":
        return joint_calibration_of(prepared, separate_compass(prepared, mag_recording, opts),
                                    opts)
    segments, fallback = find_holds(prepared, opts), []
    if opts.method == "auto" and segments and choose_method(
            segments, has_gyro_and_compass(prepared, mag_recording)) == "joint":
        mag_prepared = separate_compass(prepared, mag_recording, opts)
        try:
            cal = joint_calibration_of(prepared, mag_prepared, opts)
        except ApmcalError as err:
            fallback = [f"joint calibration not possible ({err.why}); the ellipsoid fit is used"]
        else:
            return with_own_compass_fit(cal, prepared, mag_prepared, opts)
    try:
        cal = inertial_calibration(prepared, opts, segments)
    except ApmcalError as err:
        if opts.method != "auto":
            raise
        cal = Calibration(method="none", report=CalibrationReport(
            warnings=[f"accelerometer and gyro not calibrated: {err.why}"]))
    cal = with_parts(cal, warnings=fallback + prepared.warnings,
                     sensors=with_resolution_floor(cal.sensors, prepared.floor_steps,
                                                   {"acc": opts.gravity}))
    if has_live_magnetometer(prepared.raw):
        cal = with_compass(cal, compass_part(prepared, opts))
    return cal


def separate_compass(prepared: Prepared, mag_recording: Recording | None,
                     opts: Options) -> Prepared | None:
    """A separate compass record (dataflash MAG) prepared once for the joint path; None when
    there is none or it is the IMU's own record.

    Parameters
    ----------
    prepared : Prepared
        The IMU recording, prepared.
    mag_recording : Recording or None
    opts : Options

    Returns
    -------
    Prepared or None
    """
    if mag_recording is None or mag_recording is prepared.raw:
        return None
    return prepare(mag_recording, opts.generation)


def joint_calibration_of(prepared: Prepared, mag_prepared: Prepared | None,
                         opts: Options) -> Calibration:
    """[Chow]'s joint calibration of IMU and compass (:mod:`apmcal.calibration.joint`).

    Parameters
    ----------
    prepared : Prepared
    mag_prepared : Prepared or None
        A separate compass record, prepared (:func:`separate_compass`).
    opts : Options

    Returns
    -------
    Calibration
        Method "joint", sigmas widened by the resolution.

    Raises
    ------
    ApmcalError
        When the joint fit refuses the session.
    """
    from apmcal.calibration.joint import joint_on_prepared

    cal = joint_on_prepared(prepared, mag_prepared, opts)
    warnings = list(prepared.warnings)
    if mag_prepared is not None:
        warnings += [f"mag: {w}" for w in mag_prepared.warnings]
    # one floor for all sensors: the compass is already in the result
    magnitudes = {"acc": opts.gravity}
    if "mag" in cal.sensors:
        magnitudes["mag"] = cal.report.magnetic_field.mgauss
    return with_parts(cal, warnings=warnings,
                      sensors=with_resolution_floor(cal.sensors, prepared.floor_steps, magnitudes))


def find_holds(prepared: Prepared, opts: Options) -> list:
    """The still periods (StaticSegment) of at least ``opts.min_still_s``, found once for
    every method but the joint one (which finds its own on the compass's time span).

    Parameters
    ----------
    prepared : Prepared
    opts : Options

    Returns
    -------
    list of StaticSegment
    """
    from apmcal.preprocessing.static import find_static_segments

    raw = prepared.raw
    gyr = raw.xyz("gyr") if raw.has("gyr") else None
    return find_static_segments(raw.t, raw.xyz("acc"), gyr, min_duration=opts.min_still_s)


def with_own_compass_fit(cal: Calibration, prepared: Prepared, mag_prepared: Prepared | None,
                         opts: Options) -> Calibration:
    """The joint result with its compass replaced by the compass's own ellipsoid fit (auto).

    The joint fit knows the compass only within its windows; on sitl hand-held sessions its
    compass offsets were several times further from the truth than the ellipsoid fit's on the
    same samples, while its accelerometer and gyro were as close or closer
    (``python benchmarks/joint_auto.py``). The joint's compass conditions still served the
    gyro. If the ellipsoid fit fails, the joint's compass is kept.

    Parameters
    ----------
    cal : Calibration
        The joint result.
    prepared : Prepared
    mag_prepared : Prepared or None
        A separate compass record, prepared (:func:`separate_compass`).
    opts : Options

    Returns
    -------
    Calibration
        A new result: ``cal`` with the compass's own fit, or with its own compass and the
        warning why the compass's own fit failed.
    """
    source = prepared if has_live_magnetometer(prepared.raw) else mag_prepared
    part = compass_part(source, opts)
    if part.sensor is not None:
        return with_compass(cal, part, joint=replace(cal.report.joint, compass_own_fit=True))
    if "mag" in cal.sensors:        # the joint's compass kept: the failed fit leaves its warning
        return with_parts(cal, warnings=part.warnings)
    return with_compass(cal, part)


def inertial_calibration(prepared: Prepared, opts: Options, segments: list) -> Calibration:
    """Accelerometer and gyro calibration of the prepared samples by the chosen method, on the
    still periods ``segments`` (:func:`find_holds`); auto here never means joint (the caller
    has tried it).

    Parameters
    ----------
    prepared : Prepared
    opts : Options
    segments : list of StaticSegment

    Returns
    -------
    Calibration

    Raises
    ------
    ApmcalError
        Without a still period, or when the chosen method cannot use the session.
    """
    from apmcal.preprocessing.ferraris_regions import ferraris_regions
    from apmcal.solvers.ferraris import ferraris_calibration
    from apmcal.solvers.holds import ellipsoid_on_holds, one_position_on_holds

    raw = prepared.raw
    t, acc = raw.t, raw.xyz("acc")
    gyr = raw.xyz("gyr") if raw.has("gyr") else None
    if not segments:
        raise ApmcalError(f"no still period of {opts.min_still_s:g} s or more found: hold the "
                          "vehicle still (or lower --min-still)")
    method = choose_method(segments) if opts.method == "auto" else opts.method
    if method == "ferraris":
        regions = ferraris_regions(t, acc, gyr, segments=segments)
        return ferraris_calibration(t, acc, gyr, regions, lat_deg=opts.lat_deg,
                                    gravity=opts.gravity, gyro_step=prepared.steps.get("gyr", 0.0))
    if method == "ellipsoid":
        return ellipsoid_on_holds(gyr, segments, opts.gravity)
    return one_position_on_holds(t, acc, gyr, segments, opts.lat_deg, opts.lon_deg,
                                 board_rotation(raw))


def board_rotation(recording: Recording) -> np.ndarray:
    """AHRS_ORIENTATION as a matrix (sensor → body); identity when the source does not say.

    ardupilot-facts.md "How the firmware applies the parameters": AHRS_ORIENTATION rotates
    sensor vectors into the body frame; "level" and "x north" are the vehicle's, not the board's.

    Parameters
    ----------
    recording : Recording

    Returns
    -------
    (3, 3) array
    """
    from apmcal.ardupilot.orientation import rotation_matrix

    code = recording.params.get("AHRS_ORIENTATION")
    if code is None:
        return np.eye(3)
    return rotation_matrix(code, recording.params)


def calibrate_log(contents, opts: Options | None = None):
    """Calibrate one IMU instance of a log (and its compass) and propose ArduPilot parameters.

    Returns (Calibration, ParamProposal or None); None when the source is not an ArduPilot log
    and no generation was given (a CSV file has no firmware to write parameters for).

    Parameters
    ----------
    contents : LogContents
    opts : Options, optional

    Returns
    -------
    Calibration
    ParamProposal or None

    Raises
    ------
    ApmcalError
        When no recording fits or nothing could be calibrated.
    """
    from apmcal.ardupilot.firmware import firmware_generation
    from apmcal.ardupilot.params import to_ardupilot_params, withhold_undetermined
    from apmcal.preprocessing.param_changes import split_at_param_changes

    opts = opts or Options()
    recording, mag_recording = pick_recording(contents, opts.instance)
    recording, mag_recording, change_warnings = split_at_param_changes(
        recording, mag_recording, contents.param_changes, contents.path)
    if opts.date is None:
        opts = replace(opts, date=recording_date(contents))
    cal = with_parts(calibrate(recording, opts, mag_recording), warnings=change_warnings,
                     recording=f"{recording.message} (IMU instance {recording.instance})")
    if mag_recording is not None and "mag" not in cal.sensors:
        if has_live_magnetometer(mag_recording):
            mag_prepared = prepare(mag_recording, opts.generation)
            cal = with_compass(with_parts(cal, warnings=[f"mag: {w}" for w in
                                                          mag_prepared.warnings]),
                               compass_part(mag_prepared, opts))
    if (mag_recording is not None and not has_live_magnetometer(recording)
            and has_live_magnetometer(mag_recording)
            and ("mag" in cal.sensors or "mag" in cal.report.not_calibrated)):
        # the IMU's record has no compass of its own (none, or one in impossible units
        # dropped, e.g. HIGHRES_IMU's mGauss×1000): say where the compass came from
        cal = with_parts(cal, recording=f"{cal.report.recording}; compass from "
                                        f"{mag_recording.message} (instance "
                                        f"{mag_recording.instance})")
    if not cal.sensors:
        raise ApmcalError("nothing could be calibrated: "
                          + "; ".join(cal.report.warnings), contents.path)
    cal = with_parts(cal, at_rest=at_rest(recording, mag_recording, opts))
    if opts.generation is None and contents.format == "csv":
        return cal, None
    logged = (firmware_generation(contents.params, contents.firmware)
              if contents.format != "csv" else None)
    generation = opts.generation or logged
    proposal = to_ardupilot_params(cal, generation, instance=recording.instance,
                                   current_params=contents.params)
    if logged is not None and generation != logged:
        # the samples were un-corrected and the values made with another generation's formulas
        # than the vehicle's own: said where the verdict is read, and in the proposal
        said = contents.firmware or "its parameters"
        cal = with_parts(cal, warnings=[
            f"--firmware {generation} given, but this log's firmware ({said}) uses the "
            f"{logged} formulas: the samples were un-corrected and the parameters made for "
            f"{generation}, so they are wrong for this vehicle unless it runs {generation}"])
        proposal.notes.append(f"made for firmware {generation} (--firmware), not for the "
                              f"log's {logged}")
    withhold_undetermined(proposal, cal.report.undetermined)
    return replace(cal, params=dict(proposal.values)), proposal


def at_rest(recording: Recording, mag_recording: Recording | None, opts: Options):
    """What the sensors read at rest with the calibration in force, as logged
    (:class:`~apmcal.solvers.report_types.AtRest`): the median |specific force| of the still
    periods [m/s²] beside gravity at the site, the median |field| [mGauss] beside the WMM's
    (with --lat/--lon). None without a still period."""
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.solvers.report_types import AtRest

    acc = recording.xyz("acc")
    gyr = recording.xyz("gyr") if recording.has("gyr") else None
    ok = np.all(np.isfinite(acc), axis=1) & (np.all(np.isfinite(gyr), axis=1)
                                             if gyr is not None else True)
    try:
        segments = find_static_segments(recording.t[ok], acc[ok],
                                        None if gyr is None else gyr[ok],
                                        min_duration=opts.min_still_s)
    except ApmcalError:
        segments = []
    if not segments:
        return None
    acc_norm = float(np.median([np.linalg.norm(s.acc_mean) for s in segments]))
    mag_norm = wmm = None
    compass = next((r for r in (recording, mag_recording)
                    if r is not None and has_live_magnetometer(r)), None)
    if compass is not None:
        mag = compass.xyz("mag")
        mag = mag[np.all(np.isfinite(mag), axis=1)]
        mag_norm = float(np.median(np.linalg.norm(mag, axis=1))) if len(mag) else None
    if mag_norm is not None and opts.lat_deg is not None and opts.lon_deg is not None:
        from apmcal.core.geomag import field_magnitude

        wmm = field_magnitude(opts.lat_deg, opts.lon_deg, opts.date)[0]
    return AtRest(acc_norm, float(opts.gravity), mag_norm, wmm)


@dataclass
class CompassPart:
    """The compass's own fit as the calibration takes it in (:func:`compass_part`).

    Attributes
    ----------
    sensor : SensorCalibration or None
        Sigmas widened by the resolution; None when the fit was not possible.
    ellipsoid : EllipsoidFit or None
    magnetic_field : MagneticField or None
        With the samples' coverage of the directions.
    warnings : list of str
        The fit's warnings, or why it was not possible.
    not_calibrated : str or None
        Why not, for the verdict.
    not_measured : bool
        Not because the session did not turn the compass enough (nothing wrong with it): the
        compass stays out of the overall verdict.
    """

    sensor: object = None
    ellipsoid: object = None
    magnetic_field: object = None
    warnings: list[str] = field(default_factory=list)
    not_calibrated: str | None = None
    not_measured: bool = False


def compass_part(prepared: Prepared, opts: Options) -> CompassPart:
    """The magnetometer fit of ``prepared``'s compass samples [mGauss], or why it was not
    possible (:func:`apmcal.solvers.magnetometer.calibrate_magnetometer`).

    Parameters
    ----------
    prepared : Prepared
        With magnetometer samples [mGauss].
    opts : Options

    Returns
    -------
    CompassPart
    """
    from apmcal.solvers.magnetometer import CompassNotMeasured, calibrate_magnetometer

    mag = prepared.raw.xyz("mag")
    try:
        fit = calibrate_magnetometer(mag, opts.lat_deg, opts.lon_deg, opts.date,
                                     prepared.steps.get("mag"))
    except ApmcalError as err:
        return CompassPart(warnings=[err.why], not_calibrated=err.why,
                           not_measured=isinstance(err, CompassNotMeasured))
    cover = mag_coverage(mag, fit.sensor)
    magnetic_field = replace(fit.magnetic_field, coverage_fraction=cover["fraction"],
                             coverage_min_eig=cover["min_eig"])
    steps = {"mag": prepared.floor_steps["mag"]} if "mag" in prepared.floor_steps else {}
    sensor = with_resolution_floor({"mag": fit.sensor}, steps, {"mag": magnetic_field.mgauss})
    return CompassPart(sensor["mag"], fit.ellipsoid, magnetic_field, fit.warnings)


def with_compass(cal: Calibration, part: CompassPart, **report_fields) -> Calibration:
    """A new result: ``cal`` with the compass of ``part`` (replacing any it had), its ellipsoid
    fit, field and warnings; or, when ``part`` has no fit, ``cal``'s sensors and why not.

    Parameters
    ----------
    cal : Calibration
    part : CompassPart
    **report_fields
        Further fields of the report to set.

    Returns
    -------
    Calibration
    """
    if part.sensor is None:
        not_calibrated = {**cal.report.not_calibrated, "mag": part.not_calibrated}
        not_measured = list(cal.report.not_measured)
        if part.not_measured and "mag" not in not_measured:
            not_measured.append("mag")
        return with_parts(cal, warnings=part.warnings, not_calibrated=not_calibrated,
                          not_measured=not_measured, **report_fields)
    sensors = {name: sc for name, sc in cal.sensors.items() if name != "mag"}
    sensors["mag"] = part.sensor
    return with_parts(cal, warnings=part.warnings, sensors=sensors,
                      ellipsoids={**cal.report.ellipsoids, "mag": part.ellipsoid},
                      magnetic_field=part.magnetic_field, **report_fields)


def with_parts(cal: Calibration, warnings=(), sensors=None, **report_fields) -> Calibration:
    """A new result: ``cal`` with further ``warnings`` (after its own), other ``sensors`` and
    report fields; ``cal`` itself is left as it is.

    Parameters
    ----------
    cal : Calibration
    warnings : sequence of str
    sensors : dict, optional
        name → SensorCalibration (default: ``cal``'s).
    **report_fields
        Fields of :class:`~apmcal.solvers.report_types.CalibrationReport` to set.

    Returns
    -------
    Calibration
    """
    report = replace(cal.report, warnings=[*cal.report.warnings, *warnings], **report_fields)
    return replace(cal, sensors=dict(cal.sensors if sensors is None else sensors),
                   report=report)


def mag_coverage(mag: np.ndarray, cal) -> dict:
    """How well the compass samples [mGauss] cover the directions around the fitted offset:
    ``fraction`` of the sphere within 20° of a sample, ``min_eig`` the smallest eigenvalue of
    3·mean(n nᵀ) (1 uniform, 0 all in one plane). Numbers for apmcal.report.verdict.

    Parameters
    ----------
    mag : (n, 3) array
        Raw samples [mGauss].
    cal : SensorCalibration
        The fit (its offset (3,) [mGauss]).

    Returns
    -------
    dict
        "fraction" and "min_eig" (floats).
    """
    from apmcal.solvers.coverage import direction_coverage

    # the fraction from at most 40 000 samples, as the ellipsoid fit's own (a pass over the
    # samples per grid point: on a 10-minute 400 Hz session the whole set cost 0.5 s)
    cov = direction_coverage(mag, cal.offset, fraction_samples=40_000)
    return {"fraction": cov["fraction"], "min_eig": float(np.min(cov["scatter_eig"]))}
