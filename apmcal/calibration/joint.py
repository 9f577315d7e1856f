"""Joins the stages for ``--method joint`` ([Chow]): the compass samples are brought onto the
IMU's time base, the still periods found, the field magnitude chosen, the solver run.

Kept apart from :mod:`apmcal.calibration.log` because the joint method needs the compass together with
the IMU (the other methods calibrate the compass on its own, afterwards).
"""
from __future__ import annotations

import datetime
from dataclasses import replace

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.prepare import compass_on_imu_times
from apmcal.solvers.report_types import MagneticField
from apmcal.solvers.result import Calibration

MIN_HOLDS = 3      # still poses; fewer leave most of the 42 parameters undetermined
# The fit's cost grows with the samples in the turns (a 120 s hand-held session at 400 Hz took
# 60 s), while its accuracy does not change with the rate: on sitl hand-held sessions at 200 Hz,
# fits on block means at 200, 100, 50 and 20 Hz were as close to the injected errors
# (python benchmarks/joint_auto.py). Faster recordings are averaged down to this rate first;
# 50 Hz rather than 20 keeps a fast hand turn (360°/s) under 8° per sample.
JOINT_RATE_HZ = 50.0


def field_magnitude(mag: np.ndarray, opts) -> tuple[MagneticField, list[str]]:
    """Field magnitude [mGauss] that fixes the scale of the soft-iron matrix: the World
    Magnetic Model's at --lat/--lon when given, else the samples' sphere fit; with the model's
    warning when it has one.

    Parameters
    ----------
    mag : (n, 3) array
        Raw compass samples [mGauss].
    opts : Options
        Its ``lat_deg``, ``lon_deg`` [deg] and ``date``.

    Returns
    -------
    MagneticField
        The magnitude [mGauss] and where it came from.
    list of str
        Warnings.
    """
    from apmcal.core.geomag import field_magnitude
    from apmcal.solvers.ellipsoid.fit import sphere_fit

    warnings = []
    if opts.lat_deg is not None and opts.lon_deg is not None:
        when = opts.date or datetime.date.today()
        radius, note = field_magnitude(opts.lat_deg, opts.lon_deg, when)
        if note:
            warnings.append(f"mag: {note}")
        origin = f"WMM at {when}"
    else:
        radius, origin = float(sphere_fit(mag)[1]), "sphere fit (no --lat/--lon)"
    return MagneticField(float(radius), origin), warnings


def at_joint_rate(t, acc, gyr, mag):
    """The samples averaged down to :data:`JOINT_RATE_HZ` (block means) and the samples per
    block (1: unchanged, the recording is not faster).

    Parameters
    ----------
    t : (n,) array, s
    acc : (n, 3) array, m/s²
    gyr : (n, 3) array, rad/s
    mag : (n, 3) array, mGauss, or None

    Returns
    -------
    tuple
        t (m,), acc, gyr, mag (m, 3) (mag None when given None) and the samples per block (int).
    """
    from apmcal.preprocessing.decimation import block_means, factor_for_rate

    k = factor_for_rate(t, JOINT_RATE_HZ)
    if k == 1:
        return t, acc, gyr, mag, 1
    return (*(block_means(x, k) for x in (t, acc, gyr, mag)), k)


def joint_on_prepared(prepared, mag_prepared, opts) -> Calibration:
    """[Chow]'s joint calibration of a prepared recording and its compass.

    Without a live compass the accelerometer and gyro are calibrated alone (their 30
    parameters; the compass conditions are left out, [Chow] §3.2), with a warning. Raises
    ApmcalError (one line) when there are too few still poses or no turns between them.

    Parameters
    ----------
    prepared : Prepared
        The IMU recording (:func:`apmcal.preprocessing.prepare.prepare`).
    mag_prepared : Prepared or None
        A separate compass recording.
    opts : Options

    Returns
    -------
    Calibration
        Method "joint" (sensors acc, gyr, and mag when there is a compass).

    Raises
    ------
    ApmcalError
        Without gyro samples, when compass and IMU do not overlap in time, with too few still
        poses or no turns between them, or when the session does not determine the parameters.
    """
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.solvers.joint.solve import joint_calibration

    raw = prepared.raw
    if not raw.has("gyr"):
        raise ApmcalError("joint calibration needs gyro samples; this recording has none")
    t = raw.t
    mag = compass_on_imu_times(t, prepared, mag_prepared)
    warnings = []
    if mag is None:
        warnings.append("no compass in this session (or it logged only zeros): the "
                        "accelerometer and gyro are calibrated without it")
        span = np.ones(len(t), bool)
    else:
        span = np.all(np.isfinite(mag), axis=1)
        if span.sum() < 10:
            raise ApmcalError("joint calibration: the compass and IMU records do not overlap "
                              "in time")
        mag = mag[span]
    t, acc, gyr = t[span], raw.xyz("acc")[span], raw.xyz("gyr")[span]
    recorded_hz = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else None
    t, acc, gyr, mag, block = at_joint_rate(t, acc, gyr, mag)
    holds = find_static_segments(t, acc, gyr, min_duration=opts.min_still_s)
    if len(holds) < MIN_HOLDS:
        raise ApmcalError(f"joint calibration needs at least {MIN_HOLDS} still poses with turns "
                          f"between them; found {len(holds)} still period(s) of "
                          f"{opts.min_still_s:g} s or more")
    magnetic_field = None
    if mag is not None:
        magnetic_field, notes = field_magnitude(mag, opts)
        warnings += notes
    try:
        cal = joint_calibration(t, acc, gyr, mag, holds, gravity=opts.gravity,
                                field_mgauss=None if magnetic_field is None
                                else magnetic_field.mgauss)
    except np.linalg.LinAlgError as err:      # a degenerate session (e.g. all poses alike)
        raise ApmcalError(f"joint calibration: the session does not determine the parameters "
                          f"({err}); add still poses in other orientations") from None
    report = cal.report
    return replace(cal, report=replace(
        report, warnings=warnings + report.warnings,
        magnetic_field=magnetic_field or report.magnetic_field,
        holds=replace(report.holds, count=len(holds)),
        joint=replace(report.joint, block_samples=block, recorded_rate_hz=recorded_hz)))
