"""Out-of-sample check of calibration methods on recordings ([Chow] §5): read a session,
fit a method on (part of) it, score the gyro's orientation change between still poses of
another session or of its later part (:mod:`apmcal.calibration.orientation_check`).

:data:`REAL_RECORDINGS` are the real recordings with turns between still poses that the checks
run on (names relative to the test data folder, which the caller gives), each fitted on its
first still poses and checked on the turns after them (:func:`out_of_sample`).

Glue for ``benchmarks/joint_validation.py`` and the tests; like :mod:`apmcal.calibration.log` it
joins the stages (reading, preparation, solvers) and is the only other module that does.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from apmcal.calibration.log import calibrate, compass_part, with_compass
from apmcal.calibration.orientation_check import orientation_errors
from apmcal.core.options import Options
from apmcal.preprocessing.prepare import pick_recording, prepare
from apmcal.preprocessing.static import find_static_segments
from apmcal.solvers.joint.residuals import ACC_RANGES_M_S2, at_range_limit
from apmcal.solvers.joint.solve import joint_calibration
from apmcal.solvers.result import Calibration


def session(path: Path, layout: str | None = None, counts: dict | None = None):
    """(IMU recording, its separate compass recording or None, prepared raw recording, compass
    samples on the same times or None, still poses) of the session in ``path``.

    Parameters
    ----------
    path : Path
        A log or CSV file.
    layout : str, optional
        CSV layout (:func:`apmcal.sources.csv.read_csv`); the file is sniffed when None.
    counts : dict, optional
        For raw counts: sensor ("acc", "gyr") → (zero [counts], SI per count, or None for
        the accelerometer: local gravity over the first still pose's magnitude), applied
        before anything else (:func:`in_si`).

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
    if counts:
        rec = in_si(rec, counts)
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
        from apmcal.calibration.joint import at_joint_rate

        keep = np.ones(len(raw.t), bool) if part is None else part
        if mag is not None:
            keep = keep & np.all(np.isfinite(mag), axis=1)
        # as the command line runs it: block means at its rate, the still poses found on them
        t, acc, gyr, m, _ = at_joint_rate(raw.t[keep], raw.xyz("acc")[keep],
                                          raw.xyz("gyr")[keep], None if mag is None else mag[keep])
        hs = find_static_segments(t, acc, gyr, min_duration=opts.min_still_s)
        return joint_calibration(t, acc, gyr, m, hs, gravity=opts.gravity,
                                 field_mgauss=_field(opts))
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


def in_si(rec, counts: dict):
    """A recording in raw counts brought to SI units: (counts − zero)·factor per sensor; an
    accelerometer factor of None is the one that makes the first still pose read standard
    gravity (a nominal scale: the calibration fits the rest, as imu_tk does from 1).

    Parameters
    ----------
    rec : Recording
        Columns acc_* (and gyr_*) in counts.
    counts : dict
        sensor ("acc", "gyr") → (zero [counts], factor [SI per count] or None).

    Returns
    -------
    Recording
        A copy, columns in m/s² and rad/s.
    """
    from apmcal.core.constants import STANDARD_GRAVITY

    data = rec.data.copy()
    for sensor, (zero, factor) in counts.items():
        cols = [f"{sensor}_{a}" for a in "xyz"]
        centred = data[cols].to_numpy(float) - zero
        if factor is None:
            first = find_static_segments(rec.t, centred, None, min_duration=1.0)[0]
            factor = STANDARD_GRAVITY / float(np.linalg.norm(first.acc_mean))
        data[cols] = centred * factor
    return replace(rec, data=data)


@dataclass(frozen=True)
class RealRecording:
    """A real recording with turns between still poses, checked out of sample: fitted on the
    samples up to the end of its ``fit_holds``-th still pose, checked on every turn after that
    (from that pose on), or on the still poses of the separate recording ``check_file``.

    Attributes
    ----------
    name : str
        What the table calls it.
    file : str
        Relative to the test data folder.
    layout : str or None
        CSV layout.
    fit_holds : int or None
        Still poses fitted on (None: all, the checks run on ``check_file``).
    check_file : str or None
        A separate recording of the same sensor, checked.
    counts : dict or None
        Raw counts' conversion (:func:`in_si`).
    compass : bool
        Whether it logs a compass (the attitude is checked, else the tilt).
    """

    name: str
    file: str
    layout: str | None
    fit_holds: int | None
    check_file: str | None = None
    counts: dict | None = None
    compass: bool = False


# imu_tk's own starting point for its Xsens sequence (its test program): both sensors' counts
# centred on 32768, the gyro at 1/6258 rad/s per count
XSENS_COUNTS = {"acc": (32768.0, None), "gyr": (32768.0, 1.0 / 6258.0)}
REAL_RECORDINGS = (
    RealRecording("imucal Ferraris session (hand-held, 102 Hz): six faces → the 360° turns "
                  "after them", "imucal/example_ferraris_session.csv", "imucal", 7),
    RealRecording("imu_tk Xsens sequence (100 Hz, counts): first 19 poses → the 19 after "
                  "them", "imu_tk/xsens_acc.mat", "imu_tk", 19, counts=XSENS_COUNTS),
    RealRecording("MPU-6050 run (100 Hz): first 7 poses → the 3 oblique poses after them",
                  "mpu6050/example_data_calibration.csv", "mpu6050", 7),
    RealRecording("MPU-6050 run (100 Hz): all 10 poses → the separate 90° turn recording",
                  "mpu6050/example_data_calibration.csv", "mpu6050", None,
                  check_file="mpu6050/imu_90_x_rot.csv"),
)
METHODS = ("raw", "ferraris", "ellipsoid", "joint")


@dataclass
class Score:
    """One method's out-of-sample result on one recording.

    Attributes
    ----------
    rms_deg : float or None
        RMS orientation error over the pose pairs [deg]; None when the method could not fit.
    pairs : int
    kind : str
        "attitude" or "tilt".
    noise_deg : float
        The check's own noise: RMS over the pairs of the tilt error that the gyro's and the
        accelerometer's white noise alone would give [deg].
    note : str
        Why the method could not fit; "in-sample" when it needed the checked turns;
        "fallback" when the joint fit returned its start.
    clipped : int
        Pose pairs not checked: the gyro or accelerometer was at its range limit in the turn.
    """

    rms_deg: float | None
    pairs: int
    kind: str
    noise_deg: float
    note: str = ""
    clipped: int = 0


def out_of_sample(rec: RealRecording, data: Path, methods=METHODS) -> dict[str, Score]:
    """Fit each method on the fitted part of ``rec`` and score it on the checked poses.

    Ferraris needs the known turns: on a recording whose turns are the checked part it is
    fitted on the whole session and marked "in-sample".

    Parameters
    ----------
    rec : RealRecording
    data : Path
        The test data folder.
    methods : tuple of str

    Returns
    -------
    dict
        method → :class:`Score`.
    """
    from apmcal.core.errors import ApmcalError

    s = session(data / rec.file, rec.layout, rec.counts)
    raw, holds = s[2], s[4]
    if rec.check_file is None:
        cut = holds[rec.fit_holds - 1].i1
        part = np.arange(len(raw.t)) < cut
        val = s
        pairs = [p for p, h in zip(_pairs(raw, holds), holds) if h.i0 >= holds[rec.fit_holds - 1].i0]
    else:
        part = None
        val = session(data / rec.check_file, rec.layout, rec.counts)
        pairs = _pairs(val[2], val[4])
    # a turn read through a sensor at its range limit is no test of any calibration
    limit = np.cumsum(np.append(0, at_range_limit(val[2].xyz("gyr"))
                                | at_range_limit(val[2].xyz("acc"), ACC_RANGES_M_S2)))
    kept = [p for p in pairs if limit[p.k1 + 1] == limit[p.k0]]
    clipped, pairs = len(pairs) - len(kept), kept
    noise = check_noise_deg(val[2], val[4], pairs)
    out = {}
    for m in methods:
        note, use = "", part
        if m == "ferraris" and part is not None:
            note, use = "in-sample", None
        try:
            cal = fit(m, *s, Options(m, min_still_s=1.0), part=use)
        except ApmcalError as err:
            out[m] = Score(None, len(pairs), "", noise, err.why.split(";")[0], clipped)
            continue
        if m == "joint" and cal.report.joint.fallback:
            note = "fallback"
        rms, n, kind = check(cal, val[2], val[3] if rec.compass else None, val[4], pairs)
        out[m] = Score(rms, n, kind, noise, note, clipped)
    return out


def _pairs(raw, holds):
    from apmcal.calibration.orientation_check import pose_pairs
    return pose_pairs(raw.t, holds)


def check_noise_deg(raw, holds, pairs) -> float:
    """The out-of-sample check's own noise [deg]: the RMS over ``pairs`` of the tilt error the
    sensors' white noise alone gives — the gyro's integrated over the pair's samples
    (σ_ω·Δt·√K per axis) and the accelerometer's in the two 1 s reference means
    (σ_a/(g·√N) per axis at each end); two axes each perpendicular to gravity.

    Parameters
    ----------
    raw : Recording
        The checked session (its still poses give the white noise).
    holds : list of StaticSegment
    pairs : list of PosePair

    Returns
    -------
    float
    """
    from apmcal.solvers.joint.residuals import layout

    d = layout(raw.t, raw.xyz("acc"), raw.xyz("gyr"), None, holds, 9.81, None)
    g = float(np.median([np.linalg.norm(h.acc_mean) for h in holds]))
    dt = float(np.median(np.diff(raw.t)))
    var = [2 * (d.noise["gyr"] * dt) ** 2 * (p.k1 - p.k0)
           + 2 * (d.noise["acc"] / g) ** 2 * (1 / p.ref_i.size + 1 / p.ref_j.size) for p in pairs]
    return float(np.degrees(np.sqrt(np.mean(var))))
