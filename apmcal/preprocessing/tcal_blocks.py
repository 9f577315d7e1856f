"""Still samples of a warming board cut into short blocks: the data of a temperature fit.

The still periods come from :func:`apmcal.preprocessing.static.find_static_segments` (so motion
does not pollute the fit); each is cut into blocks of ``block_s`` seconds whose means (time,
temperature, accelerometer, gyro) and sample counts are what the solver fits. Blocks, not
samples, so that the solver's residual scatter sees slow noise (a gyro random walk) at the
scale where it competes with temperature; ArduPilot's own learner averages too (at least 100
samples per 0.5 °C step, AP_InertialSensor_tempcal.cpp ``Learn::add_sample``). Holds in one
orientation share a group: one constant (gravity, g-sensitivity, Earth rate) per group.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.preprocessing.static import StaticSegment

GROUP_ANGLE_DEG = 10.0     # holds whose "up" differs by less than this share one constant


@dataclass
class Blocks:
    """Block means of the still samples, in time order.

    Attributes
    ----------
    t_s, temp_c : (m,) arrays
        Mean time [s] and temperature [°C] of each block.
    acc, gyr : (m, 3) arrays
        Mean accelerometer [m/s²] and gyro [rad/s] (the frame of the input).
    n : (m,) int array
        Samples per block (the fit's weights).
    group : (m,) int array
        Orientation group of each block (0, 1, ...).
    temp_min_c, temp_max_c : float
        Lowest and highest temperature [°C] of the still samples used.
    """

    t_s: np.ndarray
    temp_c: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    n: np.ndarray
    group: np.ndarray
    temp_min_c: float
    temp_max_c: float

    def __len__(self) -> int:
        return len(self.t_s)


def orientation_groups(segments: list[StaticSegment],
                       max_angle_deg: float = GROUP_ANGLE_DEG) -> list[int]:
    """Group index of each segment: segments whose up axes are within ``max_angle_deg`` of the
    first segment of a group join it (greedy, in time order).

    Parameters
    ----------
    segments : list of StaticSegment
        In time order.
    max_angle_deg : float, optional
        Largest angle [deg] between a segment's up axis and its group's first.

    Returns
    -------
    list of int
        One group index per segment.
    """
    heads: list[np.ndarray] = []
    out = []
    cos_max = np.cos(np.radians(max_angle_deg))
    for seg in segments:
        for k, up in enumerate(heads):
            if float(np.dot(up, seg.up_axis)) >= cos_max:
                out.append(k)
                break
        else:
            heads.append(seg.up_axis)
            out.append(len(heads) - 1)
    return out


def still_blocks(t: np.ndarray, temp_c: np.ndarray, acc: np.ndarray, gyr: np.ndarray,
                 segments: list[StaticSegment], block_s: float = 2.0,
                 min_samples: int = 5) -> Blocks:
    """Block means of the kept samples of ``segments`` (see the module docstring).

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    temp_c : (n,) array
        IMU temperature [°C], finite.
    acc, gyr : (n, 3) arrays
        Accelerometer [m/s²] and gyro [rad/s].
    segments : list of StaticSegment
        Still periods (their ``kept()`` samples are used).
    block_s : float
        Block length [s].
    min_samples : int
        Shorter blocks (a segment's tail) are dropped.

    Returns
    -------
    Blocks
        m blocks in time order (m = 0 when no block has ``min_samples`` samples; the
        temperatures are then NaN).
    """
    groups = orientation_groups(segments)
    rows = []
    lo, hi = np.inf, -np.inf
    for seg, g in zip(segments, groups):
        idx = seg.kept()
        if idx.size == 0:
            continue
        lo, hi = min(lo, float(temp_c[idx].min())), max(hi, float(temp_c[idx].max()))
        cut = np.floor((t[idx] - t[idx[0]]) / block_s).astype(np.int64)
        starts = np.flatnonzero(np.diff(np.concatenate(([-1], cut))))
        for a, b in zip(starts, np.append(starts[1:], idx.size)):
            part = idx[a:b]
            if part.size >= min_samples:
                rows.append((t[part].mean(), temp_c[part].mean(), acc[part].mean(axis=0),
                             gyr[part].mean(axis=0), part.size, g))
    if not rows:
        empty = np.zeros((0, 3))
        return Blocks(np.zeros(0), np.zeros(0), empty, empty, np.zeros(0, int),
                      np.zeros(0, int), float("nan"), float("nan"))
    t_s, tc, a, w, n, g = zip(*rows)
    return Blocks(np.array(t_s), np.array(tc), np.array(a), np.array(w), np.array(n),
                  np.array(g), lo, hi)
