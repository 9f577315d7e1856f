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

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.hold_merge import MERGE_ANGLE_DEG, merge_holds
from apmcal.preprocessing.stillness import (
    GAP_FACTOR,
    gap_free_blocks,
    hysteresis_mask,
    moving_std,
    noise_threshold,
    slow_mask,
    true_runs,
)

#: Ferraris pose name -> ArduPilot accelerometer-calibration face (ardupilot-facts.md).
ARDUPILOT_FACE = {"x_p": "noseup", "x_a": "nosedown", "y_p": "left", "y_a": "right",
                  "z_p": "back", "z_a": "level"}
POSES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")

MAX_TILT_DEG = 25.0     # a hold further than this from every axis gets no pose label
RATE_FACTOR = 10.0      # default max |mean rate − bias| = RATE_FACTOR × gyro std threshold
HYSTERESIS = 2.0        # a still run lasts while the moving std < HYSTERESIS × threshold
MERGE_GAP_S = 5.0       # default longest disturbance [s] bridged inside one hold


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
    """Ferraris pose name of a mean specific-force vector and its tilt [deg] from the nearest axis.

    Parameters
    ----------
    acc_mean : numpy.ndarray, shape (3,)
        Mean specific force, sensor frame, any unit.
    max_tilt_deg : float, optional
        Largest tilt [deg] from an axis that still earns a pose name.

    Returns
    -------
    pose : str or None
        "x_p" … "z_a", or None when tilted more than ``max_tilt_deg``.
    tilt : float
        Angle [deg] between "up" and the nearest sensor axis.
    """
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

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    acc : numpy.ndarray, shape (n, 3)
        Accelerometer, sensor frame, any unit.
    gyr : numpy.ndarray, shape (n, 3), or None
        Gyroscope, sensor frame, any unit.
    i0, i1 : int
        Half-open sample range.
    max_tilt_deg : float, optional
        See :func:`pose_of`.

    Returns
    -------
    StaticSegment
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
    list of StaticSegment
        In time order; merged ones list their excluded gaps in ``excluded``.

    Raises
    ------
    ApmcalError
        ``t`` and ``acc`` (and ``gyr``) of mismatched shapes, fewer than 3 samples, or times
        not finite and strictly increasing.
    """
    t, acc, gyr = _check_inputs(t, acc, gyr)
    dt = float(np.median(np.diff(t)))
    w = max(5, int(round((0.5 if window is None else window) / dt)))
    blocks = gap_free_blocks(t, dt)
    if max(b1 - b0 for b0, b1 in blocks) < w:
        return []
    s_acc = moving_std(acc, w, blocks)
    thr_acc = threshold[0] if threshold is not None else noise_threshold(s_acc, acc)
    still = hysteresis_mask(s_acc, thr_acc, hysteresis * thr_acc)
    thr_gyr = np.inf
    if gyr is not None:
        s_gyr = moving_std(gyr, w, blocks)
        thr_gyr = (threshold[1] if threshold is not None and threshold[1] is not None
                   else noise_threshold(s_gyr, gyr))
        still &= hysteresis_mask(s_gyr, thr_gyr, hysteresis * thr_gyr)
        still &= slow_mask(gyr, w, still, RATE_FACTOR * thr_gyr if max_rate is None else max_rate,
                       blocks)
    runs = [(b0 + i0, b0 + i1) for b0, b1 in blocks for i0, i1 in true_runs(still[b0:b1])
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
    dict of str to StaticSegment
        Pose name -> StaticSegment, only for the poses present. Use ``ARDUPILOT_FACE`` to
        rename.

    Raises
    ------
    ApmcalError
        An unknown ``how``.
    """
    if how != "longest":
        raise ApmcalError(f"unknown pose selection {how!r} (only 'longest')")
    out: dict[str, StaticSegment] = {}
    for seg in segments:
        if seg.pose is not None and (seg.pose not in out or seg.n > out[seg.pose].n):
            out[seg.pose] = seg
    return out
