"""The motion of a real session, reconstructed for its twin: attitude, rate and each hold's own
specific force and field, at the session's sample times (sensor frame = the twin's board frame).

Holds keep the orientation the fit found (``up`` from the accelerometer, ``north`` from the
compass when there is one, else the heading carried over from the previous hold). A move
between two holds follows the calibrated gyro, its end corrected onto the next hold by a
rotation spread evenly over the move; any other stretch between holds keeps the previous
hold's attitude (it is not scored). During a move the specific force and field are the holds'
own vectors carried along by the attitude, blended from the hold before to the hold after, so
the twin passes through the same readings as the real board.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

DOWN = np.array([0.0, 0.0, 1.0])


@dataclass
class Trajectory:
    """Attitude R_nb (n, 3, 3) (sensor → NED), body rate (n, 3) [rad/s], hold index of each
    sample (the hold before, for moves) and how far each move has gone from the hold before
    to the hold after.

    Attributes
    ----------
    rot : (n, 3, 3) array
        Attitude R_nb at each IMU sample.
    rate : (n, 3) array
        Body rate [rad/s].
    hold : (n,) int array
        Hold index before or at each sample.
    blend : (n,) array
        0 at the hold before .. 1 at the hold after (moves), else 0.
    """

    rot: np.ndarray
    rate: np.ndarray
    hold: np.ndarray          # hold index before or at each sample
    blend: np.ndarray         # 0 at the hold before .. 1 at the hold after (moves), else 0


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def attitude(up: np.ndarray, north: np.ndarray | None, heading_from: np.ndarray | None = None
             ) -> np.ndarray:
    """R_nb whose body "up" is ``up`` and body north is ``north`` (orthogonalised); without a
    north, the one closest to ``heading_from`` (a previous attitude), or x turned horizontal.

    Parameters
    ----------
    up : (3,) array
        "Up" in the body frame (any length).
    north : (3,) array or None
        North in the body frame.
    heading_from : (3, 3) array, optional
        A previous attitude R_nb.

    Returns
    -------
    (3, 3) array
        R_nb; its rows are the NED axes in the body frame.
    """
    up = _unit(up)
    if north is None:
        ref = heading_from.T[:, 0] if heading_from is not None else np.array([1.0, 0.0, 0.0])
        if abs(ref @ up) > 0.95:
            ref = np.array([0.0, 1.0, 0.0]) if heading_from is None else heading_from.T[:, 1]
        north = ref
    n = _unit(north - (north @ up) * up)
    down = -up
    east = np.cross(down, n)
    return np.array([n, east, down])           # rows: NED axes in the body frame


def hold_attitudes(holds, up_per_hold: np.ndarray, north_per_hold: np.ndarray | None
                   ) -> list[np.ndarray]:
    """One attitude per hold; headings carried over hold to hold when there is no compass.

    Parameters
    ----------
    holds : list
        The holds (only their number is used).
    up_per_hold : (n_holds, 3) array
        "Up" of each hold in the body frame.
    north_per_hold : (n_holds, 3) array or None
        North of each hold (a non-finite row: none for that hold).

    Returns
    -------
    list of (3, 3) arrays
        R_nb of each hold.
    """
    out: list[np.ndarray] = []
    for k in range(len(holds)):
        north = None if north_per_hold is None else north_per_hold[k]
        if north is not None and not np.all(np.isfinite(north)):
            north = None
        out.append(attitude(up_per_hold[k], north, out[-1] if out else None))
    return out


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a·b of (n, 4) quaternions in scipy's scalar-last (x, y, z, w) order.

    Returns
    -------
    (n, 4) array
    """
    return np.stack(_hamilton(a.T, b.T), axis=1)


def _hamilton(a, b) -> tuple:
    """The components (x, y, z, w) of a·b from those of a and b (arrays of any shape), each
    summed term by term in :func:`_hamilton_terms`' order."""
    out = []
    for (u, v, _), *rest in _hamilton_terms(*a, *b):
        component = u * v
        for u, v, sign in rest:
            component = component + u * v if sign > 0 else component - u * v
        out.append(component)
    return tuple(out)


def prefix_products(q: np.ndarray, segment: np.ndarray | None = None) -> np.ndarray:
    """P_i = q_0·q_1·…·q_i of (m, 4) quaternions in log2(m) vectorised rounds (Hillis-Steele
    scan; the product is associative, so the rounds may group it freely).

    ``segment`` (m,) int, non-decreasing: the products restart where it changes (P_i is then
    the product from the first quaternion of i's segment) — many short sequences scanned in
    one pass instead of one Python loop each (the moves of a session: 50× fewer calls).

    Parameters
    ----------
    q : (m, 4) array
        Quaternions, scalar last.
    segment : (m,) int array, optional

    Returns
    -------
    (m, 4) array
        The products P_i.
    """
    parts = np.array(q.T, order="C")       # a copy: ``q`` is left as it is
    out = np.empty_like(parts)
    tmp = np.empty(parts.shape[1])
    if segment is None:     # P_i = P_{i−d}·P_i for every i ≥ d, round after round
        d = 1
        while d < parts.shape[1]:
            m = parts.shape[1] - d
            parts[:, d:] = _hamilton_into(parts[:, :-d], parts[:, d:], out[:, :m], tmp[:m])
            d *= 2
        return np.ascontiguousarray(parts.T)
    segment = np.asarray(segment)
    # component by component, each contiguous, on slices: round d multiplies every P_{i−d}·P_i
    # (i ≥ d) and puts back the old P_i where i − d lies in another segment — each kept
    # product the very one a gather of the same-segment pairs made, without the gathers
    # (1.5-2× faster on a session's moves)
    for d, stale in _segment_rounds(segment.tobytes(), segment.dtype.str):
        m = parts.shape[1] - d
        new = _hamilton_into(parts[:, :-d], parts[:, d:], out[:, :m], tmp[:m])
        new[:, stale] = parts[:, d:][:, stale]
        parts[:, d:] = new
    return np.ascontiguousarray(parts.T)


def _hamilton_into(a: np.ndarray, b: np.ndarray, out: np.ndarray, tmp: np.ndarray
                   ) -> np.ndarray:
    """:func:`_hamilton` of (4, k) component rows into ``out`` (4, k), ``tmp`` (k,) scratch: the
    same products, summed in the same order (so the same values), with no temporaries."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    for o, terms in zip(out, _hamilton_terms(ax, ay, az, aw, bx, by, bz, bw)):
        (u, v, _), *rest = terms
        np.multiply(u, v, out=o)
        for u, v, sign in rest:
            np.multiply(u, v, out=tmp)
            (np.add if sign > 0 else np.subtract)(o, tmp, out=o)
    return out


def _hamilton_terms(ax, ay, az, aw, bx, by, bz, bw) -> tuple:
    """The Hamilton product's components (x, y, z, w) of a·b as their terms (u, v, sign of
    u·v), in the order they are summed: x = aw·bx + ax·bw + ay·bz − az·by, and so on."""
    return (((aw, bx, 1), (ax, bw, 1), (ay, bz, 1), (az, by, -1)),
            ((aw, by, 1), (ax, bz, -1), (ay, bw, 1), (az, bx, 1)),
            ((aw, bz, 1), (ax, by, 1), (ay, bx, -1), (az, bw, 1)),
            ((aw, bw, 1), (ax, bx, -1), (ay, by, -1), (az, bz, -1)))


@functools.lru_cache(maxsize=16)
def _segment_rounds(segment_bytes: bytes, dtype: str) -> tuple:
    """Each round of the segmented scan: d = 1, 2, 4, ... while some index has its d-th
    predecessor in its own segment, and the indices i − d (i ≥ d) whose d-th predecessor lies
    in another segment (their P_i stays). The same for every scan over the same moves (each
    least-squares step of a move fit), so found once."""
    segment = np.frombuffer(segment_bytes, dtype)
    rounds, d = [], 1
    while d < len(segment):
        same = segment[d:] == segment[:-d]
        if not same.any():
            break
        rounds.append((d, np.flatnonzero(~same)))
        d *= 2
    return tuple(rounds)


def integrate_attitude(r0: np.ndarray, rate: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """R_{i+1} = R_i·Exp(ω_i·Δt_i) from R_0 = ``r0`` (body rates ω_i over step i, e.g. the
    mean of the step's end samples); returns (m + 1, 3, 3).

    Parameters
    ----------
    r0 : (3, 3) array
        Starting attitude.
    rate : (m, 3) array
        Body rate over each step [rad/s].
    dt : (m,) array
        Step lengths [s].

    Returns
    -------
    (m + 1, 3, 3) array
    """
    steps = Rotation.from_rotvec(rate * dt[:, None]).as_quat()
    out = np.empty((len(rate) + 1, 3, 3))
    out[0] = r0
    if len(rate):
        out[1:] = r0 @ Rotation.from_quat(prefix_products(steps)).as_matrix()
    return out


def corrected_move(r_start, r_end, rate, dt) -> tuple[np.ndarray, np.ndarray]:
    """Attitudes (m + 1, 3, 3) of a move that follows ``rate`` and ends exactly at ``r_end``:
    the end error Log(R_intᵀ·R_end) [rad, body frame], also returned, is spread linearly in
    time.

    Parameters
    ----------
    r_start, r_end : (3, 3) arrays
        Attitudes of the holds before and after.
    rate : (m, 3) array
        Body rate over each step [rad/s].
    dt : (m,) array
        Step lengths [s].

    Returns
    -------
    path : (m + 1, 3, 3) array
    error : (3,) array
        End error before the correction [rad].
    """
    r_int = integrate_attitude(r_start, rate, dt)
    error = Rotation.from_matrix(r_int[-1].T @ r_end).as_rotvec()
    s = np.concatenate(([0.0], np.cumsum(dt))) / max(float(np.sum(dt)), 1e-12)
    corr = Rotation.from_rotvec(np.outer(s, error)).as_matrix()
    return r_int @ corr, error


def body_rates(rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Instantaneous body rates [rad/s] at each attitude sample: the mean of the rates that
    carry it from the previous attitude and on to the next, Log(R_iᵀR_{i+1}) / Δt.

    A gyro samples the rate at its own instant, as the real one does; a forward difference
    would put the twin's gyro half a sample ahead of its accelerometer.

    Parameters
    ----------
    rot : (n, 3, 3) array
        Attitudes.
    t : (n,) array
        Their times [s].

    Returns
    -------
    (n, 3) array
        [rad/s]; the first and last sample take their one neighbouring step's rate.
    """
    if len(t) < 2:
        return np.zeros((len(t), 3))
    rel = np.einsum("nji,njk->nik", rot[:-1], rot[1:])
    step = Rotation.from_matrix(rel).as_rotvec() / np.diff(t)[:, None]
    rates = np.empty((len(t), 3))
    rates[0], rates[-1] = step[0], step[-1]
    rates[1:-1] = 0.5 * (step[:-1] + step[1:])
    return rates


def build(session, hold_rot: list[np.ndarray], gyro_rate: np.ndarray) -> Trajectory:
    """The trajectory at the IMU sample times; ``gyro_rate`` (n, 3) is the calibrated gyro
    [rad/s] that moves follow.

    Parameters
    ----------
    session : Session
    hold_rot : list of (3, 3) arrays
        Attitude of each hold (:func:`hold_attitudes`).
    gyro_rate : (n, 3) array
        [rad/s].

    Returns
    -------
    Trajectory
    """
    n = len(session.t)
    rot = np.empty((n, 3, 3))
    rate = np.zeros((n, 3))        # holds keep one attitude: only moves turn
    hold = np.zeros(n, int)
    blend = np.zeros(n)
    moves = {s.before: s for s in session.segments if s.kind == "motion"}
    for k, h in enumerate(session.holds):
        end = session.holds[k + 1].i0 if k + 1 < len(session.holds) else n
        start = 0 if k == 0 else h.i0
        rot[start:end] = hold_rot[k]
        hold[start:end] = k
        move = moves.get(k)
        if move is not None:       # steps a-1 → a … b-1 → b, each at its mean rate (trapezoid)
            a, b = move.i0, move.i1
            dt = np.diff(session.t[a - 1:b + 1])
            mid = 0.5 * (gyro_rate[a - 1:b] + gyro_rate[a:b + 1])
            path, _ = corrected_move(hold_rot[k], hold_rot[k + 1], mid, dt)
            rot[a:b] = path[1:-1]
            blend[a:b] = np.linspace(0, 1, b - a + 2)[1:-1]
            # the twin's gyro reads the path's own rates (the motion as the model sees it:
            # ending where the next hold is, whatever the real gyro's unmodelled errors); the
            # hold samples at either end stay still, as the real board was
            rate[a:b] = body_rates(path, session.t[a - 1:b + 1])[1:-1]
    return Trajectory(rot, rate, hold, blend)


def carried(traj: Trajectory, hold_rot: list[np.ndarray], vectors: np.ndarray,
            still_holds: bool = True) -> np.ndarray:
    """Per-sample body vector: each hold's own ``vectors[k]`` (n_holds, 3), carried through a
    move by the attitude change and blended from the hold before to the hold after.

    ``still_holds``: the attitude is exactly the hold's outside the moves (no tremor added), so
    those samples take the hold's vector as it is and only the moves are rotated.

    Parameters
    ----------
    traj : Trajectory
    hold_rot : list of (3, 3) arrays
        Attitude of each hold.
    vectors : (n_holds, 3) array
        Each hold's vector in the body frame (e.g. specific force [m/s²], field [mGauss]).
    still_holds : bool

    Returns
    -------
    (n, 3) array
        In the unit of ``vectors``.
    """
    out = np.take(np.asarray(vectors), traj.hold, axis=0)     # faster than [traj.hold]
    turning = traj.blend > 0 if still_holds else np.ones(len(out), bool)
    k = traj.hold[turning]
    k_next = np.minimum(k + 1, len(hold_rot) - 1)
    hold_rot = np.asarray(hold_rot)
    blend = traj.blend[turning][:, None]
    ned = ((1 - blend) * np.einsum("nij,nj->ni", hold_rot[k], vectors[k])
           + blend * np.einsum("nij,nj->ni", hold_rot[k_next], vectors[k_next]))
    out[turning] = np.einsum("nji,nj->ni", traj.rot[turning], ned)
    return out


def with_hold_motion(traj: Trajectory, session, rate: np.ndarray, turn: np.ndarray
                     ) -> Trajectory:
    """The trajectory with a small motion inside each hold: attitude R_k·``turn`` (the holds'
    rotations, :func:`apmcal.diagnosis.session.hold_motion.hold_rotations`) and the body rate ``rate``
    [rad/s] there.

    Parameters
    ----------
    traj : Trajectory
    session : Session
    rate : (n, 3) array
        Rate of the motion [rad/s].
    turn : (n, 3, 3) array
        Its rotations.

    Returns
    -------
    Trajectory
        A new one; ``traj`` is left as it is.
    """
    inside = np.zeros(len(rate), bool)
    for h in session.holds:
        inside[h.i0:h.i1] = True
    rot, out_rate = traj.rot.copy(), traj.rate.copy()
    rot[inside] = rot[inside] @ turn[inside]
    out_rate[inside] = rate[inside]
    return Trajectory(rot, out_rate, traj.hold, traj.blend)
