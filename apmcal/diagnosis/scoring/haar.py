"""Haar wavelet coefficients of residuals cut into pieces, with where each coefficient lies.

The gap (:mod:`apmcal.diagnosis.scoring.gap`) compares real and twin residuals scale by scale. For one
piece of ``n`` samples and level ``j`` (block length ``m = 2**(j-1)`` samples) the coefficients
are the differences of adjacent non-overlapping block sums::

    d[j, k] = (S[2k+1] - S[2k]) / sqrt(2 m),   S[i] = sum of the samples of block i

counted from the piece's first sample (samples left over at the end are unused at that level).
For white noise of variance σ² every coefficient has variance σ² at every level, and the
coefficients of one level are independent (they are the orthonormal Haar transform): a level's
mean square is the Haar wavelet variance, half the non-overlapping Allan variance at
τ = m / fs times 2m (Percival & Walden 2000, §8.6). The piece mean enters through its own
coefficient ``sqrt(n) · mean`` (also of variance σ² under white noise). Coefficients never reach
across two pieces, so logging holes and the moves between holds never enter them.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np


@dataclass
class Coefficients:
    """Coefficients of one level (or of the piece means) for every piece.

    Attributes
    ----------
    values : (k, c) array
        Coefficients, one column per channel, in the residual's unit (from :func:`details`
        column-major: ``values.T`` is a C-ordered (c, k) array, one contiguous row per channel).
    piece : (k,) int array
        Index of the piece each coefficient comes from.
    center : (k,) int array
        Sample index at the middle of the coefficient's support (for time and temperature).
    """

    values: np.ndarray
    piece: np.ndarray
    center: np.ndarray


def details(x: np.ndarray, i0: np.ndarray, i1: np.ndarray) -> list[Coefficients]:
    """Haar detail coefficients of ``x`` within pieces ``[i0[p], i1[p])``, levels 1, 2, ...

    Parameters
    ----------
    x : (n,) or (n, c) array
        Residual samples on the session's sample axis (any unit).
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces.

    Returns
    -------
    list of Coefficients
        Element ``j - 1`` for level ``j``, up to the coarsest level any piece reaches.
    """
    # channel by channel, each channel's samples contiguous: gathers and arithmetic on every
    # third element (one column of an (n, 3) array) were several times slower
    sums = np.ascontiguousarray(np.asarray(x, dtype=float).reshape(len(x), -1).T)
    out, m = [], 1
    for level in _layout(np.asarray(i0, int).tobytes(), np.asarray(i1, int).tobytes()):
        even, odd_blocks = np.take(sums, level.even, axis=1), np.take(sums, level.odd, axis=1)
        # (k, c) as documented, each channel's column contiguous (values.T is C-ordered)
        out.append(Coefficients(((odd_blocks - even) / np.sqrt(2.0 * m)).T, level.piece,
                                level.center))
        sums, m = even + odd_blocks, 2 * m
    return out


@dataclass(frozen=True)
class _Level:
    even: np.ndarray            # rows of the previous level's block sums: first of each pair
    odd: np.ndarray             # ... second of each pair
    piece: np.ndarray           # piece of each coefficient (read-only: shared by every call)
    center: np.ndarray          # sample index at the middle of its support (read-only)


@functools.lru_cache(maxsize=16)     # a diagnosis uses a handful (a few MB each at 400 Hz)
def _layout(i0_bytes: bytes, i1_bytes: bytes) -> tuple[_Level, ...]:
    """Which blocks pair up at each level, and where each coefficient lies: the same for every
    residual cut into the same pieces (every model, real and twin), so worked out once.

    Blocks pair up from each piece's start; a piece's odd last block is left out of its level.
    Level 1's blocks are the samples themselves (rows of ``x``); level j's are the pair sums of
    level j − 1, one after the other in piece order.
    """
    i0, i1 = np.frombuffer(i0_bytes, int), np.frombuffer(i1_bytes, int)
    counts = np.maximum(i1 - i0, 0)
    first = i0.copy()               # each piece's first block among the current level's blocks
    levels, m = [], 1
    while np.any(counts >= 2):
        pairs = counts // 2
        piece = np.repeat(np.arange(len(i0)), pairs)
        k = np.arange(len(piece)) - np.repeat(np.cumsum(pairs) - pairs, pairs)
        even_index = first[piece] + 2 * k
        levels.append(_Level(_read_only(even_index), _read_only(even_index + 1), _read_only(piece),
                             _read_only(i0[piece] + 2 * m * k + m)))
        counts, m = pairs, 2 * m
        first = np.cumsum(counts) - counts
    return tuple(levels)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def piece_means(x: np.ndarray, i0: np.ndarray, i1: np.ndarray) -> Coefficients:
    """``sqrt(n) · mean`` of ``x`` over each piece (variance σ² under white noise).

    Parameters
    ----------
    x : (n,) or (n, c) array
        Residual samples on the session's sample axis (any unit).
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces.

    Returns
    -------
    Coefficients
        ``values`` (p, c) in the unit of ``x``, ``piece`` 0 .. p − 1, ``center`` the middle
        sample of each piece.
    """
    x2 = np.asarray(x, dtype=float).reshape(len(x), -1)
    i0, i1 = np.asarray(i0, int), np.asarray(i1, int)
    sums = np.array([x2[a:b].sum(axis=0) for a, b in zip(i0, i1)]).reshape(len(i0), -1)
    n = (i1 - i0)[:, None].astype(float)
    return Coefficients(sums / np.sqrt(n), np.arange(len(i0)), (i0 + i1) // 2)
