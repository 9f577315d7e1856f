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

from apmcal.diagnosis import workers

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "gap.bin"      # sitl, 100 Hz, with temperature and a compass


@pytest.fixture(scope="module")
def evaluator():
    from apmcal.diagnosis.evaluate import Evaluator
    from apmcal.diagnosis.session import session_from_log
    from apmcal.pipeline import Options
    from apmcal.sources import read_log

    session = session_from_log(read_log(SAMPLE), Options(lat_deg=5.6037, lon_deg=-0.187))
    return Evaluator(session)


def test_the_rate_of_the_move_rows_is_the_rate_of_every_sample_there(evaluator):
    """calibrated_rate and move_turns compute the moves' rows only: value for value what the
    whole session's arrays hold there, for bias terms of every kind (temperature, time,
    triangle) and a gyro matrix off the identity."""
    from apmcal.diagnosis.dynamics import Moves, gyro_forward, move_turns, relative_attitudes
    from apmcal.diagnosis.model import calibrated_rate

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
    from apmcal.diagnosis.decimate import decimated
    from apmcal.diagnosis.evaluate import FOLDS, Evaluator

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
    from apmcal.diagnosis.allan import _chi2_ppf
    from apmcal.diagnosis.wald import wald_p_value

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
    code = ("import sys, apmcal.cli, apmcal.diagnosis.cli, apmcal.diagnosis.run; "
            "print(sorted(m for m in ('pandas', 'scipy.stats', 'scipy.signal', 'filterpy', "
            "'allantools') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, check=True)
    assert done.stdout.strip() == "[]"
