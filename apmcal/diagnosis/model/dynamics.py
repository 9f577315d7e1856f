"""The moves between holds: the accelerometer and compass predicted from the gyro.

During a move the gyro is the only sensor that measures the turn, so the model predicts the
other two from it (the consistency [Chow] builds its joint calibration on): starting from the
hold before, the calibrated rate ω = F_g⁻¹(measured − bias) is integrated into the attitude
change R(t), and the hold's own specific force f_k and field b_k are carried along::

    acc(t) = F_a·R(t − τ)ᵀ f_k + offset + …        mag(t) = S·R(t)ᵀ b_k + offset + …

F_g is sitl's gyro forward matrix (diag(scale)·T_g⁻¹, [Oppong] §2.2: ``gyro_scale``), τ the
accelerometer's delay behind the gyro (``time_offset``). Their residuals are scored like the
holds', and the ``gyro_scale``, ``time_offset`` and ``cross_axis`` parameters are fitted to them.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from apmcal.diagnosis.model.static_fit import non_orthogonality
from apmcal.diagnosis.scoring.gap import ResidualBlock
from apmcal.diagnosis.session.trajectory import prefix_products
from apmcal.solvers.strapdown import hat

AXES = ("x", "y", "z")
FIT_RATE_HZ = 50.0      # the dynamic fits integrate the moves in steps of about 1/50 s


def gyro_forward(scale, gamma) -> np.ndarray:
    """sitl's F_g = diag(scale)·T_g⁻¹ with [Oppong]'s six misalignment angles γ (yz, zy, zx,
    xz, xy, yx) [rad] (:meth:`apmcal.sensor_model.truth.Truth.gyro_forward`).

    Parameters
    ----------
    scale : (3,) array
        Gyro scale factors (1: none).
    gamma : (6,) array
        Misalignment angles γ [rad].

    Returns
    -------
    (3, 3) array
        F_g: measured rate = F_g · true rate.
    """
    g_yz, g_zy, g_zx, g_xz, g_xy, g_yx = gamma
    t_g = np.array([[1, -g_yz, g_zy], [g_xz, 1, -g_zx], [-g_xy, g_yx, 1.0]])
    return np.diag(scale) @ np.linalg.inv(t_g)


@dataclass
class Dynamics:
    """The parameters the moves determine: gyro scale and misalignment, accelerometer delay
    [s], and the accelerometer terms that holds in fitted orientations hardly see — its
    non-orthogonality α [rad] and quadratic scale k2 [1/(m/s²)] (``acc_terms``, None when
    neither is modelled; moved into the accelerometer itself once fitted).

    Attributes
    ----------
    gyro_scale : (3,) array
        Gyro scale factors (1: none).
    gyro_gamma : (6,) array
        Gyro misalignment angles γ (yz, zy, zx, xz, xy, yx) [rad].
    time_offset_s : float
        Accelerometer delay behind the gyro [s].
    acc_terms : dict or None
        "alpha" (3,) [rad] and/or "k2" (3,) [1/(m/s²)].
    sigma : dict
        One-sigma of the fitted parameters: "params" (values) and "names" (the parameter
        block of each value).
    """

    gyro_scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    gyro_gamma: np.ndarray = field(default_factory=lambda: np.zeros(6))
    time_offset_s: float = 0.0
    acc_terms: dict | None = None
    sigma: dict = field(default_factory=dict)

    @property
    def forward(self) -> np.ndarray:
        """The gyro matrix F_g (3, 3) of ``gyro_scale`` and ``gyro_gamma``."""
        return gyro_forward(self.gyro_scale, self.gyro_gamma)


# prior one-sigma of the move parameters (MAP fit; wide against real sensors: MPU-6000 gyro
# sensitivity ±3 %, cross-axis ±2 %; a delay of a few samples at most; the accelerometer
# terms as in static_fit.PRIOR_SIGMA)
PRIOR_SIGMA = {"gyro_scale": 0.05, "gyro_gamma": 0.05, "time_offset": 0.005, "alpha": 0.05,
               "k2": 1e-3}
ACC_TERMS = {"cross_axis": "alpha", "scale_nonlinearity": "k2"}
# the physical limit of each move parameter (apmcal.diagnosis.model.plausible.LIMITS)
BOUND = {"gyro_scale": 0.1, "gyro_gamma": 0.05, "time_offset": 0.05, "alpha": 0.05,
         "k2": 1e-3}


def acc_with_terms(geo, terms: dict):
    """The accelerometer geometry with its non-orthogonality ``alpha`` and/or quadratic scale
    ``k2`` replaced by the given values.

    Parameters
    ----------
    geo : GeometryFit
        The accelerometer's fit (:class:`apmcal.diagnosis.model.static_fit.GeometryFit`).
    terms : dict
        "alpha" (3,) [rad] and/or "k2" (3,) [1/(m/s²)].

    Returns
    -------
    GeometryFit
        A copy; ``geo`` is left as it is.
    """
    out = replace(geo, params=dict(geo.params))
    if "alpha" in terms:
        scale = np.exp(np.asarray(geo.params["log_scale"]))
        out.forward = np.diag(scale) @ np.linalg.inv(non_orthogonality(terms["alpha"]))
        out.params["alpha"] = list(terms["alpha"])
    if "k2" in terms:
        out.k2 = np.asarray(terms["k2"], float)
        out.params["k2"] = list(terms["k2"])
    return out


@dataclass
class Moves:
    """The move pieces to evaluate: session sample ranges, the hold before each, piece ids.

    Attributes
    ----------
    i0, i1 : (k,) int arrays
        Half-open session sample ranges of the moves.
    hold : (k,) int array
        Index (into ``Session.holds``) of the hold before each move.
    piece : (k,) int array
        Session-wide piece id of each move.
    """

    i0: np.ndarray
    i1: np.ndarray
    hold: np.ndarray
    piece: np.ndarray

    @classmethod
    def of(cls, session, pieces: np.ndarray | None = None) -> "Moves":
        """The move pieces of ``session``, or of those among the piece ids ``pieces``."""
        ids = session.pieces.select(hold=False)
        if pieces is not None:
            ids = ids[np.isin(ids, pieces)]
        holds = np.array([session.segments[session.pieces.segment[p]].before for p in ids],
                         dtype=int)
        return cls(session.pieces.i0[ids], session.pieces.i1[ids], holds, ids)

    def __len__(self) -> int:
        return len(self.i0)

    def rows(self) -> np.ndarray:
        """Session sample indices the moves' integration reads: each move's samples and the
        last hold sample before it."""
        if not len(self):
            return np.zeros(0, int)
        return np.concatenate([np.arange(a - 1, b) for a, b in zip(self.i0, self.i1)])


def relative_attitudes(rate: np.ndarray, t: np.ndarray, moves: Moves, step: int = 1
                       ) -> Rotation:
    """R(t) relative to the hold before, at every ``step``-th move sample (one Rotation of
    them all, moves one after the other): the integral of ``rate`` [rad/s] from the last hold
    sample on. Each sample interval turns by the mean of its two end rates (trapezoid: the
    rectangle rule's O(Δt) error would be a gap of the real data only); ``step`` > 1 joins
    ``step`` intervals into one rotation (their summed rotation vectors, second-order error),
    for the fits' cheaper passes.

    Parameters
    ----------
    rate : (n, 3) array
        Body rate at every session sample [rad/s].
    t : (n,) array
        Session sample times [s].
    moves : Moves
    step : int
        Keep every ``step``-th move sample.

    Returns
    -------
    Rotation
        One rotation per kept move sample (the samples of :func:`move_index`), body frame
        relative to the hold before.
    """
    plan = _plan(moves, t, step)
    return _attitudes(plan, np.take(rate, plan.rows, axis=0))


@dataclass(frozen=True)
class _Plan:
    """What integrating ``moves`` on sample times ``t`` every ``step``-th sample reads and
    where it puts it: the same for every gyro matrix a fit tries, so found once per
    (moves, times, step) and kept (:func:`_plan`), with the last turns integrated through it
    (``recent``, :func:`_known_turns`).

    ``rows`` are :meth:`Moves.rows` (each move's samples and the last hold sample before it):
    a rate is handed to :func:`_attitudes` as its values at those rows only, ``(len(rows), 3)``.
    """

    t: np.ndarray               # the sample times the plan is for (compared by identity)
    rows: np.ndarray            # (r,) session rows the integration reads
    prev: np.ndarray            # (s,) position in rows of each interval's first end ...
    dt: np.ndarray              # (s,) ... its length [s] (the second end is prev + 1)
    starts: np.ndarray          # (k + 1,) each move's first interval, and the total
    ends: tuple                 # per move: its kept intervals' last index (step > 1), else ()
    segment: np.ndarray         # (m,) move of each kept sample
    index: np.ndarray           # (m,) session sample index of each kept sample
    hold: np.ndarray            # (m,) hold before each kept sample
    kept: np.ndarray            # (m,) position in rows of each kept sample
    kept_starts: np.ndarray     # (k + 1,) each move's first kept sample, and their number
    recent: list = field(default_factory=list, compare=False)   # (gyro matrix bytes,
                                # calibrated rates at rows, turns), newest last (_known_turns)


_PLANS: OrderedDict = OrderedDict()     # the recent plans, by moves, times and step
PLANS_KEPT = 8
TURNS_KEPT = 4                  # the turns kept per plan (full-rate ones are MBs)


def _plan(moves: Moves, t: np.ndarray, step: int) -> _Plan:
    """The integration plan of ``moves`` on ``t`` at ``step``: the one kept for the same move
    ranges and holds on the very same times array (every model of a session, real or twin,
    integrates its moves on the session's own times), or made and kept."""
    key = (id(t), step, np.asarray(moves.i0).tobytes(), np.asarray(moves.i1).tobytes(),
           np.asarray(moves.hold).tobytes())
    plan = _PLANS.get(key)
    if plan is None or plan.t is not t:     # (a kept plan holds its t: the id is not reused)
        plan = _PLANS[key] = _make_plan(moves, t, step)
        while len(_PLANS) > PLANS_KEPT:
            _PLANS.popitem(last=False)
    else:
        _PLANS.move_to_end(key)
    return plan


def _make_plan(moves: Moves, t: np.ndarray, step: int) -> _Plan:
    length = np.asarray(moves.i1 - moves.i0, int)
    rows = moves.rows()
    first_row = np.cumsum(length + 1) - (length + 1)       # each move's hold sample in rows
    starts = np.concatenate(([0], np.cumsum(length)))
    move_of = np.repeat(np.arange(len(length)), length)
    prev = first_row[move_of] + np.arange(starts[-1]) - starts[move_of]
    dt = np.take(t, rows[prev + 1]) - np.take(t, rows[prev])     # t[a:b] − t[a−1:b−1]
    index, hold = move_index(moves, step)
    if step == 1:
        ends, segment = (), move_of
        kept = prev + 1
    else:
        ends = tuple(np.arange(step - 1, n, step) for n in length)
        segment = np.repeat(np.arange(len(length)), [len(e) for e in ends])
        kept = np.concatenate([first_row[m] + 1 + e for m, e in enumerate(ends)]) \
            if len(ends) else np.zeros(0, int)
    kept_starts = np.searchsorted(segment, np.arange(len(length) + 1))
    for a in (rows, prev, dt, starts, segment, index, hold, kept, kept_starts):
        a.flags.writeable = False           # shared by every caller of the plan
    return _Plan(t, rows, prev, dt, starts, ends, segment, index, hold, kept, kept_starts)


def _attitudes(plan: _Plan, rate_rows: np.ndarray) -> Rotation:
    """:func:`relative_attitudes` of a rate given at ``plan.rows`` only (``rate_rows``,
    (len(rows), 3) [rad/s]): every move's intervals at once (each value the very product
    and sum the move-by-move loop made)."""
    if not len(plan.starts) - 1:
        return Rotation.identity(0)
    q = Rotation.from_rotvec(_step_turns(plan, rate_rows)).as_quat()
    return Rotation.from_quat(prefix_products(q, plan.segment))


def _step_turns(plan: _Plan, rate_rows: np.ndarray) -> np.ndarray:
    """The rotation vector of each kept step (m, 3) [rad]: trapezoid turns of the intervals,
    ``step`` of them summed (the running sums move by move: one across moves would round
    differently)."""
    turn = 0.5 * (np.take(rate_rows, plan.prev, axis=0)
                  + np.take(rate_rows, plan.prev + 1, axis=0)) * plan.dt[:, None]
    if plan.ends:
        parts = []
        for a, b, ends in zip(plan.starts[:-1], plan.starts[1:], plan.ends):
            parts.append(np.diff(np.vstack([np.zeros(3), np.cumsum(turn[a:b], axis=0)[ends]]),
                                 axis=0))
        turn = np.concatenate(parts)
    return turn


def move_index(moves: Moves, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Session sample index of every ``step``-th move sample (the ones relative_attitudes
    returns), and the hold before it.

    Returns
    -------
    index : (k,) int array
        Session sample indices.
    hold : (k,) int array
        Index of the hold before each sample.
    """
    idx, hold = [], []
    for a, b, k in zip(moves.i0, moves.i1, moves.hold):
        i = np.arange(a, b) if step == 1 else np.arange(a + step - 1, b, step)
        idx.append(i)
        hold.append(np.full(len(i), k))
    if not idx:
        return np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(idx), np.concatenate(hold)


def move_turns(session, forward: np.ndarray, moves: Moves, rate_cal: np.ndarray,
               step: int = 1) -> tuple:
    """The body rate (the gyro through its matrix ``forward``) at every session sample, and
    the moves' attitudes relative to the hold before (:func:`relative_attitudes`).

    Parameters
    ----------
    session : Session
    forward : (3, 3) array
        Gyro matrix F_g.
    moves : Moves
    rate_cal : (n, 3) array
        Gyro minus its fitted bias terms at every session sample [rad/s].
    step : int
        Keep every ``step``-th move sample.

    Returns
    -------
    rate : (n, 3) array
        Body rate [rad/s] at the moves' samples and the last hold sample before each; NaN
        elsewhere (nothing reads it there).
    rel : Rotation
        Attitudes relative to the hold before, one per kept move sample.
    """
    plan = _plan(moves, session.t, step)
    body, rel = _turns(plan, forward, np.take(rate_cal, plan.rows, axis=0))
    rate = np.full_like(rate_cal, np.nan)
    rate[plan.rows] = body
    return rate, rel


def _turns(plan: _Plan, forward: np.ndarray, cal_rows: np.ndarray) -> tuple:
    """(body rate at ``plan.rows`` [rad/s], attitudes) of the calibrated gyro ``cal_rows``
    (its values at ``plan.rows``) through the gyro matrix ``forward``: the moves' rows only,
    about an eighth of a session's samples, turned again at every step of a gyro fit."""
    body = cal_rows @ np.linalg.inv(forward).T
    body.flags.writeable = False        # kept and shared (_known_turns)
    return body, _attitudes(plan, body)


def predicted(session, fit, dyn: Dynamics, moves: Moves, rate_cal: np.ndarray,
              hold_f: np.ndarray, hold_b: np.ndarray | None, step: int = 1) -> tuple:
    """Predicted acc (and mag at the IMU times) of every ``step``-th move sample.

    ``rate_cal`` is the gyro minus its fitted bias terms at every session sample; ``hold_f`` /
    ``hold_b`` the calibrated specific force and field of each hold.

    Parameters
    ----------
    session : Session
    fit : ModelFit
    dyn : Dynamics
    moves : Moves
    rate_cal : (n, 3) array
        Gyro minus its fitted bias terms at every session sample [rad/s].
    hold_f : (n_holds, 3) array
        Specific force of each hold [m/s²] (:func:`apmcal.diagnosis.model.nominal.hold_vectors`).
    hold_b : (n_holds, 3) array or None
        Field of each hold [mGauss].
    step : int
        Keep every ``step``-th move sample.

    Returns
    -------
    idx : (k,) int array
        Session sample index of each predicted sample.
    acc : (k, 3) array
        Predicted accelerometer [m/s²].
    mag : (k, 3) array or None
        Predicted compass [mGauss] (None without a compass fit or hold fields).
    """
    plan = _plan(moves, session.t, step)
    turns = _known_turns(plan, dyn.forward, np.take(rate_cal, plan.rows, axis=0))
    return _predicted(session, fit, dyn, plan, turns, hold_f, hold_b)


def _known_turns(plan: _Plan, forward: np.ndarray, cal_rows: np.ndarray) -> tuple:
    """:func:`_turns`, or the turns kept on ``plan`` for the same gyro matrix and the same
    calibrated rates value for value: models that leave the gyro alone integrate the same
    moves again and again (a comparison reads the rates once, the integration many times)."""
    key = forward.tobytes()
    for i, (matrix, rows, turns) in enumerate(plan.recent):
        if matrix == key and np.array_equal(rows, cal_rows):
            plan.recent.append(plan.recent.pop(i))      # the newest last
            return turns
    turns = _turns(plan, forward, cal_rows)
    plan.recent.append((key, cal_rows, turns))
    del plan.recent[:-TURNS_KEPT]
    return turns


def _predicted(session, fit, dyn: Dynamics, plan: _Plan, turns: tuple, hold_f: np.ndarray,
               hold_b: np.ndarray | None) -> tuple:
    """:func:`predicted` with the integration ``turns`` (:func:`_turns`) already made."""
    body, rel = turns
    idx, hold = plan.index, plan.hold
    f = rel.apply(np.take(hold_f, hold, axis=0), inverse=True)     # R(t)ᵀ·f_k
    if dyn.time_offset_s:          # the accelerometer samples the past: f(t − τ) = Exp(ωτ)·f(t)
        f = Rotation.from_rotvec(np.take(body, plan.kept, axis=0) * dyn.time_offset_s).apply(f)
    temp = session.temp[idx] if session.temp is not None else None
    geo = fit.acc if dyn.acc_terms is None else acc_with_terms(fit.acc, dyn.acc_terms)
    acc = geo.predict(f / _radius(geo), fit.acc_columns(session.t[idx], temp))
    mag = None
    if hold_b is not None and fit.mag is not None:
        b = rel.apply(np.take(hold_b, hold, axis=0), inverse=True)
        cur = session.current[idx] if session.current is not None else None
        mag = fit.mag.predict(b / _radius(fit.mag), fit.mag_columns(session.t[idx], cur))
    return idx, acc, mag


def right_jacobian(theta: np.ndarray) -> np.ndarray:
    """SO(3)'s right Jacobian J_r(θ) (m, 3, 3) of rotation vectors θ (m, 3) [rad]:
    Exp(θ + δθ) = Exp(θ)·Exp(J_r(θ)·δθ) to first order.

    J_r = I − (1 − cos|θ|)/|θ|²·[θ]× + (|θ| − sin|θ|)/|θ|³·[θ]×² (their series below 1e-4 rad).
    """
    a = np.linalg.norm(theta, axis=-1)
    small = a < 1e-4
    safe = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a ** 2 / 24, (1 - np.cos(safe)) / safe ** 2)
    c2 = np.where(small, 1 / 6 - a ** 2 / 120, (safe - np.sin(safe)) / safe ** 3)
    k = hat(theta)
    return np.eye(3) - c1[:, None, None] * k + c2[:, None, None] * (k @ k)


def _gyro_matrix_derivatives(scale: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """∂M/∂p (9, 3, 3) of M = F_g⁻¹ = T_g·diag(1/scale) (:func:`gyro_forward`) for the move
    fit's gyro parameters: the three scales, then the six angles γ (yz, zy, zx, xz, xy, yx)."""
    g_yz, g_zy, g_zx, g_xz, g_xy, g_yx = gamma
    t_g = np.array([[1, -g_yz, g_zy], [g_xz, 1, -g_zx], [-g_xy, g_yx, 1.0]])
    out = np.zeros((9, 3, 3))
    for k in range(3):
        out[k, :, k] = -t_g[:, k] / scale[k] ** 2
    # where each angle sits in T_g, and its sign
    for j, (row, col, sign) in enumerate([(0, 1, -1), (0, 2, 1), (1, 2, -1), (1, 0, 1),
                                          (2, 0, -1), (2, 1, 1)]):
        out[3 + j, row, col] = sign / scale[col]
    return out


def _rotate(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """a_m·v_cm (c, m, 3) of matrices a (m, 3, 3) and vectors v (c, m, 3), column by column
    (np.einsum took 5× as long on these shapes)."""
    return a[:, :, 0] * v[..., 0:1] + a[:, :, 1] * v[..., 1:2] + a[:, :, 2] * v[..., 2:3]


def _reading_slope(geo, x: np.ndarray) -> tuple:
    """How ``geo.predict(x / radius, …)`` moves with the body vectors x (m, 3): the sensor
    forward matrix and the per-sample factor 1 + 2·k2 ⊙ s of its quadratic term (s the
    reading before offset), and s itself — d(reading) = factor ⊙ (dx·Fᵀ). None, None, None
    without geometry (the reading is x itself)."""
    if not geo.geometry:
        return None, None, None
    s = (geo.radius * (x / geo.radius)) @ geo.forward.T
    return geo.forward, 1.0 + 2.0 * geo.k2 * s, s


def _through(slope: tuple, dx: np.ndarray) -> np.ndarray:
    """d(reading) (c, m, 3) of body-vector changes dx (c, m, 3) (:func:`_reading_slope`)."""
    forward, factor, _ = slope
    return dx if forward is None else factor * (dx @ forward.T)


def move_jacobian(session, fit, dyn: Dynamics, layout: dict, start: dict, plan: _Plan,
                  turns: tuple, cal_rows: np.ndarray, cal_turns: np.ndarray,
                  hold_f: np.ndarray, hold_b: np.ndarray | None, with_mag: bool) -> tuple:
    """∂(predicted acc, mag)/∂(move parameters) at ``dyn``, analytic: what finite differences
    got by integrating every move again per gyro parameter.

    The kept steps turn by θ_l = M·Θ_l (M = F_g⁻¹, Θ_l the step's turn of the calibrated gyro,
    linear in the rates), and R_i = Exp(θ_1)···Exp(θ_i) within a move. A change δθ_l turns
    R_i by δφ_i = R_iᵀ·Σ_{l≤i} R_l·J_r(θ_l)·δθ_l (body frame, first order), so the carried
    vector R_iᵀ·v_k changes by (R_iᵀ·v_k) × δφ_i. The delay τ turns the accelerometer's by
    Exp(τω): ∂/∂τ = ω × f', and a change δω turns it by Exp(τω)·((J_r(τω)·τ·δω) × f).
    The accelerometer's α and k2 move its reading directly (:class:`GeometryFit`).

    Parameters
    ----------
    session : Session
    fit : ModelFit
    dyn : Dynamics
        The parameters where the derivatives are taken.
    layout : dict
        The fit's parameter blocks, name -> (size, prior σ) (:func:`_layout`).
    start : dict
        The accelerometer terms' starting values (the parameters are changes from them).
    plan : _Plan
    turns : tuple
        (body rate at ``plan.rows``, attitudes) of :func:`_turns` for ``dyn``'s gyro matrix.
    cal_rows : (r, 3) array
        The calibrated gyro at ``plan.rows`` [rad/s].
    cal_turns : (m, 3) array
        Its turn Θ_l over each kept step [rad] (:func:`_step_turns`).
    hold_f, hold_b : (n_holds, 3) arrays
        Each hold's specific force [m/s²] and field [mGauss] (``hold_b`` None: no compass).
    with_mag : bool
        Whether the compass is part of the fit.

    Returns
    -------
    acc : (m, 3, n) array
        ∂(predicted accelerometer)/∂p [m/s² per parameter unit].
    mag : (m, 3, n) array or None
        ∂(predicted compass)/∂p [mGauss per parameter unit] (None without ``with_mag``).
    """
    body, rel = turns
    n = sum(size for size, _ in layout.values())
    m = len(plan.index)
    d_acc = np.zeros((n, m, 3))
    d_mag = np.zeros((n, m, 3)) if with_mag else None
    f = rel.apply(np.take(hold_f, plan.hold, axis=0), inverse=True)     # R_iᵀ·f_k
    tau = dyn.time_offset_s
    omega = np.take(body, plan.kept, axis=0)
    spin = Rotation.from_rotvec(omega * tau) if tau else None
    f_late = spin.apply(f) if tau else f
    geo = fit.acc if dyn.acc_terms is None else acc_with_terms(fit.acc, dyn.acc_terms)
    slope = _reading_slope(geo, f_late)
    col = 0
    for name in layout:
        if name == "gyro_scale":        # with gyro_gamma: nine columns from here
            d_m = _gyro_matrix_derivatives(dyn.gyro_scale, dyn.gyro_gamma)
            rot = rel.as_matrix()
            # the steps' turns θ_l = M·Θ_l (to rounding: what the integration turned by)
            rj = rot @ right_jacobian(cal_turns @ np.linalg.inv(dyn.forward).T)
            d_theta = cal_turns @ d_m.transpose(0, 2, 1)                # (c, m, 3)
            spread = _rotate(rj, d_theta)                               # hold frame
            total = np.cumsum(spread, axis=1)
            before = np.zeros_like(total)
            for a, b in zip(plan.kept_starts[:-1], plan.kept_starts[1:]):   # each move anew
                if a:
                    before[:, a:b] = total[:, a - 1:a]
            d_phi = _rotate(rot.transpose(0, 2, 1), total - before)     # body frame
            d_f = np.cross(f[None], d_phi)
            if tau:
                d_omega = np.take(cal_rows, plan.kept, axis=0) @ d_m.transpose(0, 2, 1)
                lever = _rotate(right_jacobian(omega * tau), tau * d_omega)
                d_f = _rotate(spin.as_matrix(), d_f + np.cross(lever, f[None]))
            d_acc[col:col + 9] = _through(slope, d_f)
            if with_mag:
                b_body = rel.apply(np.take(hold_b, plan.hold, axis=0), inverse=True)
                d_mag[col:col + 9] = _through(_reading_slope(fit.mag, b_body),
                                              np.cross(b_body[None], d_phi))
            col += 9
        elif name == "gyro_gamma":
            continue
        elif name == "time_offset":
            d_acc[col] = _through(slope, np.cross(omega, f_late)[None])[0]
            col += 1
        elif name == "k2":
            for j in range(3):
                d_acc[col + j, :, j] = slope[2][:, j] ** 2
            col += 3
        elif name == "alpha":
            alpha = np.asarray(dyn.acc_terms["alpha"], float)
            scale = np.exp(np.asarray(geo.params["log_scale"]))
            n_inv = np.linalg.inv(non_orthogonality(alpha))
            for j, (row, c, sign) in enumerate([(0, 1, -1), (0, 2, 1), (1, 2, -1)]):
                d_n = np.zeros((3, 3))
                d_n[row, c] = sign
                d_forward = -np.diag(scale) @ n_inv @ d_n @ n_inv
                d_acc[col + j] = slope[1] * (f_late @ d_forward.T)
            col += 3
    return d_acc.transpose(1, 2, 0), None if d_mag is None else d_mag.transpose(1, 2, 0)


def _radius(geo) -> float:
    return geo.radius if geo.geometry else 1.0


def move_residuals(session, fit, dyn: Dynamics, rate_cal, hold_f, hold_b) -> list:
    """Residual blocks of every move piece: accelerometer, and compass when it shares the
    IMU's sample times (a separate, slower compass is left out of the moves).

    Parameters
    ----------
    session : Session
    fit : ModelFit
    dyn : Dynamics
    rate_cal : (n, 3) array
        Gyro minus its fitted bias terms at every session sample [rad/s].
    hold_f : (n_holds, 3) array
        Specific force of each hold [m/s²].
    hold_b : (n_holds, 3) array or None
        Field of each hold [mGauss].

    Returns
    -------
    list of ResidualBlock
        Not scored by their distribution nor by their piece means (``shape`` False); empty
        without moves.
    """
    moves = Moves.of(session)
    if not len(moves):
        return []
    idx, acc, mag = predicted(session, fit, dyn, moves, rate_cal, hold_f, hold_b)
    ends = np.cumsum(moves.i1 - moves.i0)
    starts = ends - (moves.i1 - moves.i0)
    t = session.t[idx]
    temp = session.temp[idx] if session.temp is not None else None
    blocks = [ResidualBlock([f"acc_{a}" for a in AXES], np.take(session.acc, idx, axis=0) - acc,
                            starts, ends,
                            moves.piece, t, temp, shape=False)]
    if mag is not None and session.mag is not None and session.mag.t is session.t:
        blocks.append(ResidualBlock([f"mag_{a}" for a in AXES],
                                    np.take(session.mag.values, idx, axis=0) - mag,
                                    starts, ends, moves.piece, t, None, shape=False))
    return blocks


def _layout(effects, fit) -> dict:
    """Parameter blocks of the move fit: name -> (size, prior σ)."""
    out = {}
    if "gyro_scale" in effects:
        out["gyro_scale"] = (3, PRIOR_SIGMA["gyro_scale"])
        out["gyro_gamma"] = (6, PRIOR_SIGMA["gyro_gamma"])
    if "time_offset" in effects:
        out["time_offset"] = (1, PRIOR_SIGMA["time_offset"])
    for effect, name in ACC_TERMS.items():      # when the holds left them to the moves
        if effect in effects and fit.acc.geometry and fit.acc_terms_in_moves:
            out[name] = (3, PRIOR_SIGMA[name])
    return out


def _unpack(p: np.ndarray, layout: dict, start: dict) -> Dynamics:
    d, k = Dynamics(), 0
    values = {}
    for name, (size, _) in layout.items():
        values[name] = p[k:k + size]
        k += size
    if "gyro_scale" in values:
        d.gyro_scale, d.gyro_gamma = 1.0 + values["gyro_scale"], values["gyro_gamma"]
    if "time_offset" in values:
        d.time_offset_s = float(values["time_offset"][0])
    terms = {name: start[name] + values[name] for name in ACC_TERMS.values() if name in values}
    d.acc_terms = terms or None
    return d


def fit_dynamics(session, fit, effects, train: np.ndarray, rate_cal, hold_f, hold_b,
                 sigma: dict) -> Dynamics:
    """The move parameters fitted to the training moves (MAP with the priors above);
    ``sigma`` gives each sensor's per-sample noise (the residuals are weighted by its inverse).

    Parameters
    ----------
    session : Session
    fit : ModelFit
        The holds' fit.
    effects : collection of str
        The model's effects (``gyro_scale``, ``time_offset``, ``cross_axis`` and
        ``scale_nonlinearity`` have move parameters).
    train : (k,) int array
        Session-wide ids of the training pieces.
    rate_cal : (n, 3) array
        Gyro minus its fitted bias terms at every session sample [rad/s].
    hold_f : (n_holds, 3) array
        Specific force of each hold [m/s²].
    hold_b : (n_holds, 3) array or None
        Field of each hold [mGauss].
    sigma : dict
        Per-sample noise: "acc" [m/s²] and, optionally, "mag" [mGauss].

    Returns
    -------
    Dynamics
        Neutral (no effect, scale 1) when no effect has move parameters or there are no
        training moves.
    """
    layout = _layout(effects, fit)
    moves = Moves.of(session, train)
    if not layout or not len(moves):
        return Dynamics()
    step = max(1, int(round(session.fs / FIT_RATE_HZ)))
    plan = _plan(moves, session.t, step)
    idx = plan.index
    cal_rows = np.take(rate_cal, plan.rows, axis=0)     # the same in every step
    cal_turns = _step_turns(plan, cal_rows) if "gyro_scale" in layout else None
    with_mag = hold_b is not None and fit.mag is not None and session.mag is not None \
        and session.mag.t is session.t and "mag" in sigma
    fit_b = hold_b if with_mag else None        # no compass prediction the fit does not read
    weight = {k: 1.0 / max(float(v), 1e-12) for k, v in sigma.items()}
    prior_sigma = np.concatenate([np.full(size, s) for size, s in layout.values()])
    # the accelerometer terms start from the holds' values (the prior is about the total)
    start = {name: np.asarray(fit.acc.params.get(name, np.zeros(3)), float)
             for name in ACC_TERMS.values()}
    offset = np.concatenate([start[name] if name in start else np.zeros(size)
                             for name, (size, _) in layout.items()])

    acc_seen = np.take(session.acc, idx, axis=0)        # the same in every step
    mag_seen = np.take(session.mag.values, idx, axis=0) if with_mag else None

    turns: dict = {}    # by gyro matrix: the steps of the other parameters turn the moves alike

    def turns_of(d: Dynamics) -> tuple:
        key = d.forward.tobytes()
        if key not in turns:
            if len(turns) >= 2:             # a gyro fit's matrices are new step after step
                turns.pop(next(iter(turns)))
            turns[key] = _turns(plan, d.forward, cal_rows)
        return turns[key]

    def residuals(p):
        d = _unpack(p, layout, start)
        _, acc, mag = _predicted(session, fit, d, plan, turns_of(d), hold_f, fit_b)
        r = [((acc_seen - acc) * weight["acc"]).ravel()]
        if with_mag:
            r.append(((mag_seen - mag) * weight["mag"]).ravel())
        r.append((p + offset) / prior_sigma)
        return np.concatenate(r)

    def jacobian(p):        # analytic (move_jacobian): no integration per gyro parameter
        d = _unpack(p, layout, start)
        d_acc, d_mag = move_jacobian(session, fit, d, layout, start, plan, turns_of(d),
                                     cal_rows, cal_turns, hold_f, hold_b, with_mag)
        rows = [-weight["acc"] * d_acc.reshape(-1, d_acc.shape[-1])]
        if with_mag:
            rows.append(-weight["mag"] * d_mag.reshape(-1, d_mag.shape[-1]))
        rows.append(np.diag(1.0 / prior_sigma))
        return np.concatenate(rows)

    n = len(prior_sigma)
    # kept within twice the physical limits: beyond them a term is not itself any more
    # (apmcal.diagnosis.model.plausible flags it) and the twin it makes can be nonsense
    reach = np.concatenate([np.full(size, 2.0 * BOUND[name]) for name, (size, _) in
                            layout.items()])
    low, high = -reach - offset, reach - offset
    # a holds' value already past the reach starts the fit at the nearest edge
    sol = least_squares(residuals, np.clip(np.zeros(n), low, high), jac=jacobian,
                        method="trf", x_scale=1e-3, bounds=(low, high))
    out = _unpack(sol.x, layout, start)
    from apmcal.solvers.uncertainty import covariance_from_jacobian
    cov, _ = covariance_from_jacobian(sol.jac, sol.fun, n)
    out.sigma = {"params": np.sqrt(np.clip(np.diag(cov), 0, None)).tolist(),
                 "names": [name for name, (size, _) in layout.items() for _ in range(size)]}
    return out
