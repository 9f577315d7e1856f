"""The two-rate diagnosis: slow effects scored on block means, fine effects at the recorded rate."""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.diagnosis.session.decimate import FINE_EFFECTS, block_factor, block_means, decimated
from apmcal.diagnosis.session.log import MagAxis, Session, cut_session
from apmcal.preprocessing.static import find_static_segments


def test_block_factor_is_a_power_of_two_down_to_the_slow_rate():
    assert block_factor(50.0) == 1
    assert block_factor(100.0) == 1
    assert block_factor(200.0) == 2
    assert block_factor(400.0) == 4
    assert block_factor(1000.0) == 8        # 125 Hz: the next halving would be below 100 Hz


def test_block_means_drop_a_trailing_partial_block():
    x = np.arange(10.0).reshape(5, 2)
    np.testing.assert_allclose(block_means(x, 2), [[1.0, 2.0], [5.0, 6.0]])
    assert block_means(None, 2) is None


def _session(fs: float = 400.0) -> Session:
    """Two still poses joined by a turn, with a compass on the IMU's own time axis."""
    rng = np.random.default_rng(3)
    n_hold, n_move = int(20 * fs), int(2 * fs)
    t = np.arange(2 * n_hold + n_move) / fs
    acc = np.zeros((len(t), 3))
    acc[:n_hold, 2] = 9.8
    acc[n_hold + n_move:, 0] = 9.8
    turn = np.linspace(0, np.pi / 2, n_move)
    acc[n_hold:n_hold + n_move] = np.c_[9.8 * np.sin(turn), np.zeros(n_move),
                                        9.8 * np.cos(turn)]
    gyr = np.zeros((len(t), 3))
    gyr[n_hold:n_hold + n_move, 1] = (np.pi / 2) / 2.0
    acc += rng.normal(0, 0.02, acc.shape)
    gyr += rng.normal(0, 0.002, gyr.shape)
    holds = find_static_segments(t, acc, gyr, min_duration=2.0)
    segments, pieces = cut_session(t, holds, acc)
    s = Session("made-up", t, acc, gyr, holds, segments, pieces,
                temp=np.linspace(20, 30, len(t)), integer_sensors=frozenset({"acc", "mag"}))
    s.mag = MagAxis(t, rng.normal(0, 1, (len(t), 3)) + 200.0, pieces.i0, pieces.i1)
    return s


def test_a_decimated_session_keeps_its_holds_pieces_and_folds():
    s = _session()
    c = decimated(s, 4)
    assert c.fs == pytest.approx(100.0)
    assert len(c.holds) == len(s.holds) and len(c.pieces) == len(s.pieces)
    np.testing.assert_array_equal(c.pieces.fold, s.pieces.fold)
    np.testing.assert_array_equal(c.pieces.is_hold, s.pieces.is_hold)
    # each piece shrinks to the blocks wholly inside it, losing less than a block at each end
    first, end = 4 * c.pieces.i0, 4 * c.pieces.i1        # the blocks' recorded samples
    assert np.all(first >= s.pieces.i0) and np.all(first - s.pieces.i0 < 4)
    assert np.all(end <= s.pieces.i1) and np.all(s.pieces.i1 - end < 4)
    # block means, sample for sample
    np.testing.assert_allclose(c.acc[7], s.acc[28:32].mean(axis=0))
    np.testing.assert_allclose(c.temp[7], s.temp[28:32].mean())
    assert c.integer_sensors == s.integer_sensors
    assert decimated(s, 1) is s


def test_block_means_of_rounded_readings_lie_on_the_step_over_the_block_length():
    """The twin's rounding then reproduces the block means' finer lattice."""
    from apmcal.diagnosis.session.facts import lattice_steps

    s = _session()
    step = 0.01
    s.acc = np.round(s.acc / step) * step
    s.mag.values = np.round(s.mag.values)       # 1 mGauss, as dataflash MAG stores it
    full, coarse = lattice_steps(s), lattice_steps(decimated(s, 4))
    np.testing.assert_allclose(full["acc"], step, rtol=1e-6)
    np.testing.assert_allclose(coarse["acc"], step / 4, rtol=1e-6)
    np.testing.assert_allclose(coarse["mag"], 0.25, rtol=1e-6)


def test_a_compass_on_its_own_time_axis_is_kept_and_remapped():
    s = _session()
    m_t = s.t[::8]
    s.mag = MagAxis(m_t, s.mag.values[::8], s.pieces.i0 // 8, s.pieces.i1 // 8)
    c = decimated(s, 4)
    assert c.mag.t is m_t
    np.testing.assert_array_equal(c.mag.values, s.mag.values)
    inside = (m_t[c.mag.i0] >= c.t[c.pieces.i0]) & (m_t[c.mag.i1 - 1] <= c.t[c.pieces.i1 - 1])
    assert inside.all()


def test_the_fine_effects_are_the_ones_block_means_erase():
    # rounding, a filter above the slow Nyquist rate, the noise distribution's shape
    assert set(FINE_EFFECTS) == {"quantization", "lowpass_filter", "uniform_noise"}


def test_a_fast_session_finds_a_slow_and_a_fine_effect_at_their_own_rates(tmp_path):
    """200 Hz: a temperature drift (scored on 100 Hz block means) and rounding (at 200 Hz),
    both withheld from the twin, are the two effects the selected combination needs most."""
    from apmcal.calibration.log import Options
    from apmcal.diagnosis.run import diagnose
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log
    from apmcal_sim.gap_benchmark import SITE, simulate_log

    path = tmp_path / "session.bin"
    withheld = ("temperature_drift", "quantization")
    simulate_log(withheld, 1, path, 200.0, 200.0)
    session = session_from_log(read_log(path), Options(lat_deg=SITE["lat"], lon_deg=SITE["lon"]))
    result = diagnose(session, seed=1).result
    assert set(result.selected[:2]) == set(withheld), result.selected
    assert result.effect("temperature_drift")["scored_at_hz"] == pytest.approx(100.0)
    assert result.effect("quantization")["scored_at_hz"] == pytest.approx(200.0)
    assert result.after["heldout"] < 0.5 * result.gap["heldout"]
