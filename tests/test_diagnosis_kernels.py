"""The diagnosis's hand-written fast paths give what the plain numpy they replace gives, bit for
bit (the gap's results must not move when they are made faster)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from apmcal.diagnosis.model.static_fit import MIN_CHORD, distinct_directions
from apmcal.diagnosis.scoring.gap import (
    SHAPE_BINS,
    SHAPE_SMOOTHING,
    bin_index,
    shape_shares,
    sorted_quantiles,
    variance_shares,
    variance_shares_by_row,
)
from apmcal.diagnosis.scoring.haar import details
from apmcal.diagnosis.session.trajectory import prefix_products, quat_multiply
from apmcal.diagnosis.twin.draws import ReplayedGenerator, replayed

RNG = np.random.default_rng(20261124)


def plain_shape_shares(real, twin):
    """shape_shares as first written: np.quantile edges, np.searchsorted bins (and the twin's
    histogram smoothed by its normal distribution, SHAPE_SMOOTHING of it)."""
    edges = np.unique(np.quantile(twin, np.arange(1, SHAPE_BINS) / SHAPE_BINS))
    b_r, b_t = np.searchsorted(edges, real), np.searchsorted(edges, twin)
    bins = len(edges) + 1
    p = (np.bincount(b_r, minlength=bins) + 0.5) / (len(real) + 0.5 * bins)
    q = (np.bincount(b_t, minlength=bins) + 0.5) / (len(twin) + 0.5 * bins)
    g = np.diff(ndtr(np.concatenate([[-np.inf], edges / np.sqrt(np.mean(twin ** 2)), [np.inf]])))
    q = (1.0 - SHAPE_SMOOTHING) * q + SHAPE_SMOOTHING * g
    return np.log(p / q)[b_r] - 0.5 * (bins - 1) * (1.0 + len(real) / len(twin)) / len(real)


@pytest.mark.parametrize("lattice", [False, True])
def test_shape_shares_match_quantile_and_searchsorted(lattice):
    for _ in range(40):
        real = RNG.standard_normal((int(RNG.integers(400, 30000)), 3))[:, 1] * RNG.uniform(.5, 2)
        twin = RNG.standard_normal(int(RNG.integers(400, 30000)))
        if lattice:         # tied quantiles merge bins
            real, twin = np.round(real * 2) / 2, np.round(twin * 2) / 2
        np.testing.assert_array_equal(shape_shares(real, twin), plain_shape_shares(real, twin))


def test_bin_index_is_searchsorted():
    edges = np.sort(RNG.standard_normal(31))
    x = np.concatenate([RNG.standard_normal(1000), edges, [np.nan, np.inf, -np.inf]])
    np.testing.assert_array_equal(bin_index(edges, x), np.searchsorted(edges, x))
    np.testing.assert_array_equal(bin_index(edges, x[::-2]), np.searchsorted(edges, x[::-2]))


def test_sorted_quantiles_are_numpys():
    q = np.arange(1, SHAPE_BINS) / SHAPE_BINS
    for n in list(range(1, 70)) + [999, 4096, 12345]:
        x = np.sort(np.round(RNG.standard_normal(n), int(RNG.integers(0, 4))))
        np.testing.assert_array_equal(sorted_quantiles(x, q), np.quantile(x, q))
    with_nan = np.sort(np.append(RNG.standard_normal(50), np.nan))
    np.testing.assert_array_equal(sorted_quantiles(with_nan, q), np.quantile(with_nan, q))


def test_variance_cells_of_all_channels_are_each_channels_own():
    real, twin = RNG.standard_normal((3, 777)) * [[1], [2], [3]], RNG.standard_normal((3, 777))
    for row, (share, v_r, v_t) in enumerate(variance_shares_by_row(real, twin, 2)):
        want = variance_shares(real[row].copy(), twin[row].copy(), 2)
        np.testing.assert_array_equal(share, want[0])
        assert (v_r, v_t) == want[1:]


def test_details_of_several_channels_are_each_channels_own():
    x = RNG.standard_normal((3001, 3))
    i0, i1 = np.array([0, 1100, 2000]), np.array([1001, 1999, 3001])
    together = details(x, i0, i1)
    for col in range(3):
        for a, b in zip(together, details(x[:, col].copy(), i0, i1)):
            np.testing.assert_array_equal(a.values[:, col], b.values[:, 0])
            np.testing.assert_array_equal(a.piece, b.piece)
            np.testing.assert_array_equal(a.center, b.center)
    assert not together[0].piece.flags.writeable     # shared between calls: read-only


def test_segmented_prefix_products_are_the_products_of_each_segment():
    lengths = [1, 5, 2, 17, 3]
    segment = np.repeat(np.arange(len(lengths)), lengths)
    q = RNG.standard_normal((len(segment), 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    got = prefix_products(q, segment)
    start = 0
    for n in lengths:           # the scan's own grouping, one segment alone
        np.testing.assert_array_equal(got[start:start + n], prefix_products(q[start:start + n]))
        start += n
    np.testing.assert_allclose(got[2], quat_multiply(q[1:2], q[2:3])[0])     # q1·q2


def test_replayed_draws_are_the_generators_own():
    def fresh():
        return {k: np.random.default_rng([7, i]) for i, k in enumerate(("a", "b"))}

    calls = [("a", "standard_normal", ((5, 3),)), ("b", "uniform", (-1.0, 1.0, (4,))),
             ("a", "standard_normal", ((2, 3),))]
    plain = fresh()
    want = [getattr(plain[k], m)(*args) for k, m, args in calls]
    first = replayed(fresh(), ("seed", 1))
    for (k, m, args), w in zip(calls[:2], want):       # made, then cached
        np.testing.assert_array_equal(getattr(first[k], m)(*args), w)
    again = replayed(fresh(), ("seed", 1))
    for (k, m, args), w in zip(calls, want):        # replayed, then a new draw after catching up
        np.testing.assert_array_equal(getattr(again[k], m)(*args), w)
    other_seed = ReplayedGenerator(np.random.default_rng([8, 0]), ("seed", 2, "a"))
    assert not np.array_equal(other_seed.standard_normal((5, 3)), want[0])


def test_distinct_directions_as_the_greedy_norm_loop():
    def plain(vectors, chord):
        units = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
        centres = []
        for u in units:
            if all(np.linalg.norm(u - c) >= chord for c in centres):
                centres.append(u)
        return len(centres)

    for trial in range(300):
        k = int(RNG.integers(1, 60))
        base = RNG.standard_normal((int(RNG.integers(1, 8)), 3))
        v = base[RNG.integers(0, len(base), k)] + RNG.standard_normal((k, 3)) * 0.3
        u0, u1 = v[0] / np.linalg.norm(v[0]), v[-1] / np.linalg.norm(v[-1])
        chord = float(np.linalg.norm(u0 - u1)) if trial % 2 else MIN_CHORD   # exactly at a pair
        assert distinct_directions(v, chord) == plain(v, chord)
