"""Shortcuts that make ``apmcal gap`` faster give exactly what the plain computation gives: an
evaluator's session facts found on first use, a session's rate found once per time axis, and a
cold evaluator's models spread over one worker per fold (how the null sessions are scored)."""
from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from apmcal.diagnosis.compute import workers

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "gap.bin"      # sitl, 100 Hz, with temperature and a compass


@pytest.fixture(scope="module")
def session():
    from apmcal.calibration.log import Options
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    return session_from_log(read_log(SAMPLE), Options(lat_deg=5.6037, lon_deg=-0.187))


def test_an_evaluator_finds_the_session_facts_on_first_use_and_as_before(session):
    from apmcal.diagnosis.model.dynamics import Moves
    from apmcal.diagnosis.model.nominal import reduce_session
    from apmcal.diagnosis.scoring.evaluate import Evaluator
    from apmcal.diagnosis.session.facts import (
        earth_field,
        lattice_steps,
        sample_sigma,
        variance_floors,
    )

    ev = Evaluator(session)
    assert not {"reduced", "steps", "floors", "sample_sigma", "move_rows"} & set(vars(ev))
    ev.facts()
    assert {"reduced", "steps", "floors", "sample_sigma", "move_rows"} <= set(vars(ev))
    steps = lattice_steps(session)
    assert ev.steps.keys() == steps.keys()
    for sensor, step in steps.items():
        assert (ev.steps[sensor] is None) == (step is None)
        assert step is None or np.array_equal(ev.steps[sensor], step)
    assert ev.floors == variance_floors(session, steps)
    assert ev.sample_sigma == sample_sigma(session)
    assert (ev.field_mgauss, ev.declination_rad) == earth_field(session)
    assert np.array_equal(ev.move_rows, Moves.of(session).rows())
    reduced = reduce_session(session)
    for sensor in ("acc", "gyr", "mag"):
        assert np.array_equal(getattr(ev.reduced, sensor).values,
                              getattr(reduced, sensor).values)
    assert ev.fs_of["acc"] == ev.fs_of["gyr"] == session.fs


def test_a_session_finds_its_rate_anew_for_another_time_axis(session):
    s = replace(session)
    assert s.fs == pytest.approx(float(1.0 / np.median(np.diff(session.t))))
    slower = replace(s, t=s.t[0] + 2.0 * (s.t - s.t[0]))
    assert slower.fs == pytest.approx(s.fs / 2)
    s.t = slower.t
    assert s.fs == slower.fs


def test_one_worker_per_fold_gives_the_summaries_made_in_one_process(session, monkeypatch):
    """A cold evaluator's models on one worker per fold (each fits its fold's nominal model,
    then that fold of every model): the summaries, the parameters and the state kept
    afterwards are those of the plain computation in one process."""
    from apmcal.diagnosis.scoring.evaluate import Evaluator
    from apmcal.diagnosis.session.decimate import decimated

    small = decimated(session, 2)       # 50 Hz: quicker, the same code
    models = [(), ("temperature_drift",), ("gyro_scale",), ("bias_random_walk",)]
    by_fold = Evaluator(small, 3)
    by_fold._prefetch_by_fold([frozenset(m) for m in models[1:]])
    with monkeypatch.context() as m:
        m.setattr(workers, "parallel", lambda: False)
        plain = Evaluator(small, 3)
        plain.prefetch(models)
    for model in models:       # value for value (a NaN σ equals a NaN σ)
        np.testing.assert_equal(asdict(by_fold.summary(model)), asdict(plain.summary(model)),
                                err_msg=str(model))
    assert not by_fold._cold() and set(by_fold._motion) == set(plain._motion)


def test_several_cold_evaluators_at_once_give_the_summaries_of_each_alone(session, monkeypatch):
    """prefetch_cold (the first null sessions fitted in one pair of workers, one fold each,
    evaluator after evaluator) against each evaluator prefetched alone in one process."""
    from apmcal.diagnosis.scoring.evaluate import Evaluator, prefetch_cold
    from apmcal.diagnosis.session.decimate import decimated

    small = decimated(session, 2)
    work = [[(), ("temperature_drift",)], [(), ("bias_drift",), ("gyro_scale",)]]
    monkeypatch.setattr(workers, "parallel", lambda: True)     # as on a two-core machine,
    monkeypatch.setattr("os.cpu_count", lambda: 2)             # whatever this one has
    lanes = []
    run_lanes = workers.run_lanes
    monkeypatch.setattr(workers, "run_lanes",
                        lambda target, jobs: lanes.append(jobs) or run_lanes(target, jobs))
    together = [Evaluator(small, seed) for seed in (3, 4)]
    prefetch_cold(list(zip(together, work)))
    assert len(lanes) == 1 and len(lanes[0]) == 2       # one pair of workers for both
    monkeypatch.setattr(workers, "parallel", lambda: False)
    for seed, ev, models in zip((3, 4), together, work):
        alone = Evaluator(small, seed)
        alone.prefetch(models)
        assert not ev._cold()
        for model in models:
            np.testing.assert_equal(asdict(ev.summary(model)), asdict(alone.summary(model)),
                                    err_msg=str(model))


def test_workers_kept_per_fold_give_the_summaries_made_in_one_process(session, monkeypatch):
    """Evaluator.workers_kept: each fold's jobs in one worker forked once for many calls
    (workers.per_fold), against the plain computation in one process."""
    from apmcal.diagnosis.scoring.evaluate import Evaluator
    from apmcal.diagnosis.session.decimate import decimated

    small = decimated(session, 2)
    first, then = [(), ("temperature_drift",)], [("bias_drift",), ("gyro_scale",)]
    monkeypatch.setattr(workers, "parallel", lambda: True)
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    calls = []
    run = workers.FoldWorkers.run
    monkeypatch.setattr(workers.FoldWorkers, "run",
                        lambda self, jobs, fold_of: calls.append(jobs) or run(self, jobs, fold_of))
    kept = Evaluator(small, 3)
    kept.prefetch(first)
    with kept.workers_kept():
        kept.prefetch(then[:1])         # two calls: the same two workers serve both
        kept.prefetch(then[1:])
    assert len(calls) == 2 and kept._kept is None
    monkeypatch.setattr(workers, "parallel", lambda: False)
    plain = Evaluator(small, 3)
    plain.prefetch(first + then)
    for model in first + then:
        np.testing.assert_equal(asdict(kept.summary(model)), asdict(plain.summary(model)),
                                err_msg=str(model))


def test_null_sessions_drawn_in_the_kept_workers_give_the_summaries_made_here(session,
                                                                             monkeypatch):
    """Evaluator.prefetch_nulls: each kept worker draws the null session itself and fits its
    fold; the summaries are those of the same session drawn and fitted in one process."""
    from apmcal.diagnosis.scoring.evaluate import Evaluator
    from apmcal.diagnosis.session.decimate import decimated

    small = decimated(session, 2)
    models = [(), ("temperature_drift",)]
    monkeypatch.setattr(workers, "parallel", lambda: True)
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    source = Evaluator(small, 3)
    source.prefetch([()])
    drawn = {(effects, k): Evaluator(source.model_draw(effects, k), 3)
             for effects in ((), ("bias_drift",)) for k in (0, 1)}
    with source.workers_kept():
        assert source.kept
        source.prefetch_nulls([(effects, k, null, models) for (effects, k), null in drawn.items()])
    monkeypatch.setattr(workers, "parallel", lambda: False)
    for (effects, k), null in drawn.items():
        assert null._cold()             # fitted in the workers, kept here as summaries
        here = Evaluator(source.model_draw(effects, k), 3)
        here.prefetch(models)
        for model in models:
            np.testing.assert_equal(asdict(null.summary(model)), asdict(here.summary(model)),
                                    err_msg=f"{effects} {k} {model}")
