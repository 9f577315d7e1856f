"""The cheaper per-model paths of ``apmcal gap`` against their plain definitions, value for value.

Each fast path (the segmented quaternion scan on slices, the moves integrated through a kept
plan, ...) must give the very numbers of the plain computation it replaced, written out here
the plain way.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from apmcal.diagnosis.model.dynamics import Moves, move_index, move_turns, relative_attitudes
from apmcal.diagnosis.session.trajectory import _hamilton, prefix_products, quat_multiply


def _plain_segmented_scan(q: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """The Hillis-Steele scan by gathers of the same-segment pairs (the former code)."""
    parts = np.ascontiguousarray(q.T)
    d = 1
    while d < len(segment):
        later = np.flatnonzero(segment[d:] == segment[:-d]) + d
        if not len(later):
            break
        parts[:, later] = _hamilton(np.take(parts, later - d, axis=1),
                                    np.take(parts, later, axis=1))
        d *= 2
    return np.ascontiguousarray(parts.T)


def _plain_relative_attitudes(rate, t, moves, step):
    """Move by move: trapezoid turns, ``step`` joined, scanned (the former code)."""
    turns, segment = [], []
    for m, (a, b) in enumerate(zip(moves.i0, moves.i1)):
        dt = t[a:b] - t[a - 1:b - 1]
        turn = 0.5 * (rate[a - 1:b - 1] + rate[a:b]) * dt[:, None]
        if step > 1:
            ends = np.arange(step - 1, b - a, step)
            turn = np.diff(np.vstack([np.zeros(3), np.cumsum(turn, axis=0)[ends]]), axis=0)
        turns.append(turn)
        segment.append(np.full(len(turn), m))
    q = Rotation.from_rotvec(np.concatenate(turns)).as_quat()
    return Rotation.from_quat(_plain_segmented_scan(q, np.concatenate(segment)))


def _moves(n=6000, seed=0):
    """Jittered sample times, a wandering rate and moves of uneven lengths between holds."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(0.0025 + 1e-5 * rng.standard_normal(n))
    rate = np.cumsum(rng.standard_normal((n, 3)), axis=0) * 0.01
    lengths = [1, 2, 7, 64, 129, 700, 1500, 3]
    i0, start = [], 50
    for length in lengths:
        i0.append(start)
        start += length + 40 + int(rng.integers(0, 30))
    i0 = np.array(i0)
    i1 = i0 + np.array(lengths)
    moves = Moves(i0, i1, np.arange(len(i0)), 10 + 2 * np.arange(len(i0)))
    return t, rate, moves


def test_segmented_scan_on_slices_is_the_scan_by_gathers():
    rng = np.random.default_rng(1)
    for sizes in ([1], [5], [1, 1, 1], [3, 1, 64, 65, 200, 2], [1000, 1, 17]):
        segment = np.repeat(np.arange(len(sizes)), sizes)
        q = Rotation.from_rotvec(rng.standard_normal((len(segment), 3)) * 0.3).as_quat()
        given = q.copy()
        got = prefix_products(q, segment)
        assert np.array_equal(got, _plain_segmented_scan(given, segment))
        assert np.array_equal(q, given)            # the input is left as it was


def test_scan_on_slices_is_the_scan_by_whole_quaternion_products():
    rng = np.random.default_rng(5)
    for m in (1, 2, 3, 64, 1000):
        q = Rotation.from_rotvec(rng.standard_normal((m, 3)) * 0.3).as_quat()
        plain = q.copy()
        d = 1
        while d < m:
            plain[d:] = quat_multiply(plain[:-d], plain[d:])
            d *= 2
        given = np.asfortranarray(q)         # either memory order; left as it was
        assert np.array_equal(prefix_products(given), plain)
        assert np.array_equal(given, q)


@pytest.mark.parametrize("step", [1, 2, 3, 8])
def test_moves_integrated_through_the_plan_are_the_move_by_move_integral(step):
    t, rate, moves = _moves()
    got = relative_attitudes(rate, t, moves, step)
    assert np.array_equal(got.as_quat(), _plain_relative_attitudes(rate, t, moves, step).as_quat())
    index, _ = move_index(moves, step)
    assert len(got) == len(index)
    # the same moves again (the kept plan) and on other times (a new plan)
    assert np.array_equal(relative_attitudes(rate, t, moves, step).as_quat(), got.as_quat())
    # the plan's rows of the kept samples: the rate there is the rate at move_index's samples
    from apmcal.diagnosis.model.dynamics import _plan

    plan = _plan(moves, t, step)
    assert np.array_equal(np.take(rate[plan.rows], plan.kept, axis=0), rate[index])
    t2 = t * 1.01
    assert np.array_equal(relative_attitudes(rate, t2, moves, step).as_quat(),
                          _plain_relative_attitudes(rate, t2, moves, step).as_quat())


def test_move_turns_gives_the_body_rate_of_every_row_it_reads():
    t, rate, moves = _moves(seed=2)

    class _Session:
        pass

    s = _Session()
    s.t = t
    forward = np.array([[1.02, 0.01, -0.004], [0.003, 0.99, 0.02], [-0.01, 0.005, 1.01]])
    body, rel = move_turns(s, forward, moves, rate, 2)
    rows = moves.rows()
    plain = rate[rows] @ np.linalg.inv(forward).T
    assert np.array_equal(body[rows], plain)
    outside = np.ones(len(t), bool)
    outside[rows] = False
    assert np.all(np.isnan(body[outside]))
    whole = np.full_like(rate, np.nan)
    whole[rows] = plain
    assert np.array_equal(rel.as_quat(),
                          _plain_relative_attitudes(whole, t, moves, 2).as_quat())


ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "gap.bin"      # sitl, 100 Hz, with temperature and a compass


@pytest.mark.parametrize("effects, terms_in_moves, size", [
    (("gyro_scale", "time_offset", "cross_axis", "scale_nonlinearity"), False, 10),
    (("gyro_scale", "time_offset", "cross_axis", "scale_nonlinearity"), True, 16),
    (("time_offset", "scale_nonlinearity"), True, 4)])
def test_the_move_fits_analytic_jacobian_is_the_derivative_of_its_residuals(
        monkeypatch, effects, terms_in_moves, size):
    """fit_dynamics hands least_squares the analytic Jacobian (move_jacobian): at the start
    and at a point off it (a time offset, other gyro matrices and accelerometer terms), every
    column is the central difference of the very residual function it fits, to 1e-7 of the
    column's size — gyro scale and misalignment, delay and, when the holds leave them to the
    moves, the accelerometer's non-orthogonality and quadratic scale."""
    from apmcal.calibration.log import Options
    from apmcal.diagnosis.model import dynamics, nominal
    from apmcal.diagnosis.scoring.evaluate import Evaluator
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    if terms_in_moves:
        monkeypatch.setattr(nominal, "acc_terms_in_moves", lambda *args: True)
    captured = []
    solve = dynamics.least_squares

    def spy(fun, x0, jac=None, **kw):
        captured.append((fun, jac, x0, kw["bounds"]))
        return solve(fun, x0, jac=jac, **kw)

    monkeypatch.setattr(dynamics, "least_squares", spy)
    session = session_from_log(read_log(SAMPLE), Options(lat_deg=5.6037, lon_deg=-0.187))
    # the compass on the IMU's own times, so that the moves fit it too (its rows checked)
    assert len(session.mag.t) == len(session.t)
    session.mag.t = session.t
    ev = Evaluator(session)
    ev._model(session, ev.reduced, frozenset(effects), 0, None, False)
    fun, jac, x0, (low, high) = captured[0]
    assert len(x0) == size
    moves = dynamics.Moves.of(session, session.pieces.select(fold=0))
    step = max(1, int(round(session.fs / dynamics.FIT_RATE_HZ)))
    kept = len(dynamics.move_index(moves, step)[0])
    assert len(fun(x0)) == 6 * kept + len(x0)          # accelerometer, compass, priors
    rng = np.random.default_rng(3)
    away = np.clip(x0 + 3e-3 * rng.standard_normal(len(x0)), 0.9 * low, 0.9 * high)
    for x in (x0, away):
        got = jac(x)
        plain = np.empty_like(got)
        for c in range(len(x)):
            e = np.zeros(len(x))
            e[c] = 1e-6
            plain[:, c] = (fun(x + e) - fun(x - e)) / 2e-6
        size = np.abs(plain).max(axis=0)
        assert np.all(size > 0)
        assert np.all(np.abs(got - plain).max(axis=0) <= 1e-7 * size)


def test_turns_kept_for_the_same_rates_are_the_turns_made_anew():
    """predicted hands back the turns kept for the same gyro matrix and rates (value for value),
    and makes new ones for other rates or another matrix: the predictions are those of a fresh
    integration either way."""
    from apmcal.diagnosis.model import dynamics

    t, rate, moves = _moves(seed=4)
    plan = dynamics._plan(moves, t, 1)
    assert dynamics._plan(Moves(moves.i0.copy(), moves.i1.copy(), moves.hold.copy(),
                                moves.piece), t, 1) is plan      # same moves, same times
    assert dynamics._plan(moves, t.copy(), 1) is not plan       # other times
    forward = np.diag([1.01, 0.98, 1.0])
    rows = np.take(rate, plan.rows, axis=0)
    first = dynamics._known_turns(plan, forward, rows)
    again = dynamics._known_turns(plan, forward, rows.copy())
    assert again is first
    other = rows.copy()
    other[5, 1] += 1e-12
    for turns, (f, r) in ((dynamics._known_turns(plan, forward, other), (forward, other)),
                          (dynamics._known_turns(plan, np.eye(3), rows), (np.eye(3), rows))):
        assert turns is not first
        fresh = dynamics._turns(plan, f, r)
        assert np.array_equal(turns[0], fresh[0])
        assert np.array_equal(turns[1].as_quat(), fresh[1].as_quat())
