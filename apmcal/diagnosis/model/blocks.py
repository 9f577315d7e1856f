"""Block means of the hold pieces: the reduced data the slow (deterministic) effects are fitted on.

Temperature, bias drift, g-sensitivity and the like change over seconds to minutes, so fitting
them to means of half-second blocks loses nothing while cutting the data a hundredfold; the
fast effects (noise shape, low-pass, tremor) are fitted on the wavelet statistics instead.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

BLOCK_S = 0.5       # block length [s]


@dataclass
class Blocks:
    """Means over blocks of consecutive samples inside pieces (arrays of length b, or (b, 3)).

    ``group`` numbers the (hold, fold) pairs: blocks of one group share one orientation, the
    nuisance the geometric fits estimate for each of them.

    Attributes
    ----------
    values : (b, 3) array
        Block means of the samples, sensor units.
    t : (b,) array
        Mean time of each block [s].
    count : (b,) int array
        Samples per block.
    piece : (b,) int array
        Session-wide piece id of each block.
    group : (b,) int array
        (hold, fold) group number, 0 .. n_groups − 1.
    temp : (b,) array or None
        Mean temperature [°C].
    current : (b,) array or None
        Mean battery current [A].
    groups_total : int or None
        Number of groups when some have no block here.
    """

    values: np.ndarray      # (b, 3) sensor units
    t: np.ndarray           # (b,) mean time [s]
    count: np.ndarray       # (b,) samples per block
    piece: np.ndarray       # (b,) piece id
    group: np.ndarray       # (b,) (hold, fold) group number, 0..n_groups-1
    temp: np.ndarray | None = None       # (b,) [°C]
    current: np.ndarray | None = None    # (b,) [A]
    groups_total: int | None = None      # number of groups when some have no block here

    @property
    def n_groups(self) -> int:
        """Number of (hold, fold) groups (``groups_total`` when given)."""
        if self.groups_total is not None:
            return self.groups_total
        return int(self.group.max()) + 1 if len(self.group) else 0

    def select(self, pieces: np.ndarray) -> "Blocks":
        """The blocks of the given pieces, groups renumbered.

        Parameters
        ----------
        pieces : (k,) int array
            Session-wide piece ids to keep.

        Returns
        -------
        Blocks
            The kept blocks; their groups numbered 0, 1, ... in order (``groups_total`` not
            carried over).
        """
        keep = np.isin(self.piece, pieces)
        _, group = np.unique(self.group[keep], return_inverse=True)
        pick = lambda a: None if a is None else a[keep]  # noqa: E731
        return Blocks(self.values[keep], self.t[keep], self.count[keep], self.piece[keep],
                      group, pick(self.temp), pick(self.current))

    def group_means(self, values: np.ndarray) -> np.ndarray:
        """Count-weighted mean of (b, 3) ``values`` over each group → (n_groups, 3).

        Parameters
        ----------
        values : (b, c) array
            One row per block (the readings, c = 3, or any other per-block columns, such as
            the slow regressors).

        Returns
        -------
        (n_groups, c) array
            NaN rows for groups without a block here.
        """
        w = self.count.astype(float)
        sums = np.column_stack([np.bincount(self.group, values[:, c] * w, minlength=self.n_groups)
                                for c in range(values.shape[1])])
        weights = np.bincount(self.group, w, minlength=self.n_groups)
        with np.errstate(invalid="ignore", divide="ignore"):
            return sums / weights[:, None]          # NaN for a group without blocks here


def block_starts(i0: np.ndarray, i1: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Start indices of blocks of ``size`` samples inside each piece, and each block's piece.

    Parameters
    ----------
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces.
    size : int
        Block length [samples].

    Returns
    -------
    starts : (b,) int array
        First sample of each block.
    piece : (b,) int array
        Index (into ``i0``) of each block's piece.
    """
    counts = np.maximum((i1 - i0 + size - 1) // size, 0)
    piece = np.repeat(np.arange(len(i0)), counts)
    k = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    return i0[piece] + k * size, piece


def block_means(x: np.ndarray, i0: np.ndarray, i1: np.ndarray, size: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of ``x`` (n,) or (n, c) over blocks of ``size`` samples within pieces ``[i0, i1)``
    (the last block of a piece may be shorter). Returns (means, counts, piece of each block).

    Parameters
    ----------
    x : (n,) or (n, c) array
        Samples (any unit).
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces.
    size : int
        Block length [samples].

    Returns
    -------
    means : (b,) or (b, c) array
        Block means, in the unit of ``x``.
    counts : (b,) int array
        Samples in each block.
    piece : (b,) int array
        Index (into ``i0``) of each block's piece.
    """
    bounds, pick, counts, piece = _layout(np.asarray(i0, int).tobytes(),
                                          np.asarray(i1, int).tobytes(), size, len(x))
    sums = np.add.reduceat(np.asarray(x, dtype=float), bounds, axis=0)[pick]
    shape = (-1,) + (1,) * (sums.ndim - 1)
    return sums / counts.reshape(shape), counts, piece


@functools.lru_cache(maxsize=16)
def _layout(i0_bytes: bytes, i1_bytes: bytes, size: int, n: int) -> tuple:
    """Where :func:`block_means` sums: the reduceat boundaries, which of their sums are blocks,
    the blocks' counts and pieces — the same for every sensor and model of a session, so found
    once (read-only arrays)."""
    i0, i1 = np.frombuffer(i0_bytes, int), np.frombuffer(i1_bytes, int)
    starts, piece = block_starts(i0, i1, size)
    ends = np.minimum(starts + size, i1[piece])
    # reduceat sums between consecutive boundaries: add the ends so gaps between pieces are
    # their own (discarded) intervals
    bounds = np.unique(np.concatenate((starts, ends)))
    bounds = bounds[bounds < n]
    out = bounds, np.searchsorted(bounds, starts), ends - starts, piece
    for a in out:
        a.flags.writeable = False
    return out


def make_blocks(t, values, i0, i1, piece_ids, group_of_piece, fs: float,
                temp=None, current=None, block_s: float = BLOCK_S,
                groups_total: int | None = None) -> Blocks:
    """Blocks of the given pieces of one sample axis.

    ``piece_ids`` are the session-wide ids of the pieces ``[i0, i1)``; ``group_of_piece`` maps a
    session-wide piece id to its (hold, fold) group number.

    Parameters
    ----------
    t : (n,) array
        Sample times of the axis [s].
    values : (n, 3) array
        Samples, sensor units.
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces on this axis (empty ones are skipped).
    piece_ids : (p,) int array
        Session-wide id of each piece.
    group_of_piece : (P,) int array
        (hold, fold) group number of every session-wide piece id.
    fs : float
        Sample rate of the axis [Hz].
    temp, current : (n,) arrays, optional
        Temperature [°C] and battery current [A] at the samples.
    block_s : float
        Block length [s].
    groups_total : int, optional
        Number of groups (when some have no block among these pieces).

    Returns
    -------
    Blocks
    """
    i0, i1 = np.asarray(i0, int), np.asarray(i1, int)
    ok = i1 > i0
    i0, i1, piece_ids = i0[ok], i1[ok], np.asarray(piece_ids)[ok]
    size = max(1, int(round(block_s * fs)))
    means, counts, local = block_means(values, i0, i1, size)
    t_mean, _, _ = block_means(t, i0, i1, size)
    opt = lambda a: None if a is None else block_means(a, i0, i1, size)[0]  # noqa: E731
    pieces = piece_ids[local]
    return Blocks(means, t_mean, counts, pieces, np.asarray(group_of_piece)[pieces],
                  opt(temp), opt(current), groups_total)
