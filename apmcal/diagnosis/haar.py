"""Haar wavelet coefficients of residuals cut into pieces, with where each coefficient lies.

The gap (:mod:`apmcal.diagnosis.gap`) compares real and twin residuals scale by scale. For one
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

from dataclasses import dataclass

import numpy as np


@dataclass
class Coefficients:
    """Coefficients of one level (or of the piece means) for every piece.

    Attributes
    ----------
    values : (k, c) array
        Coefficients, one column per channel, in the residual's unit.
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
    list of Coefficients, element ``j - 1`` for level ``j``, up to the coarsest level any piece
    reaches.
    """
    x2 = np.asarray(x, dtype=float).reshape(len(x), -1)
    i0, i1 = np.asarray(i0, int), np.asarray(i1, int)
    counts = np.maximum(i1 - i0, 0)
    # the current level's block sums of every piece, one after the other
    sums = np.concatenate([x2[a:b] for a, b in zip(i0, i1)]) if len(i0) else x2[:0]
    out, m = [], 1
    while np.any(counts >= 2):
        # blocks pair up from each piece's start; an odd last block is left out of this level
        pairs = counts // 2
        first = np.cumsum(counts) - counts          # each piece's first block in ``sums``
        piece = np.repeat(np.arange(len(i0)), pairs)
        k = np.arange(len(piece)) - np.repeat(np.cumsum(pairs) - pairs, pairs)
        even_index = first[piece] + 2 * k
        even, odd_blocks = sums[even_index], sums[even_index + 1]
        out.append(Coefficients((odd_blocks - even) / np.sqrt(2.0 * m), piece,
                                i0[piece] + 2 * m * k + m))
        sums, counts, m = even + odd_blocks, pairs, 2 * m
    return out


def piece_means(x: np.ndarray, i0: np.ndarray, i1: np.ndarray) -> Coefficients:
    """``sqrt(n) · mean`` of ``x`` over each piece (variance σ² under white noise)."""
    x2 = np.asarray(x, dtype=float).reshape(len(x), -1)
    i0, i1 = np.asarray(i0, int), np.asarray(i1, int)
    sums = np.array([x2[a:b].sum(axis=0) for a, b in zip(i0, i1)]).reshape(len(i0), -1)
    n = (i1 - i0)[:, None].astype(float)
    return Coefficients(sums / np.sqrt(n), np.arange(len(i0)), (i0 + i1) // 2)
