"""Out-of-sample check of calibration methods on recordings ([Chow] §5): read a session,
fit a method on (part of) it, score the gyro's orientation change between still poses of
another session (:mod:`apmcal.calibration.orientation_check`).

Glue for ``benchmarks/joint_validation.py`` and the tests; like :mod:`apmcal.calibration.log` it
joins the stages (reading, preparation, solvers) and is the only other module that does.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from apmcal.calibration.log import calibrate, compass_part, with_compass
from apmcal.calibration.orientation_check import orientation_errors
from apmcal.core.options import Options
from apmcal.preprocessing.prepare import pick_recording, prepare
from apmcal.preprocessing.static import find_static_segments
from apmcal.solvers.joint.solve import joint_calibration
from apmcal.solvers.result import Calibration


def session(path: Path, layout: str | None = None):
    """(IMU recording, its separate compass recording or None, prepared raw recording, compass
    samples on the same times or None, still poses) of the session in ``path``.

    Parameters
    ----------
    path : Path
        A log or CSV file.
    layout : str, optional
        CSV layout (:func:`apmcal.sources.csv.read_csv`); the file is sniffed when None.

    Returns
    -------
    rec : Recording
        The IMU recording as read.
    mag_rec : Recording or None
        A separate compass recording of the same IMU (dataflash MAG), or None.
    raw : Recording
        ``rec`` prepared (:func:`apmcal.preprocessing.prepare.prepare`): raw sensor-frame samples, n rows.
    mag : numpy.ndarray, shape (n, 3), or None
        Raw compass samples [mGauss] on ``raw``'s times, NaN outside the compass's span;
        None without a live compass.
    holds : list of StaticSegment
        Still poses of ``raw`` (at least 1 s each).

    Raises
    ------
    ApmcalError
        From the readers: an unreadable file or no usable IMU data.
    """
    from apmcal.preprocessing.prepare import compass_on_imu_times
    from apmcal.sources import read_log
    from apmcal.sources.csv import read_csv

    contents = read_csv(path, layout=layout) if layout else read_log(path)
    rec, mag_rec = pick_recording(contents, None)
    prepared = prepare(rec)
    mag_prepared = prepare(mag_rec) if mag_rec is not None else None
    mag = compass_on_imu_times(prepared.raw.t, prepared, mag_prepared)
    holds = find_static_segments(prepared.raw.t, prepared.raw.xyz("acc"),
                                 prepared.raw.xyz("gyr"), min_duration=1.0)
    return rec, mag_rec, prepared.raw, mag, holds


def fit(method: str, rec, mag_rec, raw, mag, holds, opts: Options, part=None) -> Calibration:
    """``method`` ("raw", "ferraris", "ellipsoid", "joint") fitted on the samples ``part`` (a
    boolean mask; all when None) of a :func:`session`. The joint method runs its solver
    directly, so that a session without a compass gets its accelerometer + gyro part (the
    command line refuses such a session).

    Parameters
    ----------
    method : str
        "raw", "ferraris", "ellipsoid" or "joint".
    rec, mag_rec, raw, mag, holds
        The five items of :func:`session`.
    opts : Options
        Latitude, longitude, date and gravity for the fit.
    part : numpy.ndarray of bool, shape (n,), optional
        Mask over ``raw``'s samples to fit on; all samples when None.

    Returns
    -------
    Calibration
        Identity for "raw".
    """
    if method == "raw":
        return Calibration(method="raw")
    if method == "joint":
        keep = np.ones(len(raw.t), bool) if part is None else part
        hs = [h for h in holds if keep[h.i0] and keep[h.i1 - 1]]
        return joint_calibration(raw.t[keep], raw.xyz("acc")[keep], raw.xyz("gyr")[keep],
                                 None if mag is None else mag[keep],
                                 [_shift(h, np.flatnonzero(keep)[0]) for h in hs],
                                 gravity=opts.gravity, field_mgauss=_field(opts))
    if part is not None:
        if len(rec.data) != len(raw.t):
            raise ValueError("part is a mask over the prepared samples; this recording lost "
                             "rows in preparation")
        rec = replace(rec, data=rec.data.loc[part].reset_index(drop=True))
    o = Options(method, opts.lat_deg, opts.lon_deg, 1.0, date=opts.date)
    cal = calibrate(rec, o, mag_rec)
    if mag_rec is not None and "mag" not in cal.sensors:     # as calibrate_log does
        cal = with_compass(cal, compass_part(prepare(mag_rec), o))
    return cal


def _shift(h, first: int):
    """A still period's indices counted from sample ``first``."""
    return replace(h, i0=h.i0 - first, i1=h.i1 - first,
                   excluded=tuple((a - first, b - first) for a, b in h.excluded))


def _field(opts: Options) -> float | None:
    if opts.lat_deg is None or opts.lon_deg is None:
        return None
    from apmcal.core.geomag import field_magnitude

    return field_magnitude(opts.lat_deg, opts.lon_deg, opts.date)[0]


def check(cal: Calibration, raw, mag, holds, pairs=None) -> tuple[float, int, str]:
    """(RMS orientation error [deg], number of pose pairs, "attitude" or "tilt").

    Parameters
    ----------
    cal : Calibration
        The calibration scored (from :func:`fit` on another session or part).
    raw, mag, holds
        Items of the :func:`session` checked: n samples, compass (n, 3) [mGauss] or None,
        still poses.
    pairs : list, optional
        Pose pairs to score; :func:`apmcal.calibration.orientation_check.pose_pairs` of
        ``holds`` when None.

    Returns
    -------
    rms_deg : float
        RMS orientation error over the pose pairs [deg].
    n_pairs : int
        Number of pose pairs.
    kind : str
        "attitude" (with a compass) or "tilt" (without).
    """
    r = orientation_errors(cal, raw.t, raw.xyz("acc"), raw.xyz("gyr"), mag, holds, pairs)
    return float(np.sqrt(np.mean(r["error_deg"] ** 2))), len(r["error_deg"]), r["kind"]
