"""The gap diagnosis's significance calibrated under the null (apmcal.diagnosis.scoring.null).

- the p-value and threshold of a candidate's null draws, worked by hand with scipy.stats;
- clean sessions from a generator written apart from the simulator (tests/independent_sessions.py:
  exact continuous-time motion, its own noise code): at most 5 % claim an effect;
- the same generator with a gyro scale error injected: the diagnosis still finds it first.
"""
from __future__ import annotations

import independent_sessions
import numpy as np
import pytest
from scipy import stats

from apmcal.core.options import Options
from apmcal.diagnosis.run import diagnose
from apmcal.diagnosis.scoring.null import ALPHA, MIN_DRAWS, NullDraws
from apmcal.diagnosis.session.log import session_from_log
from apmcal.sources import read_log

CLEAN_SEEDS = range(100, 120)       # none of them looked at while the calibration was built


def test_p_value_is_the_predictive_t_tail():
    draws = NullDraws("cross_axis", [1.0, 2.0, 3.0, 4.0, 5.0], family=10)
    b, mean, sd = 5, 3.0, np.std([1, 2, 3, 4, 5], ddof=1)
    scale = sd * np.sqrt(1 + 1 / b)
    assert draws.p_value(12.0) == pytest.approx(stats.t.sf((12.0 - mean) / scale, b - 1),
                                                rel=1e-9)
    # the threshold is the evidence whose p-value is α / M
    threshold = draws.threshold()
    assert threshold == pytest.approx(mean + scale * stats.t.isf(ALPHA / 10, b - 1), rel=1e-9)
    assert draws.p_value(threshold) == pytest.approx(ALPHA / 10, rel=1e-6)
    # real evidence below one of the draws: never less than the draws' rank says (1 + 1) / 6
    assert draws.p_value(4.5) >= 2 / 6
    assert draws.p_value(np.nan) is None
    assert NullDraws("x", [3.0], 10).p_value(100.0) is None     # one draw: no spread


def test_draws_stop_when_the_decision_is_plain():
    few = NullDraws("x", list(np.linspace(1.0, 3.0, MIN_DRAWS - 1)), family=15)
    assert not few.decided(1e4)                     # fewer than MIN_DRAWS
    plain = NullDraws("x", list(np.linspace(-3, 3, MIN_DRAWS)), family=15)
    assert plain.decided(1e4) and plain.decided(-10.0)
    assert not plain.decided(plain.threshold())     # right at the threshold: draw on


def _diagnosed(tmp_path, seed: int, gyro_scale=None):
    path = independent_sessions.write_csv(tmp_path / f"clean_{seed}.csv", seed,
                                          gyro_scale=gyro_scale)
    session = session_from_log(read_log(path), Options())
    return diagnose(session, seed=seed).result


@pytest.mark.timeout(900)   # 20 diagnoses: about a minute on an idle two-core machine, far
                            # more while the rest of the suite shares the cores
def test_independent_clean_sessions_hold_the_false_alarm_rate(tmp_path):
    alarms = {}
    for seed in CLEAN_SEEDS:
        result = _diagnosed(tmp_path, seed)
        claimed = [e["name"] for e in result.effects if e["significant"]]
        if claimed:
            alarms[seed] = claimed
        for e in result.effects:        # every candidate the null had to judge got a p-value
            if e.get("null_sessions"):
                assert 0.0 <= e["null_p_value"] <= 1.0
    assert len(alarms) <= 0.05 * len(CLEAN_SEEDS), f"effects claimed on clean sessions: {alarms}"


def test_an_injected_gyro_scale_is_still_found(tmp_path):
    result = _diagnosed(tmp_path, 7, gyro_scale=[1.01, 0.99, 1.005])
    assert result.top == "gyro_scale"
    entry = result.effect("gyro_scale")
    assert entry["null_p_value"] < ALPHA / 10 and entry["null_sessions"] >= MIN_DRAWS
    scale = np.asarray(entry["params"]["scale"]["value"])
    assert np.allclose(scale, [1.01, 0.99, 1.005], atol=1e-3)


def test_nulls_drawn_on_first_need_decide_as_nulls_drawn_for_every_candidate(tmp_path,
                                                                              monkeypatch):
    """The lazy calibration (null.Calibration) against the eager one it replaces: every
    candidate supported alone calibrated before the selection starts."""
    from apmcal.diagnosis import run

    lazy = _diagnosed(tmp_path, 7, gyro_scale=[1.01, 0.99, 1.005])
    selection = run.forward_selection

    def eager(evaluator, ranked, **kwargs):
        for s in ranked:
            if s.supported:
                evaluator.chance.calibrated(s.name)
        return selection(evaluator, ranked, **kwargs)

    monkeypatch.setattr(run, "forward_selection", eager)
    every = _diagnosed(tmp_path, 7, gyro_scale=[1.01, 0.99, 1.005])
    assert lazy.selected == every.selected
    drawn = {e["name"]: e for e in every.effects}
    assert any(e["null_sessions"] for e in every.effects)
    for e in lazy.effects:
        other = drawn[e["name"]]
        assert e["significant"] == other["significant"], e["name"]
        if e["null_sessions"]:      # drawn lazily: the very draws the eager calibration made
            assert (e["null_sessions"], e["null_p_value"]) == \
                (other["null_sessions"], other["null_p_value"]), e["name"]
        else:
            assert other["null_sessions"] == 0 or not e["significant"]


def test_an_effect_refused_on_top_of_the_selection_is_not_significant():
    from apmcal.diagnosis.scoring.select import Selection

    selection = Selection(["bias_random_walk"], {"bias_random_walk": 900.0},
                          beyond={"triangle_drift": 40.0}, chance={"triangle_drift": 0.2})
    assert not selection.significant("triangle_drift")      # 40 nats, but chance gives as much
    assert Selection(["bias_random_walk"], {"bias_random_walk": 900.0},
                     beyond={"triangle_drift": 40.0}).significant("triangle_drift")
