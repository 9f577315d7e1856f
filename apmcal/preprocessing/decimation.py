"""Fewer samples for a solver whose cost grows with the sample count: means of blocks of
consecutive samples.

A block mean keeps what the slow solvers use: a hold's mean is unchanged, and the gyro's
integral over a turn (rate × time, summed) is kept to first order, since the block's mean rate
spans the block's whole duration. What it removes is noise above the new Nyquist frequency.
"""
from __future__ import annotations

import numpy as np


def block_means(x: np.ndarray | None, k: int) -> np.ndarray | None:
    """Means of ``k`` consecutive rows of ``x`` (n, ...) → (n // k, ...); a trailing partial
    block is dropped. None stays None; ``k`` 1 returns ``x`` itself.

    Parameters
    ----------
    x : numpy.ndarray, shape (n, ...), or None
        Samples, any unit.
    k : int
        Samples per block.

    Returns
    -------
    numpy.ndarray, shape (n // k, ...), or None
        Block means, in the unit of ``x``.
    """
    if x is None or k <= 1:
        return x
    n = len(x) // k
    return x[:n * k].reshape(n, k, *x.shape[1:]).mean(axis=1)


def factor_for_rate(t: np.ndarray, target_hz: float) -> int:
    """Samples per block that bring the rate of times ``t`` [s] down to ``target_hz`` or just
    above it (1 when it is already at or below it).

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s], increasing.
    target_hz : float
        Rate wanted [Hz].

    Returns
    -------
    int
        Block length k ≥ 1 for :func:`block_means`.
    """
    if len(t) < 2:
        return 1
    fs = 1.0 / float(np.median(np.diff(t)))
    return max(int(fs / target_hz + 1e-6), 1)
