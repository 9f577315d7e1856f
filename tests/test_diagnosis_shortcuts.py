"""Shortcuts ``apmcal gap`` takes for speed give exactly what the plain computation gives: the
moves' rates computed on the moves only, the nominal model of the block means made in a worker
beside the nominal model, the χ² functions taken from scipy.special, and a start that leaves
the heavy packages to the stage that needs them."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from apmcal.diagnosis.compute import workers

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "gap.bin"      # sitl, 100 Hz, with temperature and a compass


@pytest.fixture(scope="module")
def evaluator():
    from apmcal.calibration.log import Options
    from apmcal.diagnosis.scoring.evaluate import Evaluator
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    session = session_from_log(read_log(SAMPLE), Options(lat_deg=5.6037, lon_deg=-0.187))
    return Evaluator(session)


def test_the_rate_of_the_move_rows_is_the_rate_of_every_sample_there(evaluator):
    """calibrated_rate and move_turns compute the moves' rows only: value for value what the
    whole session's arrays hold there, for bias terms of every kind (temperature, time,
    triangle) and a gyro matrix off the identity."""
    from apmcal.diagnosis.model.dynamics import Moves, gyro_forward, move_turns, relative_attitudes
    from apmcal.diagnosis.model.nominal import calibrated_rate

    s = evaluator.session
    effects = frozenset({"temperature_drift", "bias_drift", "triangle_drift"})
    fit, _, _ = evaluator._model(s, evaluator.reduced, effects, 0, None, False)
    moves = Moves.of(s)
    rows = moves.rows()
    assert len(moves) and 0 < len(rows) < len(s.t) / 2
    whole = calibrated_rate(s, fit)
    part = calibrated_rate(s, fit, rows)
    assert np.array_equal(part[rows], whole[rows])
    elsewhere = np.ones(len(s.t), bool)
    elsewhere[rows] = False
    assert np.all(np.isnan(part[elsewhere]))

    forward = gyro_forward([1.02, 0.99, 1.01], [0.01, -0.02, 0.005, 0.0, 0.015, -0.01])
    body_everywhere = whole @ np.linalg.inv(forward).T
    for step in (1, 2):
        rate, rel = move_turns(s, forward, moves, part, step)
        assert np.array_equal(rate[rows], body_everywhere[rows])
        plain = relative_attitudes(body_everywhere, s.t, moves, step)
        assert np.array_equal(rel.as_quat(), plain.as_quat())


def test_the_block_means_nominal_model_made_in_a_worker_is_the_one_made_here(evaluator):
    """apmcal.diagnosis.run scores the nominal model of the block means in a worker beside the
    recorded rate's: its summary and warm state are those prefetch would have made."""
    from apmcal.diagnosis.scoring.evaluate import FOLDS, Evaluator
    from apmcal.diagnosis.session.decimate import decimated

    s = evaluator.session
    # a 50 Hz decimation stands in for the block means of a faster recording
    evaluator.__dict__["slow"] = Evaluator(decimated(s, 2), evaluator.seed)
    there = Evaluator(decimated(s, 2), evaluator.seed)
    there.keep_nominal_folds(workers.run(evaluator, [("_slow_nominal_fold", (fold,))
                                                     for fold in FOLDS]))
    here = Evaluator(decimated(s, 2), evaluator.seed)
    here.prefetch([()])
    assert there.summary(()) == here.summary(())
    assert not there._cold() and set(there._motion) == set(here._motion)
    del evaluator.__dict__["slow"]


def test_the_chi2_functions_are_scipy_stats_own():
    from apmcal.diagnosis.model.wald import wald_p_value
    from apmcal.diagnosis.noise.allan import _chi2_ppf

    edf = np.array([0.7, 1.0, 2.5, 17.0, 380.0, 12345.6])
    for q in (0.025, 0.5, 0.975):
        assert np.array_equal(_chi2_ppf(q, edf), stats.chi2.ppf(q, edf))
    params = {"vertical": {"value": [3e-5], "sigma": [1e-5]},
              "horizontal": {"value": [-1e-5], "sigma": [2e-5]}}
    assert wald_p_value("earth_rate", params) == stats.chi2.sf(9.0 + 0.25, 2)


def test_the_diagnosis_starts_without_pandas_scipy_stats_or_scipy_signal():
    """The log is read in a worker (pandas) while the main process imports the diagnosis; the
    candidates' packages are imported beside the nominal model. A module that imports one of
    them at its top puts its import time (0.3-0.8 s each) back on every start."""
    code = ("import sys, apmcal.cli, apmcal.cli.gap, apmcal.diagnosis.run; "
            "print(sorted(m for m in ('pandas', 'scipy.stats', 'scipy.signal', 'filterpy', "
            "'allantools') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, check=True)
    assert done.stdout.strip() == "[]"


def _hold_block(rng, pieces=10, length=500, dof=1):
    """Still-hold residuals of ten pieces of 500 samples (100 Hz), session-wide ids 0, 2, ..."""
    from apmcal.diagnosis.scoring.gap import ResidualBlock

    n = pieces * length
    i0 = np.arange(pieces) * length
    return ResidualBlock(["acc_x", "acc_y", "acc_z"], rng.standard_normal((n, 3)), i0,
                         i0 + length - 20, 2 * np.arange(pieces), np.arange(n) / 100.0, None,
                         mean_dof=dof)


def test_a_block_of_the_same_values_gets_the_same_coefficients_and_cells():
    """apmcal.diagnosis.compute.reuse hands back kept results only for the same numbers: one changed
    bit, or another scoring of the piece means, and they are worked out afresh."""
    from dataclasses import replace

    from apmcal.diagnosis.compute import reuse
    from apmcal.diagnosis.scoring.gap import coefficients, compare
    from apmcal.diagnosis.scoring.haar import details

    rng = np.random.default_rng(20261124)
    real, twin = _hold_block(rng), _hold_block(rng)
    first = coefficients([real])[0]
    again = coefficients([replace(real, values=real.values.copy())])[0]
    assert again.levels is first.levels and again.means is first.means
    reuse.forget()                      # a new session: nothing kept
    assert coefficients([real])[0].levels is not first.levels
    first = coefficients([real])[0]
    changed = real.values.copy()
    changed[2000, 1] = np.nextafter(changed[2000, 1], np.inf)
    other = coefficients([replace(real, values=changed)])[0]
    assert other.levels is not first.levels
    fresh = details(changed, real.i0, real.i1)
    assert all(np.array_equal(a.values, b.values) for a, b in zip(other.levels, fresh))

    tw = coefficients([twin])[0]
    keep = np.array([0, 4, 6, 8, 12, 14, 18])
    gap = compare([first], [tw], keep, in_sample=True)
    copy = replace(real, values=real.values.copy(), t=real.t + 0.0)
    reused = compare(coefficients([copy]), coefficients([replace(twin)]), keep, in_sample=True)
    assert [c.total for c in reused.cells] == [c.total for c in gap.cells]
    assert all(c.block is copy for c in reused.cells)          # the new block's, for its times
    more_dof = compare(coefficients([replace(copy, mean_dof=2)]), [tw], keep, in_sample=True)
    means = [c for c in more_dof.cells if c.level == 0]
    assert means and means[0].total != [c for c in gap.cells if c.level == 0][0].total


def test_an_effect_of_the_gyro_leaves_the_other_sensors_hold_residuals_as_they_were(evaluator):
    """The premise of apmcal.diagnosis.compute.reuse: after the nominal model, a gyro-only effect's
    accelerometer and compass hold coefficients, real and twin, are the nominal model's own
    objects (found equal, so not worked out again); the gyro's are new."""
    nominal = evaluator._fold(frozenset(), 0)
    gyro_only = evaluator._fold(frozenset({"g_sensitivity"}), 0)
    for side in ("real", "twin"):
        was = {c.block.names[0]: c for c in getattr(nominal, side) if c.block.shape}
        now = {c.block.names[0]: c for c in getattr(gyro_only, side) if c.block.shape}
        assert now["acc_x"].levels is was["acc_x"].levels, side
        assert now["mag_x"].levels is was["mag_x"].levels, side
        assert now["gyr_x"].levels is not was["gyr_x"].levels, side


def test_statistics_of_kept_coefficients_are_kept_with_them():
    """reuse.derived: the same coefficient objects and pieces give the kept statistic; other
    pieces, or the same values under other piece ids, are worked out afresh."""
    from dataclasses import replace

    from apmcal.diagnosis.compute import reuse
    from apmcal.diagnosis.noise.fit import level_stats
    from apmcal.diagnosis.scoring.gap import coefficients

    block = _hold_block(np.random.default_rng(7))
    coeffs = coefficients([block])[0]
    calls = []

    def stats(c, pieces):
        calls.append(pieces.tobytes())
        return level_stats(c, pieces)

    train = np.array([0, 2, 4, 6])
    first = reuse.derived(coeffs, "levels", train, lambda: stats(coeffs, train))
    same = coefficients([replace(block, values=block.values.copy())])[0]
    assert reuse.derived(same, "levels", train.copy(), lambda: stats(same, train)) is first
    assert len(calls) == 1
    other = np.array([8, 10])
    v, n = reuse.derived(coeffs, "levels", other, lambda: stats(coeffs, other))
    assert len(calls) == 2 and np.array_equal(v, level_stats(coeffs, other)[0])
    renumbered = coefficients([replace(block, piece=block.piece[::-1].copy())])[0]
    reuse.derived(renumbered, "levels", train, lambda: stats(renumbered, train))
    assert len(calls) == 3


def test_the_vectors_carried_along_a_path_are_the_plain_ones(evaluator):
    """twin._carried keeps recent results for the very path objects and equal vectors: the same
    numbers as trajectory.carried, read-only (shared by twins), and worked out afresh for other
    vectors."""
    from apmcal.diagnosis.session import trajectory
    from apmcal.diagnosis.twin.simulate import _carried

    hold_rot, traj = evaluator._motion_path(0)
    vectors = np.random.default_rng(3).standard_normal((len(evaluator.session.holds), 3))
    first = _carried(traj, hold_rot, vectors, True)
    assert np.array_equal(first, trajectory.carried(traj, hold_rot, vectors, True))
    assert not first.flags.writeable
    assert _carried(traj, hold_rot, vectors.copy(), True) is first
    moved = vectors.copy()
    moved[0, 0] += 1e-12
    other = _carried(traj, hold_rot, moved, True)
    assert other is not first
    assert np.array_equal(other, trajectory.carried(traj, hold_rot, moved, True))


def test_the_compass_to_imu_index_is_found_once_per_pair_of_time_axes():
    from apmcal.diagnosis.twin.simulate import _imu_index

    t_imu = np.arange(1000) / 400.0
    t_mag = np.arange(-3, 260) / 100.0 + 0.0013
    first = _imu_index(t_imu, t_mag)
    assert np.array_equal(first, np.clip(np.searchsorted(t_imu, t_mag), 0, 999))
    assert _imu_index(t_imu, t_mag) is first and not first.flags.writeable
    assert _imu_index(t_imu, t_mag.copy()) is not first     # other arrays: found again
