"""The gap metric: Haar coefficients, the KL cells and their null expectation, the breakdown."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from apmcal.diagnosis.scoring.gap import (
    LEVEL_MEANS,
    ResidualBlock,
    coefficients,
    compare,
    expected_variance_kl,
    level_groups,
    variance_shares,
)
from apmcal.diagnosis.scoring.haar import details, piece_means

RNG = np.random.default_rng(20261123)


def direct_detail(x, start, level, k):
    """The definition: (sum of block 2k+1 − sum of block 2k) / sqrt(2m), m = 2^(level−1)."""
    m = 2 ** (level - 1)
    a = start + 2 * k * m
    return (x[a + m:a + 2 * m].sum(axis=0) - x[a:a + m].sum(axis=0)) / np.sqrt(2 * m)


def test_details_match_the_definition_in_uneven_pieces():
    x = RNG.standard_normal((5000, 2))
    i0, i1 = np.array([3, 1500, 4000]), np.array([1203, 3777, 4999])
    levels = details(x, i0, i1)
    for level in (1, 2, 5, 9):
        coeffs = levels[level - 1]
        for p in range(3):
            sel = coeffs.piece == p
            k = (i1[p] - i0[p]) // 2 ** level
            assert sel.sum() == k
            want = np.array([direct_detail(x, i0[p], level, j) for j in range(k)])
            np.testing.assert_allclose(coeffs.values[sel], want, atol=1e-12)
            m = 2 ** (level - 1)
            np.testing.assert_array_equal(coeffs.center[sel], i0[p] + 2 * m * np.arange(k) + m)
    means = piece_means(x, i0, i1)
    np.testing.assert_allclose(means.values[1], x[1500:3777].mean(axis=0) * np.sqrt(2277))


def test_white_noise_has_its_variance_at_every_level():
    x = 0.3 * RNG.standard_normal((2 ** 17, 1))
    for c in details(x, np.array([0]), np.array([len(x)]))[:12]:
        v, n = np.mean(c.values ** 2), len(c.values)
        # chi-square interval of a variance estimate from n terms, 99.9 %
        lo, hi = stats.chi2.ppf([0.0005, 0.9995], n) / n
        assert lo * 0.09 <= v <= hi * 0.09


def test_expected_kl_matches_monte_carlo():
    """E[½n(x − 1 − ln x)], x = ratio of two independent variance estimates."""
    for n, dof in ((12, 12), (40, 31), (500, 500)):
        x = (stats.chi2.rvs(dof, size=200_000, random_state=1) / dof) / \
            (stats.chi2.rvs(dof, size=200_000, random_state=2) / dof)
        mc = np.mean(0.5 * n * (x - 1 - np.log(x)))
        assert expected_variance_kl(n, dof, dof) == pytest.approx(mc, rel=0.02)


def test_level_groups_pool_the_coarse_end():
    assert level_groups([1000, 500, 250, 6, 3, 1]) == [[1], [2], [3], [4, 5, 6]]
    assert level_groups([10, 1]) == [[1, 2]]
    assert level_groups([2]) == []


def _block(x, i0, i1):
    return ResidualBlock(["a_x", "a_y", "a_z"], x, i0, i1, np.arange(len(i0)),
                         np.arange(len(x)) / 100.0)


def test_gap_of_two_draws_of_one_process_is_zero_on_average():
    i0 = np.arange(0, 60_000, 3000)
    i1 = i0 + 2900
    values = []
    for _ in range(40):
        real = coefficients([_block(RNG.standard_normal((60_000, 3)), i0, i1)])
        twin = coefficients([_block(RNG.standard_normal((60_000, 3)), i0, i1)])
        values.append(compare(real, twin).nats)
    mean, se = np.mean(values), np.std(values, ddof=1) / np.sqrt(len(values))
    assert abs(mean) < 4 * se + 1.0          # nats: unbiased (without the correction: ~100)


def test_a_slow_trend_or_a_rounding_lattice_is_a_gap_where_it_lies():
    n = 60_000
    i0 = np.arange(0, n, 3000)
    i1 = i0 + 3000
    noise = RNG.standard_normal((n, 3))
    twin = coefficients([_block(RNG.standard_normal((n, 3)), i0, i1)])
    trend = noise.copy()
    trend[:, 2] += 0.5 * np.sin(np.arange(n) / 4000.0)
    gap = compare(coefficients([_block(trend, i0, i1)]), twin)
    by_channel = {}
    for c in gap.cells:
        by_channel[c.channel] = by_channel.get(c.channel, 0.0) + c.total
    assert by_channel["a_z"] > 50 * max(abs(by_channel["a_x"]), abs(by_channel["a_y"]), 1.0)
    slow = sum(c.total for c in gap.cells if c.level == LEVEL_MEANS or min(c.levels) >= 8)
    assert slow > 0.9 * gap.nats
    rounded = np.round(noise * 0.7) / 0.7
    rounded *= noise.std() / rounded.std()
    lattice = compare(coefficients([_block(rounded, i0, i1)]), twin)
    fine = sum(c.total for c in lattice.cells if c.kind == "histogram")
    assert fine > 0.9 * lattice.nats > 1000


def test_variance_shares_add_up_to_the_cell_kl():
    real, twin = 1.3 * RNG.standard_normal(400), RNG.standard_normal(400)
    share, v_r, v_t = variance_shares(real, twin)
    x = v_r / v_t
    assert share.sum() == pytest.approx(0.5 * 400 * (x - 1 - np.log(x))
                                        - expected_variance_kl(400, 400, 400))
