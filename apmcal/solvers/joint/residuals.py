"""The implicit conditions f(X, Y) = 0 of [Chow] §3.2, evaluated for a parameter vector.

Each family is one of the paper's updates, written (as the paper does) without navigation
states: the states are marginalised by integrating the gyro between the samples a condition
compares, so the unknowns are the 42 calibration parameters only ([Chow] §3.3).

=========  ======================================================  ==============================
family     condition (sensor frame, calibrated quantities)          [Chow]
=========  ======================================================  ==============================
acc_norm   |ā| − g = 0 on each still block                          eq. 5 (static norm = g)
zaru       ω̄ = 0 on each still block                                eq. 6 (zero-rotation update)
mag        D_m·(m(t+T) − dR(t, t+T)ᵀ·m(t)) = 0 on windows of T      eq. 7 with dR from eq. 8
level      Eⱼᵀ·(û_j − dR(i, j)ᵀ·û_i) = 0 between consecutive poses  eq. 9 (levelling)
zupt       Σ dR(i, τ)·a_τ·Δτ − ā_i·T = 0 between still poses        eq. 10 with Δv from eq. 11
mag_datum  mean |m| − F = 0                                          (datum, see below)
=========  ======================================================  ==============================

û = ā/|ā| is the direction of the specific force and E_j (3×2) an orthonormal basis
perpendicular to pose j's: the levelling compares inclinations only (two angles [rad]); the
length of ā is the static norm's business — with it too, one combination of the three
conditions would carry no noise at all (rotation keeps lengths) and make B·C_l·Bᵀ singular.
Equation numbers are those the text of [Chow] refers to (the equations themselves are
missing from the text we have): 1-3 sensor models, 4 mechanisation, 5 static norm, 6 ZARU,
7-8 compass + gyro, 9 levelling, 10-11 ZUPT, 12-13 CUPT, 14-15 the adjustment. (§5.2 calls
the compass + gyro pair "(6) and (7)"; its §3.2.3 text, "(7)" and "(8)", is followed here.)
dR(t, t+T) = Π Exp(ω_k Δt_k) is the strap-down integration of the calibrated gyro (eq. 8, the
quaternion product written with rotation matrices). In eq. 10 the gravity at the first still
pose is −ā_i (specific force at rest), so the velocity change to the next still pose is zero.
CUPT (eq. 12-13) needs loop closures detected by hand in the paper; it is not used here.

The magnetometer condition is eq. 7 multiplied by D_m, i.e. written in the raw samples
units, (y_e − o_m) − D_m·dRᵀ·D_m⁻¹·(y_s − o_m): its noise covariance then hardly depends on
the soft iron, so holding B·C_l·Bᵀ fixed within a Gauss-Newton pass does not pull the fit
towards a smaller D_m⁻¹ (over 0.1 s windows the misclosure is mostly noise, and in calibrated
units shrinking D_m⁻¹ shrinks that noise: in sitl the hard iron came out 6σ off).
The magnetometer updates only relate fields at different times, so they leave the overall
scale of D_m free ([Chow] §2: "the magnitude can arbitrarily be constrained"): ``mag_datum``
fixes it to the field magnitude F given (World Magnetic Model, else the samples' sphere fit).

Simplifications, and why: (1) the still-pose conditions use block means (~1 s) instead of
every sample — to first order the same information, a hundred times fewer conditions;
(2) the observation covariance B·C_l·Bᵀ comes from white sensor noise
(:mod:`apmcal.solvers.joint.covariance`, which says which correlations it keeps); the variance
factor of each family is then estimated from its residuals (:mod:`apmcal.solvers.joint.solve`).
(3) The magnetometer runs at three window lengths, 0.1 s, 1 s and 5 s, where the paper uses two
rates (100 Hz and 10 Hz, which 50 Hz telemetry cannot give); the paper notes that
longer windows drift less in heading and show outliers better, and on short hand-held sessions
the two short windows alone leave the soft iron weakly determined (a sitl hand-held session
checked on another one: attitude error 1.6° with 0.1 + 1 s windows, 0.4° with 5 s added, the
tilt part unchanged at 0.05°).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse

from apmcal.solvers.joint.trajectory import Trajectory

BLOCK_S = 1.0                  # still conditions on means of blocks this long [s]
MAG_WINDOWS_S = (0.1, 1.0, 5.0)   # magnetometer window lengths [s] ([Chow] §3.2.3)
GAP_FACTOR = 5.0               # a step > GAP_FACTOR × median interval is a logging gap
DIM = {"acc_norm": 1, "zaru": 3, "level": 2, "zupt": 3, "mag": 3, "mag_datum": 1}


@dataclass
class JointData:
    """Samples and the condition layout (indices only; built once, by :func:`layout`).

    Attributes
    ----------
    t : (n,) array, s
    acc : (n, 3) array, m/s²
    gyr : (n, 3) array, rad/s
    mag : (n, 3) array, mGauss, or None
        Raw, sensor frame, on one time base (as ``t``, ``acc`` and ``gyr``).
    gravity : float
        Local gravity [m/s²].
    field : float or None
        Field magnitude [mGauss].
    dt : (n,) array
        Step to the next sample [s] (0 for the last).
    blocks : list of int arrays
        Index arrays of still blocks.
    level_basis : (I, 3, 2) array
        E_j of each interval.
    block_mean : scipy.sparse matrix, (n_blocks, n)
        The block means as one product.
    intervals : list of tuple
        (last block of pose i, first block of pose j, k0, k1) with the moving samples
        k0 .. k1−1 between them.
    interval_index : (I, 4) int array
        The same as columns: block i, block j, k0, k1.
    steps : (I, K) int array
        Each interval's steps k0 .. k1−1, padded with n (:func:`interval_rows` without its
        last column).
    windows : list of int arrays
        Per window length, an (W, K+1) index array of the samples each window spans.
    noise : dict
        Per-sample white-noise σ of "acc", "gyr", "mag" (sensor units).
    clipped : int
        Turns between consecutive still poses left out because the gyro or accelerometer was
        at its range limit in them (:func:`at_range_limit`).
    """

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray | None
    gravity: float
    field: float | None
    dt: np.ndarray = None
    blocks: list = field(default_factory=list)
    level_basis: np.ndarray = None      # (I, 3, 2): E_j of each interval
    block_mean: object = None           # sparse (n_blocks, n): the block means as one product
    intervals: list = field(default_factory=list)
    interval_index: np.ndarray = None   # (I, 4): the intervals as columns
    steps: np.ndarray = None            # (I, K): their steps, padded with n
    windows: list = field(default_factory=list)
    noise: dict = field(default_factory=dict)
    clipped: int = 0


MIN_CLIPPED = 3                # samples at a full scale that make it a range limit
# the full scales MEMS gyros and accelerometers are set to (MPU-6000/6050, ICM-20xxx, BMI):
# ±125..4000 °/s and ±2..32 g; a sensor at its limit reads one of them (to a count)
GYRO_RANGES_RAD_S = tuple(np.radians([125.0, 250.0, 500.0, 1000.0, 2000.0, 4000.0]))
ACC_RANGES_M_S2 = tuple(9.80665 * np.array([2.0, 4.0, 8.0, 16.0, 32.0]))
RANGE_MATCH = 2e-3             # relative: within a count or two of 16 bits


def at_range_limit(y: np.ndarray, full_scales=GYRO_RANGES_RAD_S) -> np.ndarray:
    """Samples (n,) where a sensor sat at its range limit: the largest |value| of any axis is
    within ``RANGE_MATCH`` of one of the standard ``full_scales`` (in the samples' units) and
    is reached (to 1e-4, a two's complement range being one count wider below zero) by
    ``MIN_CLIPPED`` samples or more — a real MPU-6050 turned faster than its ±250 °/s read
    250.1 °/s for up to 10 samples in a row. A steady turn's plateau below a full scale
    (ArduPilot's SITL turns its model at a constant rate) is no limit.

    Parameters
    ----------
    y : (n, 3) array
        Samples: gyro [rad/s] or accelerometer [m/s²] (``full_scales`` in the same units).
    full_scales : tuple of float
        The candidate range limits.

    Returns
    -------
    (n,) bool array
    """
    a = np.abs(np.asarray(y, float))
    none = np.zeros(len(a), bool)
    top = float(np.nanmax(a)) if a.size else 0.0
    if top <= 0 or not any(abs(top / fs - 1) <= RANGE_MATCH for fs in full_scales):
        return none
    hit = np.any(a >= top * (1 - 1e-4), axis=1)
    return hit if hit.sum() >= MIN_CLIPPED else none


def layout(t, acc, gyr, mag, holds, gravity: float, field_mgauss: float | None) -> JointData:
    """Still blocks, moving intervals between consecutive holds and magnetometer windows.

    ``holds`` are the still periods (:class:`apmcal.preprocessing.static.StaticSegment`, time
    order). An interval runs from the centre of one pose's last block to the centre of the
    next pose's first block; intervals across a logging gap are left out.

    Parameters
    ----------
    t : (n,) array, s
    acc : (n, 3) array, m/s²
    gyr : (n, 3) array, rad/s
    mag : (n, 3) array, mGauss, or None
    holds : list of StaticSegment
    gravity : float
        Local gravity [m/s²].
    field_mgauss : float or None
        Field magnitude [mGauss].

    Returns
    -------
    JointData
    """
    d = JointData(np.asarray(t, float), np.asarray(acc, float), np.asarray(gyr, float),
                  None if mag is None else np.asarray(mag, float), gravity, field_mgauss)
    dt = np.diff(d.t)
    d.dt = np.append(dt, 0.0)
    gap = GAP_FACTOR * float(np.median(dt))
    hold_blocks = []
    for h in holds:
        kept = h.kept()
        n_blocks = max(1, int((d.t[kept[-1]] - d.t[kept[0]]) // BLOCK_S))
        hold_blocks.append([b for b in np.array_split(kept, n_blocks) if b.size >= 2])
    d.blocks = [b for hb in hold_blocks for b in hb]
    rows = np.repeat(np.arange(len(d.blocks)), [b.size for b in d.blocks])
    cols = np.concatenate(d.blocks) if d.blocks else np.zeros(0, int)
    d.block_mean = sparse.csr_matrix((1.0 / np.repeat([b.size for b in d.blocks],
                                                      [b.size for b in d.blocks]), (rows, cols)),
                                     shape=(len(d.blocks), d.t.size))
    index = {id(b): k for k, b in enumerate(d.blocks)}
    # a turn read through a sensor at its range limit is not the turn made: left out
    clipped = np.cumsum(np.append(0, at_range_limit(d.gyr)
                                  | at_range_limit(d.acc, ACC_RANGES_M_S2)))
    for _h0, _h1, b0, b1 in zip(holds, holds[1:], hold_blocks, hold_blocks[1:]):
        if not b0 or not b1:
            continue
        # from the centre of pose i's last block to the centre of pose j's first: a block
        # mean is the specific force at its centre, while a hold's edge sample may already
        # be turning (the still detector's edges are soft)
        k0, k1 = int(b0[-1][b0[-1].size // 2]), int(b1[0][b1[0].size // 2])
        if k1 > k0 and clipped[k1 + 1] > clipped[k0]:
            d.clipped += 1
        elif k1 > k0 and dt[k0:k1].max() <= gap:
            d.intervals.append((index[id(b0[-1])], index[id(b1[0])], k0, k1))
    d.interval_index = np.array(d.intervals, dtype=int).reshape(-1, 4)
    d.steps = interval_rows(d)[:, :-1]
    d.level_basis = perpendicular_basis(np.array(
        [d.acc[d.blocks[j]].mean(axis=0) for _, j, _, _ in d.intervals]).reshape(-1, 3))
    if d.mag is not None:
        for span in MAG_WINDOWS_S:
            k = max(1, int(round(span / np.median(dt))))
            # windows never share a sample: a shared end point would count its noise twice
            starts = np.arange(0, d.t.size - k, k + 1)
            idx = starts[:, None] + np.arange(k + 1)[None]
            ok = (dt[idx[:, :-1]].max(axis=1) <= gap) & (clipped[idx[:, -1] + 1]
                                                          == clipped[idx[:, 0]])
            d.windows.append(idx[ok])
    d.noise = white_noise(d)
    return d


def perpendicular_basis(v: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal columns perpendicular to ``v``, or (c, 3, 2) of (c, 3) vectors (one
    stacked QR for all).

    Parameters
    ----------
    v : (3,) or (c, 3) array
        Non-zero vector(s) (any units).

    Returns
    -------
    (3, 2) or (c, 3, 2) array
    """
    v = np.asarray(v, float)
    u = v / np.linalg.norm(v, axis=-1, keepdims=True)
    # columns: u, then the two coordinate axes least aligned with it
    others = np.swapaxes(np.eye(3)[np.argsort(np.abs(u), axis=-1)[..., :2]], -1, -2)
    q, _ = np.linalg.qr(np.concatenate([u[..., None], others], axis=-1))
    return q[..., 1:]


NOISE_FLOOR = {"acc": 1e-4, "mag": 1e-4}     # of the still samples' median magnitude
GYRO_NOISE_FLOOR = 1e-6                       # rad/s


def white_noise(d: JointData) -> dict[str, float]:
    """Per-sample white-noise σ of each sensor from the still blocks (median over blocks of the
    per-axis std, first-differenced so that a slow sway does not count), never below a floor:
    1e-4 of the accelerometer's or compass's median magnitude at rest (what a 14-16 bit
    converter resolves), 1e-6 rad/s for the gyro. A simulated sensor can be noise-free and a
    compass logged in whole mGauss at 10 Hz, brought onto the IMU's times, reads constant
    through a hold (ArduPilot's SITL): a σ of zero would make its conditions infinitely tight.

    Parameters
    ----------
    d : JointData

    Returns
    -------
    dict
        "acc" [m/s²], "gyr" [rad/s], "mag" [mGauss] (those present) → σ, at least 1e-9.
    """
    out = {}
    if not d.blocks:
        return out
    # all blocks at once: the samples of every block in turn, the differences that straddle
    # two blocks left out, so that block b keeps its size − 1 differences, contiguous
    sizes = np.array([b.size for b in d.blocks])
    idx = np.concatenate(d.blocks)
    keep = np.ones(idx.size - 1, bool)
    keep[np.cumsum(sizes)[:-1] - 1] = False
    counts = sizes - 1
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for name, y in (("acc", d.acc), ("gyr", d.gyr), ("mag", d.mag)):
        if y is None:
            continue
        dy = np.diff(y[idx], axis=0)[keep]
        mean = np.add.reduceat(dy, starts, axis=0) / counts[:, None]
        dev = dy - np.repeat(mean, counts, axis=0)
        std = np.sqrt(np.add.reduceat(dev * dev, starts, axis=0) / counts[:, None])
        floor = (GYRO_NOISE_FLOOR if name == "gyr"
                 else NOISE_FLOOR[name] * float(np.median(np.linalg.norm(y[idx], axis=1))))
        out[name] = max(float(np.median(std.mean(axis=1) / np.sqrt(2))), floor, 1e-9)
    return out


def interval_rows(d: JointData) -> np.ndarray:
    """(I, K+1) sample indices of the moving intervals' steps k0 .. k1−1, padded with n (the
    identity step, no force) to one column more than the longest (``integrate`` integrates
    the steps ``idx[:, :-1]``).

    Parameters
    ----------
    d : JointData

    Returns
    -------
    (I, K+1) int array
    """
    spans = [np.arange(k0, k1) for _, _, k0, k1 in d.intervals]
    width = max((s.size for s in spans), default=0) + 1
    out = np.full((len(spans), width), d.t.size, dtype=int)
    for r, s in enumerate(spans):
        out[r, :s.size] = s
    return out


def misclosures(x: np.ndarray, d: JointData, families,
                traj: Trajectory | None = None) -> dict[str, np.ndarray]:
    """Each family's misclosure w = f(X, Y) at parameters ``x``: name → (n_c, dim) array.

    Parameters
    ----------
    x : (42,) array
        Parameters (:mod:`apmcal.solvers.joint.model`).
    d : JointData
        The session's samples and condition layout (:func:`layout`).
    families : tuple of str
        The families to evaluate.
    traj : Trajectory, optional
        :class:`~apmcal.solvers.joint.trajectory.Trajectory` of ``x`` and ``d``, when the
        caller has it.

    Returns
    -------
    dict
        family → (n_c, dim) array, in the family's units (acc_norm [m/s²], zaru [rad/s],
        level [rad], zupt [m/s], mag and mag_datum [mGauss]).
    """
    tr = Trajectory(x, d) if traj is None else traj
    a, w = tr.a, tr.w
    out: dict[str, np.ndarray] = {}
    a_blk = d.block_mean @ a
    if "acc_norm" in families:
        out["acc_norm"] = (np.linalg.norm(a_blk, axis=1) - d.gravity)[:, None]
    if "zaru" in families:
        out["zaru"] = d.block_mean @ w
    if d.intervals and ("level" in families or "zupt" in families):
        bi, bj, k0, k1 = d.interval_index.T
        ai, aj = a_blk[bi], a_blk[bj]
        if "level" in families:
            dr = tr.rotation(k0, k1)
            ui = ai / np.linalg.norm(ai, axis=1, keepdims=True)
            uj = aj / np.linalg.norm(aj, axis=1, keepdims=True)
            out["level"] = np.einsum("wia,wi->wa", d.level_basis,
                                     uj - np.einsum("wji,wj->wi", dr, ui))
        if "zupt" in families:
            out["zupt"] = tr.delta_v(k0, k1) - ai * (d.t[k1] - d.t[k0])[:, None]
    if d.mag is not None and "mag" in families:
        mc = tr.mc
        s, e = window_ends(d)
        dr = tr.rotation(s, e)
        out["mag"] = (mc[e] - np.einsum("wji,wj->wi", dr, mc[s])) @ tr.mats["D_m"].T
    if d.mag is not None and "mag_datum" in families:
        out["mag_datum"] = np.array([[np.linalg.norm(tr.mc, axis=1).mean() - d.field]])
    return out


def window_ends(d: JointData) -> tuple[np.ndarray, np.ndarray]:
    """First and last sample (W,) of every magnetometer window, all window lengths in turn.

    Parameters
    ----------
    d : JointData

    Returns
    -------
    s, e : (W,) int arrays
    """
    if not d.windows:
        return np.zeros(0, int), np.zeros(0, int)
    return (np.concatenate([idx[:, 0] for idx in d.windows]),
            np.concatenate([idx[:, -1] for idx in d.windows]))
