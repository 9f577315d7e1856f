"""Results kept by the content of their inputs (apmcal.diagnosis.compute.memo): the very result the
function returns, never a stale one, and the entries forked workers make come back."""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.diagnosis.compute import memo, workers
from apmcal.diagnosis.model.blocks import Blocks
from apmcal.diagnosis.model.static_fit import _fit_geometry, fit_geometry

RNG = np.random.default_rng(20261124)
_TEST_MEMO = memo.ContentMemo("test_diagnosis_memo", 3)


def test_digest_tells_contents_dtype_and_shape_apart():
    a = np.arange(6.0)
    same = memo.digest(a, {"k": [1, 2.0, None]}, "acc", True)
    assert same == memo.digest(a.copy(), {"k": [1, 2.0, None]}, "acc", True)
    others = [memo.digest(a.reshape(2, 3)), memo.digest(a.astype(np.float32)),
              memo.digest(np.nextafter(a, 7)), memo.digest(a[::-1]), memo.digest(a)]
    assert len(set(others)) == len(others)
    assert memo.digest((1, 2)) != memo.digest((12,)) != memo.digest("12")
    assert memo.digest(np.asfortranarray(np.eye(3) + np.arange(3))) == \
        memo.digest(np.ascontiguousarray(np.eye(3) + np.arange(3)))


def test_digest_refuses_what_it_cannot_hash():
    with pytest.raises(TypeError, match="object"):
        memo.digest(object())


def test_memo_gives_copies_and_forgets_the_oldest():
    value = {"x": np.zeros(3)}
    _TEST_MEMO.put(b"a", value)
    value["x"][0] = 1.0                         # the caller's object is not the stored one
    got = _TEST_MEMO.get(b"a")
    assert got["x"][0] == 0.0
    got["x"][1] = 5.0                           # nor is what a caller gets back
    assert _TEST_MEMO.get(b"a")["x"][1] == 0.0
    for key in (b"b", b"c", b"d"):              # size 3: "a" is the least recently used
        _TEST_MEMO.put(key, key)
    assert _TEST_MEMO.get(b"a") is None and _TEST_MEMO.get(b"d") == b"d"


def _hold_blocks(offset, scale, n_groups=8, per_group=5):
    """Block means of a tilted accelerometer in ``n_groups`` orientations."""
    u = RNG.standard_normal((n_groups, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    group = np.repeat(np.arange(n_groups), per_group)
    values = offset + scale * 9.80665 * u[group] + 1e-3 * RNG.standard_normal((len(group), 3))
    return Blocks(values, np.arange(len(group), dtype=float), np.full(len(group), 40),
                  np.arange(len(group)), group)


def test_a_kept_geometric_fit_is_the_fit_itself():
    blocks = _hold_blocks(np.array([0.1, -0.2, 0.3]), np.array([1.01, 0.99, 1.02]))
    columns = np.zeros((len(blocks.t), 0))
    direct = _fit_geometry(blocks, columns, 9.80665, "acc", False, False, None, True, None)
    first = fit_geometry(blocks, columns, 9.80665)
    first.offset[0] = 99.0                      # a caller changing its copy ...
    kept = fit_geometry(blocks, columns, 9.80665)
    for fit in (first, kept):
        assert np.array_equal(fit.forward, direct.forward)
        assert fit.params == direct.params and fit.sigma == direct.sigma
    assert np.array_equal(kept.offset, direct.offset)   # ... changes nothing kept
    # other inputs, another fit: one block's mean moved by one unit in the last place
    moved = Blocks(blocks.values.copy(), blocks.t, blocks.count, blocks.piece, blocks.group)
    moved.values[0, 0] = np.nextafter(moved.values[0, 0], 1.0)
    other = fit_geometry(moved, columns, 9.80665)
    assert np.array_equal(other.vector, _fit_geometry(moved, columns, 9.80665, "acc", False,
                                                      False, None, True, None).vector)


class _Squares:
    """A worker job that stores its result in a memo."""

    def square(self, x: int) -> int:
        _TEST_MEMO.put(memo.digest("square", x), x * x)
        return x * x


def test_entries_made_in_forked_workers_come_back():
    if not workers.parallel():
        pytest.skip("one core: no forked workers on this machine")
    assert workers.run(_Squares(), [("square", (7,)), ("square", (8,))]) == [49, 64]
    assert _TEST_MEMO.get(memo.digest("square", 7)) == 49
    assert _TEST_MEMO.get(memo.digest("square", 8)) == 64



def test_noise_effects_leave_the_fit_of_the_real_data_as_it_is():
    """The premise of Evaluator._real_model: a model that adds only effects of the noise fits
    the real data exactly as the model without them (fit, hold and move residuals)."""
    from pathlib import Path

    from apmcal.calibration.log import Options
    from apmcal.diagnosis.scoring.evaluate import NOISE_ONLY, Evaluator
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    log = Path(__file__).resolve().parents[1] / "logs" / "gap.bin"
    session = session_from_log(read_log(log), Options(lat_deg=5.6037, lon_deg=-0.187))
    ev = Evaluator(session)

    def plain(effects):
        fit, holds, moves = ev._model(session, ev.reduced, frozenset(effects), 0, None, True)
        return fit, [c.block.values for c in holds + moves]

    for base in ((), ("temperature_drift",)):
        fit, residuals = plain(base)
        for noise_effect in sorted(NOISE_ONLY):
            other, other_residuals = plain(base + (noise_effect,))
            assert np.array_equal(other.acc.vector, fit.acc.vector), noise_effect
            assert np.array_equal(other.gyr.offset, fit.gyr.offset), noise_effect
            assert np.array_equal(other.mag.vector, fit.mag.vector), noise_effect
            for name in ("gyro_scale", "gyro_gamma", "time_offset_s"):
                assert np.array_equal(getattr(other.dynamics, name),
                                      getattr(fit.dynamics, name)), (noise_effect, name)
            assert all(np.array_equal(a, b) for a, b in zip(other_residuals, residuals))
    # and what the evaluator hands out carries the effects asked for
    fit, _, _ = ev.fit(session, ev.reduced, {"uniform_noise"}, 0)
    assert fit.effects == frozenset({"uniform_noise"})
