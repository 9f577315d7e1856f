"""Block means (apmcal.preprocessing.decimation): what the joint method's averaging keeps."""
import numpy as np

from apmcal.preprocessing.decimation import block_means, factor_for_rate


def test_block_means_keep_the_integral_of_a_rate_over_whole_blocks():
    t = np.arange(4000) / 400.0
    rate = np.column_stack([np.sin(2 * np.pi * 0.5 * t), np.cos(3 * t), t])    # rad/s
    k = factor_for_rate(t, 50.0)
    assert k == 8
    tk, rk = block_means(t, k), block_means(rate, k)
    assert len(tk) == 500 and np.allclose(np.diff(tk), 8 / 400.0)
    np.testing.assert_allclose(rk.sum(axis=0) * (k / 400.0), rate.sum(axis=0) / 400.0,
                               atol=1e-12)


def test_a_trailing_partial_block_is_dropped_and_slow_recordings_stay_as_they_are():
    x = np.arange(10.0)
    np.testing.assert_allclose(block_means(x, 4), [1.5, 5.5])
    assert block_means(None, 4) is None and block_means(x, 1) is x
    assert factor_for_rate(np.arange(100) / 50.0, 50.0) == 1
    assert factor_for_rate(np.arange(100) / 20.0, 50.0) == 1
    assert factor_for_rate(np.arange(100) / 120.0, 50.0) == 2
