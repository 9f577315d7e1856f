"""Static periods of an IMU recording and which face of the sensor points up in each.

A sample is "static" when the moving standard deviation of the accelerometer (and gyroscope when
given) stays below a threshold adapted to the sensor's own noise, so the same code works on 2 Hz
telemetry and 1 kHz dataflash logs without tuning.

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
import pandas as pd

from apmcal.errors import ApmcalError

#: Ferraris pose name -> ArduPilot accelerometer-calibration face (ardupilot-facts.md).
ARDUPILOT_FACE = {"x_p": "noseup", "x_a": "nosedown", "y_p": "left", "y_a": "right",
                  "z_p": "back", "z_a": "level"}
POSES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")

MAX_TILT_DEG = 25.0     # a hold further than this from every axis gets no pose label
NOISE_FACTOR = 3.0      # threshold = NOISE_FACTOR × robust static noise floor
NOISE_QUANTILE = 10.0   # percentile of the moving std taken as the noise floor
RATE_FACTOR = 10.0      # default max |mean rate − bias| = RATE_FACTOR × gyro std threshold


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

    @property
    def duration(self) -> float:
        """Length [s] from first to last sample."""
        return self.end - self.start

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


def make_segment(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray | None, i0: int, i1: int,
                 max_tilt_deg: float = MAX_TILT_DEG) -> StaticSegment:
    """Statistics of samples ``i0 .. i1-1`` as a :class:`StaticSegment` (also for hand-set ranges)."""
    a = acc[i0:i1]
    acc_mean = a.mean(axis=0)
    up = acc_mean / np.linalg.norm(acc_mean)
    pose, tilt = pose_of(acc_mean, max_tilt_deg)
    g = None if gyr is None else gyr[i0:i1]
    ddof = 1 if i1 - i0 > 1 else 0
    return StaticSegment(
        start=float(t[i0]), end=float(t[i1 - 1]), i0=int(i0), i1=int(i1), n=int(i1 - i0),
        t_mean=float(np.mean(t[i0:i1])), acc_mean=acc_mean, acc_std=a.std(axis=0, ddof=ddof),
        gyr_mean=None if g is None else g.mean(axis=0),
        gyr_std=None if g is None else g.std(axis=0, ddof=ddof),
        up_axis=up, gravity_dir=-up, pose=pose, tilt_deg=tilt)


def moving_std(x: np.ndarray, w: int) -> np.ndarray:
    """Centred moving standard deviation of (n, 3) ``x`` over ``w`` samples, root-sum-square over axes.

    Summing per-axis variances (rather than taking the std of the norm) also catches slow
    rotations, during which the accelerometer norm stays at g but its components change.
    """
    var = pd.DataFrame(x).rolling(w, center=True, min_periods=max(2, w // 2)).var().to_numpy()
    s = np.sqrt(np.nansum(var, axis=1))
    s[np.all(np.isnan(var), axis=1)] = np.inf
    return s


def noise_threshold(s: np.ndarray, x: np.ndarray, factor: float = NOISE_FACTOR) -> float:
    """Noise-adapted threshold for the moving std ``s`` of signal ``x``.

    The noise floor is a low percentile of the moving std (robust to the motion that fills the
    rest of the recording); a floor of 1.5 quantisation steps keeps integer telemetry (RAW_IMU,
    1 mG steps, ardupilot-facts.md) from giving a zero threshold.
    """
    finite = s[np.isfinite(s)]
    floor = float(np.percentile(finite, NOISE_QUANTILE)) if finite.size else 0.0
    steps = np.abs(np.diff(x, axis=0))
    steps = steps[steps > 0]
    quantum = float(steps.min()) if steps.size else 0.0
    return max(factor * floor, 1.5 * quantum, np.finfo(float).tiny)


def _slow(gyr: np.ndarray, w: int, still: np.ndarray, max_rate: float) -> np.ndarray:
    """Samples whose moving-mean rate stays within ``max_rate`` of the bias.

    A turn at constant rate (a turntable, or a steady hand) has a small moving std; only its
    mean betrays it. The bias is the median rate over the samples the std test kept, which
    are mostly true holds.
    """
    if not np.any(still):
        return still
    bias = np.median(gyr[still], axis=0)
    mean = pd.DataFrame(gyr - bias).rolling(w, center=True, min_periods=1).mean().to_numpy()
    return np.linalg.norm(mean, axis=1) < max_rate


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open index ranges of the True runs of a boolean array."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


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
                         max_tilt_deg: float = MAX_TILT_DEG) -> list[StaticSegment]:
    """Find the still periods of a recording.

    Parameters
    ----------
    t : (n,) array
        Sample times [s], strictly increasing; sampling may be irregular (the window is counted in
        samples from the median interval).
    acc : (n, 3) array
        Accelerometer, sensor frame, any unit (m/s², mG, counts).
    gyr : (n, 3) array, optional
        Gyroscope, sensor frame, any unit; strongly recommended (rotations about the gravity
        vector are invisible to the accelerometer).
    min_duration : float
        Shortest still period kept [s].
    window : float, optional
        Moving-std window [s]; default max(0.5 s, 5 samples).
    threshold : (acc_thr, gyr_thr), optional
        Fixed thresholds on the moving std (input units); default adapted to the noise.
    max_rate : float, optional
        Largest |moving-mean gyro − bias| of a still sample (gyro units); default 10 × the gyro
        std threshold. Catches constant-rate turns, which have a small moving std. Slower
        turns (below ~10 noise sigmas) are taken as still.
    max_tilt_deg : float
        Largest angle between "up" and a sensor axis that still earns a pose label.

    Returns
    -------
    list of StaticSegment, in time order.
    """
    t, acc, gyr = _check_inputs(t, acc, gyr)
    dt = float(np.median(np.diff(t)))
    w = max(5, int(round((0.5 if window is None else window) / dt)))
    if w > t.size:
        return []
    s_acc = moving_std(acc, w)
    thr_acc = threshold[0] if threshold is not None else noise_threshold(s_acc, acc)
    still = s_acc < thr_acc
    if gyr is not None:
        s_gyr = moving_std(gyr, w)
        thr_gyr = (threshold[1] if threshold is not None and threshold[1] is not None
                   else noise_threshold(s_gyr, gyr))
        still &= s_gyr < thr_gyr
        still &= _slow(gyr, w, still, RATE_FACTOR * thr_gyr if max_rate is None else max_rate)
    segments = []
    for i0, i1 in _runs(still):
        if t[i1 - 1] - t[i0] >= min_duration and i1 - i0 >= 2:
            segments.append(make_segment(t, acc, gyr, i0, i1, max_tilt_deg))
    return segments


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
