"""The twin's noise terms: the wavelet-variance formulas against simulation, and their fit."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from apmcal.diagnosis.noise.fit import MeanPairs, fit_channels, lattice_step, lowpass_gain, random_walk_gain
from apmcal.diagnosis.scoring.gap import ResidualBlock
from apmcal.diagnosis.scoring.haar import details

RNG = np.random.default_rng(7)
FS = 100.0


def level_variances(x: np.ndarray, pieces: int = 1) -> np.ndarray:
    n = len(x) // pieces
    i0 = np.arange(pieces) * n
    return np.array([np.mean(c.values ** 2) for c in details(x[:, None], i0, i0 + n)])


def test_random_walk_haar_variance_is_dt_2m2_plus_1_over_6():
    """Derived in noise_fit: var d_j = q²Δt(2m² + 1)/6 for a discrete random walk."""
    q, runs = 3e-3, 400
    walk = np.cumsum(RNG.standard_normal((runs, 4096)) * q / np.sqrt(FS), axis=1)
    sim = np.mean([level_variances(w)[:8] for w in walk], axis=0)
    np.testing.assert_allclose(sim, q ** 2 * random_walk_gain(8, FS), rtol=0.08)


def test_lowpass_gain_matches_filtered_white_noise():
    b, a = butter(2, 12.0 / (FS / 2))
    x = lfilter(b, a, RNG.standard_normal(2 ** 20))
    np.testing.assert_allclose(level_variances(x)[:8], lowpass_gain(8, FS, 12.0)[:8], rtol=0.03)
    np.testing.assert_allclose(lowpass_gain(6, FS, None), 1.0, rtol=1e-3)


def test_mean_pair_variance_of_a_random_walk_plus_white_noise():
    """σ²(1/n_a + 1/n_b) + q²(L_a/3 + L_b/3 + G) for pieces of 10 s, 6 s apart."""
    q, sigma, runs = 2e-3, 0.05, 3000
    n, gap = 1000, 600
    total = 2 * n + gap
    x = (np.cumsum(RNG.standard_normal((runs, total)) * q / np.sqrt(FS), axis=1)
         + sigma * RNG.standard_normal((runs, total)))
    d = x[:, n + gap:].mean(axis=1) - x[:, :n].mean(axis=1)
    t = np.arange(total) / FS
    block = ResidualBlock(["g_x"], x[0][:, None], np.array([0, n + gap]),
                          np.array([n, total]), np.array([0, 1]), t)
    pairs = MeanPairs.of(block, np.array([0, 1]))
    assert pairs is None                     # fewer than three pieces: nothing to pair
    i0 = np.array([0, n + gap, 2 * (n + gap)])
    block = ResidualBlock(["g_x"], np.zeros((3 * (n + gap), 1)), i0, i0 + n, np.arange(3),
                          np.arange(3 * (n + gap)) / FS)
    pairs = MeanPairs.of(block, np.arange(3))
    want = sigma ** 2 * pairs.white[0] + q ** 2 * pairs.walk[0]
    assert np.mean(d ** 2) == pytest.approx(want, rel=0.08)


def test_fit_recovers_white_noise_and_random_walk_from_levels():
    sigma, q, levels = 1.2e-3, 2e-5, 11
    n = 50_000 / 2.0 ** np.arange(levels)
    v = sigma ** 2 + q ** 2 * random_walk_gain(levels, FS)
    s, qq, _ = fit_channels(np.column_stack([v] * 3), n, FS, cutoff_hz=None, random_walk=True,
                            floor=np.full(3, sigma ** 2))
    np.testing.assert_allclose(s, sigma, rtol=1e-3)
    np.testing.assert_allclose(qq, q, rtol=1e-3)
    s, qq, _ = fit_channels(np.column_stack([v] * 3), n, FS, cutoff_hz=None,
                            floor=np.full(3, sigma ** 2))
    assert qq is None
    np.testing.assert_allclose(s, sigma, rtol=1e-9)    # nominal: the high-frequency floor


def test_fit_with_rounding_survives_a_pair_of_equal_piece_means():
    """Rounding plus a random walk: two consecutive piece means that happen to be equal (a
    squared difference of ~0) once made the first weighted step return zero white noise."""
    sigma, step, levels = 8.7e-4, 1.06e-3, 11
    n = 50_000 / 2.0 ** np.arange(levels)
    v = np.full(levels, sigma ** 2 + step ** 2 / 12)
    rng = np.random.default_rng(2)
    white = np.full(8, 2 / 5000)                  # 1/n_a + 1/n_b of pieces of 5000 samples
    walk = np.full(8, 20.0)
    squares = (sigma ** 2 + step ** 2 / 12) * white[:, None] * rng.chisquare(1, (8, 3))
    squares[3] = 1e-30                           # equal means
    pairs = MeanPairs(squares, white, walk)
    s, _, _ = fit_channels(np.column_stack([v] * 3), n, FS, cutoff_hz=None, random_walk=True,
                           floor=np.full(3, v[0]), step=np.full(3, step), pairs=pairs)
    np.testing.assert_allclose(s, sigma, rtol=0.05)


def test_floor_sees_white_noise_not_a_strong_slow_signal():
    from apmcal.diagnosis.noise.fit import floor_gain, floor_stat
    t = np.arange(40_000) / FS
    x = 0.01 * RNG.standard_normal((40_000, 1)) + 0.5 * np.sin(2 * np.pi * 5 * t)[:, None]
    block = ResidualBlock(["g_x"], x, np.array([0, 20_000]), np.array([20_000, 40_000]),
                          np.array([0, 1]), t)
    assert floor_stat(block, np.array([0, 1]))[0] == pytest.approx(1e-4, rel=0.05)
    b, a = butter(2, 20.0 / (FS / 2))
    y = lfilter(b, a, RNG.standard_normal(2 ** 18))
    assert np.mean(np.diff(y, 4) ** 2) / 70 == pytest.approx(floor_gain(FS, 20.0), rel=0.03)


def test_lowpass_cutoff_found_from_filtered_noise():
    from apmcal.diagnosis.noise.fit import shared_cutoff
    b, a = butter(2, 20.0 / (FS / 2))
    x = lfilter(b, a, RNG.standard_normal((2 ** 17, 3)), axis=0)
    coeffs = details(x, np.arange(0, 2 ** 17, 2 ** 13), np.arange(2 ** 13, 2 ** 17 + 1, 2 ** 13))
    v = np.array([np.mean(c.values ** 2, axis=0) for c in coeffs])
    n = np.array([float(len(c.values)) for c in coeffs])
    floor = np.mean(np.diff(x, 4, axis=0) ** 2, axis=0) / 70
    fc = shared_cutoff([dict(v=v, n=n, fs=FS, floor=floor)])
    assert fc == pytest.approx(20.0, rel=0.15)
    white = RNG.standard_normal((2 ** 17, 3))
    coeffs = details(white, np.arange(0, 2 ** 17, 2 ** 13), np.arange(2 ** 13, 2 ** 17 + 1, 2 ** 13))
    v = np.array([np.mean(c.values ** 2, axis=0) for c in coeffs])
    floor = np.mean(np.diff(white, 4, axis=0) ** 2, axis=0) / 70
    assert shared_cutoff([dict(v=v, n=n, fs=FS, floor=floor)]) is None


def test_lattice_step_finds_rounding_and_rejects_floats():
    x = np.round(RNG.standard_normal(5000) * 3) * 0.25 + 0.1
    assert lattice_step(x) == pytest.approx(0.25)
    assert lattice_step(RNG.standard_normal(5000)) is None
