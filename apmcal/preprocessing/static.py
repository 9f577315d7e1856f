"""Static periods of an IMU recording and which face of the sensor points up in each.

A sample is "static" when the moving standard deviation of the accelerometer (and gyroscope when
given) stays below a threshold adapted to the sensor's own noise, so the same code works on 2 Hz
telemetry and 1 kHz dataflash logs without tuning (the variance-vs-threshold test of Tedaldi et
al. 2014, imu_tk, with the threshold found from the record itself instead of a known rest period).
Windows and segments never reach across logging holes (dataflash stops IMU logging while
disarmed); a two-level hysteresis bridges noisy stretches inside a hold, and runs of one hold
split by a short knock (same mean specific force, no turn across the gap) are merged with the
knock's samples excluded from the statistics.

Signs (ardupilot-facts.md, "Frames and signs"): accelerometers read specific force, so at rest an
axis pointing UP reads +g and an axis pointing down reads −g; a level FRD vehicle reads
(0, 0, −g). The "up" direction in the sensor frame is therefore ``acc_mean / |acc_mean|`` and the
direction of gravity is its opposite.

Pose names follow imucal's Ferraris convention, checked on imucal's example session
(``x_p`` hold: acc_x ≈ +10.3 m/s²): ``<axis>_p`` = that axis points up (reads +g), ``<axis>_a`` =
it points down (reads −g). The ArduPilot accelerometer-calibration faces map onto them
(ardupilot-facts.md: nose up → acc_x ≈ +g, left side down → acc_y ≈ +g, upside down → acc_z ≈ +g).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.ndimage import uniform_filter1d

from apmcal.errors import ApmcalError

#: Ferraris pose name -> ArduPilot accelerometer-calibration face (ardupilot-facts.md).
ARDUPILOT_FACE = {"x_p": "noseup", "x_a": "nosedown", "y_p": "left", "y_a": "right",
                  "z_p": "back", "z_a": "level"}
POSES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")

MAX_TILT_DEG = 25.0     # a hold further than this from every axis gets no pose label
NOISE_FACTOR = 3.0      # "enter still" threshold ≥ NOISE_FACTOR × robust static noise floor
MAX_NOISE_FACTOR = 10.0  # ... and ≤ MAX_NOISE_FACTOR × floor (see noise_threshold)
NOISE_QUANTILE = 5.0    # percentile of the moving std taken as the noise floor
RATE_FACTOR = 10.0      # default max |mean rate − bias| = RATE_FACTOR × gyro std threshold
HYSTERESIS = 2.0        # a still run lasts while the moving std < HYSTERESIS × threshold
GAP_FACTOR = 5.0        # a time step > GAP_FACTOR × median interval is a logging gap
MERGE_GAP_S = 5.0       # default longest disturbance [s] bridged inside one hold
MERGE_ANGLE_DEG = 2.0   # runs of one hold: mean specific forces and gap turn within this angle


@dataclass
class StaticSegment:
    """One still period of a recording.

    Attributes
    ----------
    start, end : float
        Time [s] of the first and last sample.
    i0, i1 : int
        Sample indices, half-open: samples ``i0 .. i1-1``.
    n : int
        Number of samples.
    t_mean : float
        Mean sample time [s].
    acc_mean, acc_std : (3,) arrays
        Mean and standard deviation of the accelerometer (sensor frame, input units).
    gyr_mean, gyr_std : (3,) arrays or None
        The same for the gyroscope when one was given.
    up_axis : (3,) array
        Unit vector pointing UP, in the sensor frame: ``acc_mean / |acc_mean|`` (specific force).
    gravity_dir : (3,) array
        Unit vector of gravity (pointing down) in the sensor frame, ``-up_axis``.
    pose : str or None
        Ferraris pose name ("x_p" … "z_a") or None when tilted more than 25° from every axis.
    tilt_deg : float
        Angle [deg] between ``up_axis`` and the nearest sensor axis.
    excluded : tuple of (int, int)
        Half-open index ranges inside ``i0 .. i1-1`` left out of the statistics (short
        disturbances bridged by the merge step); ``n`` counts only the samples kept.
        Slice with :meth:`kept` rather than ``i0:i1`` to skip them.
    """

    start: float
    end: float
    i0: int
    i1: int
    n: int
    t_mean: float
    acc_mean: np.ndarray
    acc_std: np.ndarray
    gyr_mean: np.ndarray | None
    gyr_std: np.ndarray | None
    up_axis: np.ndarray
    gravity_dir: np.ndarray
    pose: str | None
    tilt_deg: float
    excluded: tuple = ()

    @property
    def duration(self) -> float:
        """Length [s] from first to last sample."""
        return self.end - self.start

    @property
    def n_excluded(self) -> int:
        """Number of samples inside ``i0 .. i1-1`` left out of the statistics."""
        return int(sum(b - a for a, b in self.excluded))

    def kept(self) -> np.ndarray:
        """Indices of the samples the statistics use (``i0 .. i1-1`` minus ``excluded``)."""
        return _kept_index(self.i0, self.i1, self.excluded)

    @property
    def face(self) -> str | None:
        """ArduPilot accelerometer-calibration face name, or None."""
        return ARDUPILOT_FACE.get(self.pose)


def pose_of(acc_mean: np.ndarray, max_tilt_deg: float = MAX_TILT_DEG) -> tuple[str | None, float]:
    """Ferraris pose name of a mean specific-force vector and its tilt [deg] from the nearest axis."""
    up = np.asarray(acc_mean, dtype=float) / np.linalg.norm(acc_mean)
    axis = int(np.argmax(np.abs(up)))
    tilt = float(np.degrees(np.arccos(min(1.0, abs(up[axis])))))
    if tilt > max_tilt_deg:
        return None, tilt
    return "xyz"[axis] + ("_p" if up[axis] > 0 else "_a"), tilt


def _kept_index(i0: int, i1: int, exclude) -> np.ndarray:
    keep = np.ones(i1 - i0, bool)
    for a, b in exclude:
        keep[max(a, i0) - i0:min(b, i1) - i0] = False
    return i0 + np.flatnonzero(keep)


def make_segment(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray | None, i0: int, i1: int,
                 max_tilt_deg: float = MAX_TILT_DEG, *, exclude=()) -> StaticSegment:
    """Statistics of samples ``i0 .. i1-1`` as a :class:`StaticSegment` (also for hand-set ranges).

    ``exclude`` lists half-open index ranges inside ``[i0, i1)`` left out of the statistics.
    """
    exclude = tuple((int(a), int(b)) for a, b in exclude)
    idx = _kept_index(int(i0), int(i1), exclude) if exclude else slice(i0, i1)
    a = acc[idx]
    acc_mean = a.mean(axis=0)
    up = acc_mean / np.linalg.norm(acc_mean)
    pose, tilt = pose_of(acc_mean, max_tilt_deg)
    g = None if gyr is None else gyr[idx]
    n = a.shape[0]
    ddof = 1 if n > 1 else 0
    return StaticSegment(
        start=float(t[i0]), end=float(t[i1 - 1]), i0=int(i0), i1=int(i1), n=int(n),
        t_mean=float(np.mean(t[idx])), acc_mean=acc_mean, acc_std=a.std(axis=0, ddof=ddof),
        gyr_mean=None if g is None else g.mean(axis=0),
        gyr_std=None if g is None else g.std(axis=0, ddof=ddof),
        up_axis=up, gravity_dir=-up, pose=pose, tilt_deg=tilt, excluded=exclude)


def moving_std(x: np.ndarray, w: int, blocks: list[tuple[int, int]] | None = None) -> np.ndarray:
    """Centred moving standard deviation of (n, 3) ``x`` over ``w`` samples, root-sum-square over axes.

    Summing per-axis variances (rather than taking the std of the norm) also catches slow
    rotations, during which the accelerometer norm stays at g but its components change.
    The window never reaches across a logging gap: each of ``blocks`` (half-open index ranges,
    default the whole record) is filtered on its own, mirrored at its ends. Blocks shorter than
    3 samples get ``inf`` (never still).
    """
    x = np.asarray(x, dtype=float)
    out = np.full(x.shape[0], np.inf)
    for b0, b1 in blocks or [(0, x.shape[0])]:
        if b1 - b0 < 3:
            continue
        xb = x[b0:b1] - np.median(x[b0:b1], axis=0)     # centre first: E[x²] − E[x]² cancels less
        wb = min(w, b1 - b0)
        m = uniform_filter1d(xb, wb, axis=0, mode="reflect")
        m2 = uniform_filter1d(xb * xb, wb, axis=0, mode="reflect")
        out[b0:b1] = np.sqrt(np.maximum(m2 - m * m, 0.0).sum(axis=1) * wb / max(wb - 1, 1))
    return out


def _otsu_log(s: np.ndarray, bins: int = 128) -> float:
    """Otsu's split of ``log(s)``: the level that best separates "still" from "moving" windows.

    Otsu (1979): maximise the between-class variance w0·w1·(μ0 − μ1)² over the histogram.
    On a log axis the still mode (noise) and the motion mode (10-1000 × noise) are well apart.
    """
    ls = np.log(s[(s > 0) & np.isfinite(s)])
    if ls.size < 2 or np.ptp(ls) == 0:
        return float(np.exp(ls[0])) if ls.size else 0.0
    h, e = np.histogram(ls, bins)
    c = 0.5 * (e[:-1] + e[1:])
    w0 = np.cumsum(h) / h.sum()
    m0 = np.cumsum(h * c) / h.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (m0[-1] * w0 - m0) ** 2 / (w0 * (1.0 - w0))
    return float(np.exp(c[np.nanargmax(between)]))


def noise_threshold(s: np.ndarray, x: np.ndarray, factor: float = NOISE_FACTOR,
                    max_factor: float = MAX_NOISE_FACTOR) -> float:
    """Noise-adapted "enter still" threshold for the moving std ``s`` of signal ``x``.

    The noise floor is a low percentile of the moving std (robust to the motion that fills the
    rest of the recording). The threshold is Otsu's split of log(s) between still and moving
    windows, kept within [``factor``, ``max_factor``] × floor: hand-held holds are 1.5-10 ×
    noisier than a bench rest (mpu6050 example: gyro std 6-10 × its bench floor), while a
    record with no motion at all has no second mode and gets ``factor`` × floor. A floor of
    1.5 quantisation steps keeps integer telemetry (RAW_IMU, 1 mG steps, ardupilot-facts.md)
    from giving a zero threshold.
    """
    finite = s[np.isfinite(s)]
    floor = float(np.percentile(finite, NOISE_QUANTILE)) if finite.size else 0.0
    thr = float(np.clip(_otsu_log(finite), factor * floor, max_factor * floor)) if finite.size else 0.0
    steps = np.abs(np.diff(x, axis=0))
    steps = steps[steps > 0]
    quantum = float(steps.min()) if steps.size else 0.0
    return max(thr, 1.5 * quantum, np.finfo(float).tiny)


def _hysteresis(s: np.ndarray, enter: float, leave: float) -> np.ndarray:
    """Two-level test: runs of ``s < leave`` that dip below ``enter``, trimmed to their first and
    last sample below ``enter``.

    The higher ``leave`` level only bridges short noisy stretches inside a hold; the edges stay
    where the stricter ``enter`` level puts them, so a hold does not creep into the slow start
    or end of the next motion.
    """
    low = s < leave
    lab, n = ndimage.label(low)
    out = np.zeros(s.shape, bool)
    core = np.flatnonzero(s < enter)
    if n == 0 or core.size == 0:
        return out
    labels = np.unique(lab[core])
    labels = labels[labels > 0]
    first = np.asarray(ndimage.minimum(np.arange(s.size), lab * (s < enter), labels), int)
    last = np.asarray(ndimage.maximum(np.arange(s.size), lab * (s < enter), labels), int)
    edges = np.zeros(s.size + 1, np.int32)
    np.add.at(edges, first, 1)
    np.add.at(edges, last + 1, -1)
    return np.cumsum(edges[:-1]) > 0


def _slow(gyr: np.ndarray, w: int, still: np.ndarray, max_rate: float,
          blocks: list[tuple[int, int]]) -> np.ndarray:
    """Samples whose moving-mean rate stays within ``max_rate`` of the bias.

    A turn at constant rate (a turntable, or a steady hand) has a small moving std; only its
    mean betrays it. The bias is the median rate over the samples the std test kept, which
    are mostly true holds.
    """
    if not np.any(still):
        return still
    bias = np.median(gyr[still], axis=0)
    mean = np.empty_like(gyr)
    for b0, b1 in blocks:                   # as moving_std: no window across a logging hole
        mean[b0:b1] = uniform_filter1d(gyr[b0:b1] - bias, min(w, b1 - b0), axis=0, mode="nearest")
    return np.linalg.norm(mean, axis=1) < max_rate


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open index ranges of the True runs of a boolean array."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def _blocks(t: np.ndarray, dt: float) -> list[tuple[int, int]]:
    """Half-open ranges of samples without a logging gap (> GAP_FACTOR × the median interval).

    Dataflash logs stop writing IMU while disarmed (pxf_copter_mag.BIN: 13 gaps of 5-363 s);
    a window or a segment must not reach across such a hole.
    """
    cut = np.flatnonzero(np.diff(t) > GAP_FACTOR * dt) + 1
    b = np.concatenate(([0], cut, [t.size]))
    return list(zip(b[:-1].tolist(), b[1:].tolist()))


def _check_inputs(t, acc, gyr):
    t = np.asarray(t, dtype=float)
    acc = np.asarray(acc, dtype=float)
    if acc.ndim != 2 or acc.shape[1] != 3 or t.shape != (acc.shape[0],):
        raise ApmcalError(f"static detection needs t (n,) and acc (n, 3), got {t.shape} and {acc.shape}")
    if gyr is not None:
        gyr = np.asarray(gyr, dtype=float)
        if gyr.shape != acc.shape:
            raise ApmcalError(f"gyr shape {gyr.shape} differs from acc shape {acc.shape}")
    if t.size < 3:
        raise ApmcalError(f"static detection needs at least 3 samples, got {t.size}")
    if np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
        raise ApmcalError("sample times must be finite and strictly increasing")
    return t, acc, gyr


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _same_hold(t, acc, gyr, a, b, *, max_angle_deg, gyr_tol, gyr_unit_rad, max_step):
    """True when runs ``a`` and ``b`` (i0, i1) are one hold interrupted by a disturbance.

    Same orientation before and after: mean specific force within ``max_angle_deg``, mean rates
    within ``gyr_tol`` (the gyro noise threshold), and the bias-corrected gyro integrated over
    the gap turns less than ``max_angle_deg`` — a quarter turn about the vertical (seed 002 §3.1)
    leaves the accelerometer unchanged and must still split the holds.
    """
    if _angle_deg(acc[a[0]:a[1]].mean(axis=0), acc[b[0]:b[1]].mean(axis=0)) >= max_angle_deg:
        return False
    if gyr is None:
        return True
    ga, gb = gyr[a[0]:a[1]].mean(axis=0), gyr[b[0]:b[1]].mean(axis=0)
    if np.linalg.norm(ga - gb) > gyr_tol:
        return False
    g0, g1 = a[1] - 1, b[0] + 1            # last still sample .. first still sample
    turn = integrate_rate(t[g0:g1], gyr[g0:g1] - 0.5 * (ga + gb), max_step)
    return float(np.degrees(np.linalg.norm(turn) * gyr_unit_rad)) < max_angle_deg


def integrate_rate(t: np.ndarray, rate: np.ndarray, max_step: float = np.inf) -> np.ndarray:
    """Trapezoidal integral of (n, 3) ``rate`` over ``t`` [rate unit × s], skipping steps longer
    than ``max_step`` [s] (a logging hole: the turn inside it is unknown, not rate × hole)."""
    if t.size < 2:
        return np.zeros(rate.shape[1])
    h = np.diff(t)
    h = np.where(h > max_step, 0.0, h)
    return (0.5 * (rate[1:] + rate[:-1]) * h[:, None]).sum(axis=0)


def merge_holds(t, acc, gyr, runs, *, merge_gap: float, max_angle_deg: float = MERGE_ANGLE_DEG,
                gyr_tol: float = np.inf, gyr_unit_rad: float = 1.0, max_step: float = np.inf):
    """Join consecutive still runs that are one hold split by short disturbances.

    Parameters
    ----------
    runs : list of (i0, i1)
        Half-open still runs in time order.
    merge_gap : float
        Longest gap [s] (disturbance or logging hole) bridged.
    max_angle_deg, gyr_tol, gyr_unit_rad
        See :func:`find_static_segments`.
    max_step : float
        Sample steps longer than this [s] are logging holes, left out of the gap's turn.

    Returns
    -------
    list of (i0, i1, excluded): ``excluded`` are the half-open gap ranges inside [i0, i1) whose
    samples are left out of the segment's statistics.
    """
    out: list[tuple[int, int, list[tuple[int, int]]]] = []
    for r in runs:
        if out:
            i0, i1, exc = out[-1]
            last = (exc[-1][1] if exc else i0, i1)          # the previous run's own samples
            if (t[r[0]] - t[i1 - 1] <= merge_gap
                    and _same_hold(t, acc, gyr, last, r, max_angle_deg=max_angle_deg,
                                   gyr_tol=gyr_tol, gyr_unit_rad=gyr_unit_rad,
                                   max_step=max_step)):
                out[-1] = (i0, r[1], exc + ([(i1, r[0])] if r[0] > i1 else []))
                continue
        out.append((r[0], r[1], []))
    return out


def find_static_segments(t, acc, gyr=None, *, min_duration: float = 2.0, window: float | None = None,
                         threshold: tuple[float, float | None] | None = None,
                         max_rate: float | None = None,
                         max_tilt_deg: float = MAX_TILT_DEG, hysteresis: float = HYSTERESIS,
                         merge_gap: float = MERGE_GAP_S, merge_angle_deg: float = MERGE_ANGLE_DEG,
                         gyr_unit_rad: float = 1.0) -> list[StaticSegment]:
    """Find the still periods of a recording.

    Steps: moving std of acc and gyro (per gap-free block); noise-adapted thresholds
    (:func:`noise_threshold`, Tedaldi et al. 2014 use the same variance-vs-threshold test with a
    threshold scaled from a known rest period); two-level hysteresis; a constant-rate test;
    then short disturbances inside one hold are bridged (:func:`merge_holds`) and their samples
    excluded from the statistics.

    Parameters
    ----------
    t : (n,) array
        Sample times [s], strictly increasing; sampling may be irregular (the window is counted in
        samples from the median interval). Gaps longer than 5 median intervals split the record.
    acc : (n, 3) array
        Accelerometer, sensor frame, any unit (m/s², mG, counts).
    gyr : (n, 3) array, optional
        Gyroscope, sensor frame, any unit; strongly recommended (rotations about the gravity
        vector are invisible to the accelerometer).
    min_duration : float
        Shortest still period kept [s] (first to last sample, after merging).
    window : float, optional
        Moving-std window [s]; default max(0.5 s, 5 samples).
    threshold : (acc_thr, gyr_thr), optional
        Fixed "enter" thresholds on the moving std (input units); default adapted to the noise.
    max_rate : float, optional
        Largest |moving-mean gyro − bias| of a still sample (gyro units); default 10 × the gyro
        std threshold. Catches constant-rate turns, which have a small moving std. Slower
        turns (below ~10 noise sigmas) are taken as still.
    max_tilt_deg : float
        Largest angle between "up" and a sensor axis that still earns a pose label.
    hysteresis : float
        A still run continues while the moving std stays below ``hysteresis`` × threshold.
    merge_gap : float
        Longest disturbance or logging gap [s] bridged between two runs of one hold; 0 disables.
    merge_angle_deg : float
        Two runs are one hold when their mean specific forces differ by less than this angle and
        the gyro turns less than this angle across the gap (their mean rates must also agree
        within the gyro threshold). Without ``gyr`` only the mean specific force is compared,
        so holds separated by a turn about the vertical are merged.
    gyr_unit_rad : float
        Gyro unit in rad/s (1 for rad/s, π/180 for deg/s), used only for the turn in the merge
        test. Too large a value only makes merging stricter.

    Returns
    -------
    list of StaticSegment, in time order; merged ones list their excluded gaps in ``excluded``.
    """
    t, acc, gyr = _check_inputs(t, acc, gyr)
    dt = float(np.median(np.diff(t)))
    w = max(5, int(round((0.5 if window is None else window) / dt)))
    blocks = _blocks(t, dt)
    if max(b1 - b0 for b0, b1 in blocks) < w:
        return []
    s_acc = moving_std(acc, w, blocks)
    thr_acc = threshold[0] if threshold is not None else noise_threshold(s_acc, acc)
    still = _hysteresis(s_acc, thr_acc, hysteresis * thr_acc)
    thr_gyr = np.inf
    if gyr is not None:
        s_gyr = moving_std(gyr, w, blocks)
        thr_gyr = (threshold[1] if threshold is not None and threshold[1] is not None
                   else noise_threshold(s_gyr, gyr))
        still &= _hysteresis(s_gyr, thr_gyr, hysteresis * thr_gyr)
        still &= _slow(gyr, w, still, RATE_FACTOR * thr_gyr if max_rate is None else max_rate,
                       blocks)
    runs = [(b0 + i0, b0 + i1) for b0, b1 in blocks for i0, i1 in _runs(still[b0:b1])
            if i1 - i0 >= 2]
    merged = merge_holds(t, acc, gyr, runs, merge_gap=merge_gap, max_angle_deg=merge_angle_deg,
                         gyr_tol=thr_gyr, gyr_unit_rad=gyr_unit_rad, max_step=GAP_FACTOR * dt)
    return [make_segment(t, acc, gyr, i0, i1, max_tilt_deg, exclude=exc) for i0, i1, exc in merged
            if t[i1 - 1] - t[i0] >= min_duration]


def label_poses(segments: list[StaticSegment], how: str = "longest") -> dict[str, StaticSegment]:
    """The one segment per Ferraris pose to calibrate from.

    Parameters
    ----------
    segments : list of StaticSegment
    how : {"longest"}
        Which segment wins when one pose was held several times: the longest (most samples).

    Returns
    -------
    dict pose name -> StaticSegment, only for the poses present. Use ``ARDUPILOT_FACE`` to rename.
    """
    if how != "longest":
        raise ApmcalError(f"unknown pose selection {how!r} (only 'longest')")
    out: dict[str, StaticSegment] = {}
    for seg in segments:
        if seg.pose is not None and (seg.pose not in out or seg.n > out[seg.pose].n):
            out[seg.pose] = seg
    return out
