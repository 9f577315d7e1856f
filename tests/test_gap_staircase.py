"""Integer telemetry whose noise hardly dithers its rounding (ArduPilot's RAW_IMU gyro at rest:
int16 mrad/s truncated toward zero, noise a fifth of a step) is a staircase: the gap must not
score what its readings cannot show.

- The level-1 histogram's bins never split a cluster of lattice values at the fitted model's
  sub-step offsets (:func:`apmcal.diagnosis.scoring.gap.resolved_edges`). Before, an ArduPilot
  SITL tlog's triangle drift cost 5e4 nats there against itself and the temperature polynomial
  won (issue: the staircase favoured the temperature polynomial).
- A piece mean adds up the rounding errors of an undithered run coherently, so its floor is
  Σ L²/n · Δ²/12 (:func:`apmcal.diagnosis.session.facts.coherent_runs`), not Δ²/12.
"""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.diagnosis.scoring.gap import resolved_edges, shape_shares
from apmcal.diagnosis.session.facts import coherent_runs

STEP = 1e-3                 # rad/s: RAW_IMU's mrad/s
FLOOR = STEP ** 2 / 12


def staircase_coefficients(rng, n: int, jitter: float) -> np.ndarray:
    """Level-1 Haar coefficients of a gyro reading on a 1 mrad/s lattice that changes in 4 %
    of the sample pairs (by one step, or 1.5 where the reader moved a truncated reading half a
    step out), minus a fitted model's slope: ``jitter`` [rad/s] per coefficient, far below a
    step."""
    jumps = rng.choice([0.0, 1.0, -1.0, 1.5, -1.5], size=n, p=[0.96, 0.012, 0.012, 0.008, 0.008])
    return jumps * STEP / np.sqrt(2) + jitter


def test_edges_fall_between_the_lattice_points_and_bound_a_tie_on_both_sides():
    grid = STEP / (2 * np.sqrt(2))          # half the finest coefficients' lattice
    edges = np.array([-1e-9, -1e-9, 2e-9, 2e-9, 0.7071e-3 + 3e-9])
    # the tie at 0 is bounded at ±grid/2; the lattice point 2·grid (one step) above it
    np.testing.assert_allclose(resolved_edges(edges, FLOOR), [-0.5 * grid, 0.5 * grid,
                                                              2.5 * grid], rtol=1e-12)
    # float readings (a float32's spacing as the floor): the edges stay where they were
    fine = np.array([-0.3, 0.1, 0.2])
    np.testing.assert_allclose(resolved_edges(fine, (2 ** -23) ** 2 / 12), fine, atol=1e-7)
    np.testing.assert_array_equal(resolved_edges(fine, 0.0), fine)


def test_sub_step_offsets_of_the_model_cost_nothing():
    """Real and twin: the same staircase process, residuals of fitted models whose slopes differ
    by a millionth of a step (the twin's zeros sit just above zero, the real ones just below).
    The histogram must see two draws of one process (about 0 nats); binned at the twin's
    quantiles as before (a floor of 0 keeps them), the zeros fell below every edge inside the
    twin's cluster and cost thousands."""
    rng = np.random.default_rng(4)
    twin = staircase_coefficients(rng, 15000, rng.uniform(0, 4e-9, 15000))
    real = staircase_coefficients(rng, 15000, rng.uniform(-4e-9, 0, 15000))
    assert abs(shape_shares(real, twin, FLOOR).sum()) < 30
    assert shape_shares(real, twin, 0.0).sum() > 1000


def test_a_different_staircase_still_costs():
    """What the readings do show — how often the reading changes — is still scored: a twin
    that changes a quarter as often as the real board pays for it, far beyond the
    same-process figure above."""
    rng = np.random.default_rng(5)
    real = staircase_coefficients(rng, 15000, 0.0)
    twin = np.where(rng.random(15000) < 0.25, staircase_coefficients(rng, 15000, 1e-9), 1e-9)
    assert shape_shares(real, twin, FLOOR).sum() > 60


def test_coherent_runs_hand_worked():
    x = np.zeros((20, 3))
    x[4:10, 0] = 1.0                        # piece [0, 10): runs 4 and 6 on x
    x[10:20, 1] = np.arange(10) % 2         # piece [10, 20): y alternates, ten runs of one
    x[:, 2] = np.random.default_rng(1).standard_normal(20)     # z: float noise
    i0, i1 = np.array([0, 10]), np.array([10, 20])
    got = coherent_runs(x, i0, i1)
    # x: (16 + 36)/10 = 5.2 and, in the second piece one run of 10: 100/10 = 10 -> 7.6
    # y: one run of 10 (10), then ten runs of 1 (1) -> 5.5;  z: every sample new -> 1
    np.testing.assert_allclose(got, [7.6, 5.5, 1.0])
    assert coherent_runs(x, np.array([0]), np.array([0])).tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize("sigma_steps, low, high", [(0.02, 50.0, 1e9), (2.0, 1.0, 2.0)])
def test_an_undithered_staircase_raises_the_piece_mean_floor(sigma_steps, low, high):
    """A slow drift over a 30-s piece at 50 Hz read through truncation: with noise of 2 % of a
    step the reading changes a few times per piece (coherent errors: the floor rises by
    hundreds); with two steps of noise it changes at nearly every sample (about white)."""
    rng = np.random.default_rng(2)
    t = np.arange(1500 * 4) / 50.0
    x = np.trunc((0.5 + 0.01 * t[:, None] + sigma_steps * rng.standard_normal((len(t), 3))))
    edges = np.arange(0, len(t) + 1, 1500)
    factor = coherent_runs(x * STEP, edges[:-1], edges[1:])
    assert np.all((factor > low) & (factor < high)), factor


@pytest.mark.parametrize("truncated", [True, False])
@pytest.mark.parametrize("sigma_steps, uniform", [(0.01, False), (0.04, False), (0.15, False),
                                                  (0.6, True), (0.2, True)])
def test_the_noise_below_the_step_is_found_from_how_often_the_reading_changes(
        truncated, sigma_steps, uniform):
    """A triangle-like drift over 0-4.4 steps read through the format (truncated toward zero
    and moved half a step out, or rounded), with noise σ below the step — Gaussian, or uniform
    as ArduPilot SITL's (an accelerometer at rest: ±1.02 mG under a 1 mG step): given the
    drift, the σ that makes the readings change as often as they do is σ (the wavelet
    variances see only the rounding there, and gave 0)."""
    from apmcal.diagnosis.noise.dither import dither_sigma
    from apmcal.diagnosis.twin.simulate import truncated_reading

    rng = np.random.default_rng(7)
    t = np.arange(30000) / 50.0                               # 600 s at 50 Hz
    mu = STEP * np.column_stack([4.4 * np.minimum(t, 600 - t) / 300, 0.3 + t / 150,
                                 -0.2 - t / 200])
    e = rng.uniform(-np.sqrt(3), np.sqrt(3), mu.shape) if uniform else \
        rng.standard_normal(mu.shape)
    x = mu + sigma_steps * STEP * e
    readings = truncated_reading(x, STEP) if truncated else np.round(x / STEP) * STEP
    edges = np.arange(0, len(t) + 1, 1500)                   # 30-s pieces
    got = dither_sigma(readings, mu, edges[:-1], edges[1:], np.full(3, STEP), truncated,
                       uniform)
    np.testing.assert_allclose(got / STEP, sigma_steps, rtol=0.15)


def test_noise_of_a_step_or_more_is_left_to_the_wavelet_estimate():
    from apmcal.diagnosis.noise.dither import dither_sigma

    rng = np.random.default_rng(8)
    mu = np.full((5000, 1), 0.3 * STEP)
    readings = np.round((mu + 2 * STEP * rng.standard_normal(mu.shape)) / STEP) * STEP
    got = dither_sigma(readings, mu, np.array([0]), np.array([5000]), np.array([STEP]), False)
    assert got[0] == pytest.approx(STEP)           # the cap: white rounding from here on
    # a reading that never changes, far from any threshold: no noise to speak of
    flat = np.zeros((5000, 1))
    assert dither_sigma(flat, flat + 0.1 * STEP, np.array([0]), np.array([5000]),
                        np.array([STEP]), True)[0] == pytest.approx(1e-4 * STEP)
