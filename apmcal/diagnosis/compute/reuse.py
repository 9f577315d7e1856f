"""The Haar coefficients and gap cells of a residual block that comes back value for value.

Most candidate effects change the model of one sensor and leave the others as every other
model has them: their hold residuals, real and twin, are then the very same numbers model after
model (the fits are deterministic, and the twin's noise draws are common to all models:
:mod:`apmcal.diagnosis.twin.draws`). So are their coefficients and their cells. This module keeps the
recent ones and hands them back for a block whose values equal a kept block's, number for
number (``np.array_equal``, after a check of every 251st value) — never on a key that only
describes the inputs, which a change elsewhere could make stale. Comparing costs a fraction of
what it saves (a block's coefficients and cells are several passes over its values, each
with sorting and binning).

Kept per process; a forked worker starts with what the main process kept.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

KEPT = 24           # blocks kept of each kind (at 400 Hz a hold block is about 6 MB) ...
BUDGET = 48 << 20   # ... within this many bytes of arrays per kind: a longer session keeps
                    # fewer blocks, not more memory (a one-hour 400 Hz block is 35 MB)
STRIDE = 251        # the quick check reads every STRIDE-th value


_ALL: list = []     # every store, for forget()


def forget() -> None:
    """Drop everything kept (a new session: nothing of the last one can match, and what it
    kept is hundreds of MB at 400 Hz)."""
    for store in _ALL:
        store.entries.clear()
        store._bytes.clear()


class Recent:
    """Entries found by comparing arrays, least recently used forgotten first.

    Parameters
    ----------
    size : int
        Entries kept.
    budget : int, optional
        Bytes the entries may hold together, as ``weigh(key, value)`` counts them; the oldest
        are forgotten beyond it (the newest is kept whatever its size).
    weigh : callable, optional
        (key, value) -> bytes (default: :func:`array_bytes` of both).
    """

    def __init__(self, size: int, budget: int | None = None, weigh=None):
        self.size = size
        self.budget = budget
        self.weigh = weigh or array_bytes
        self.entries: OrderedDict = OrderedDict()
        self._bytes: dict = {}
        self._next = 0
        _ALL.append(self)

    def find(self, match):
        """The value of the first entry ``match(entry key)`` accepts, or None."""
        for token, (key, value) in self.entries.items():
            if match(key):
                self.entries.move_to_end(token)
                return value
        return None

    def keep(self, key, value) -> None:
        """Keep ``value`` under ``key`` (what ``match`` reads), forgetting the oldest beyond
        the size."""
        self.entries[self._next] = (key, value)
        if self.budget is not None:
            self._bytes[self._next] = self.weigh(key, value)
        self._next += 1
        while len(self.entries) > self.size or (
                self.budget is not None and len(self.entries) > 1
                and sum(self._bytes.values()) > self.budget):
            token, _ = self.entries.popitem(last=False)
            self._bytes.pop(token, None)


def array_bytes(*objects) -> int:
    """Bytes of the numpy arrays among ``objects`` and the items of those that are tuples or
    lists (one level down: what a store's keys and values hold directly)."""
    total = 0
    for o in objects:
        items = o if isinstance(o, (tuple, list)) else (o,)
        total += sum(x.nbytes for x in items if isinstance(x, np.ndarray))
    return total


# a block's coefficients are about as large as its values (levels and piece means), its cells
# hold a share per coefficient and a piece and centre for each
_COEFFICIENTS = Recent(KEPT, BUDGET, lambda key, value: 2 * key[1].nbytes)
_CELLS = Recent(KEPT, BUDGET, lambda key, value: sum(3 * c.nats.nbytes for c in value))
_DERIVED = Recent(2 * KEPT)     # statistics of a few numbers per level and channel


def _same_values(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and \
        np.array_equal(a[::STRIDE], b[::STRIDE]) and np.array_equal(a, b)


def coefficients(block, compute):
    """(levels, means) of ``block`` (a ResidualBlock): those kept for a block with the same
    values and pieces, or ``compute(block)``'s, then kept.

    Parameters
    ----------
    block : ResidualBlock
    compute : callable
        block -> (levels, means), as :func:`apmcal.diagnosis.scoring.gap.coefficients` makes them.

    Returns
    -------
    (list of Coefficients, Coefficients)
        Shared with the other blocks of the same values: read them, never write to them.
    """
    names = tuple(block.names)

    def match(key) -> bool:        # the cheap tests first: most kept blocks are another's
        kept_names, values, i0, i1 = key
        return kept_names == names and values.shape == block.values.shape and \
            np.array_equal(i0, block.i0) and np.array_equal(i1, block.i1) and \
            _same_values(values, block.values)

    known = _COEFFICIENTS.find(match)
    if known is None:
        known = compute(block)
        _COEFFICIENTS.keep((names, block.values, block.i0, block.i1), known)
    return known


def _scoring(block) -> tuple:
    """What of a block, besides its coefficients, its cells depend on."""
    return (tuple(block.names), block.shape, block.mean_dof, block.mean_nuisance)


def cells(real, twin, keep, in_sample: bool, compute, floors: dict | None = None) -> list:
    """The gap cells of one block (real and twin BlockCoefficients): those kept for the same
    coefficients (the very objects :func:`coefficients` hands out), pieces kept, side and
    scoring, turned to this block; or ``compute()``'s, then kept.

    Parameters
    ----------
    real, twin : BlockCoefficients
    keep : (k,) int array or None
        Session-wide ids of the pieces compared.
    in_sample : bool
    compute : callable
        () -> list of CellShare.
    floors : dict, optional
        The channels' variance floors the cells were scored with (part of the match).

    Returns
    -------
    list of CellShare
        Their share arrays are shared with the kept cells: read them, never write to them.
    """
    block = real.block
    keep_bytes = None if keep is None else np.asarray(keep).tobytes()
    scoring = _scoring(block) + (tuple(sorted((floors or {}).items())),)

    def match(key) -> bool:
        levels, twin_levels, kept, side, kept_scoring, piece, radial = key
        return levels is real.levels and twin_levels is twin.levels and kept == keep_bytes \
            and side == in_sample and kept_scoring == scoring \
            and np.array_equal(piece, block.piece) and \
            (radial is None if block.radial is None else
             radial is not None and np.array_equal(radial, block.radial))

    known = _CELLS.find(match)
    if known is None:
        known = compute()
        _CELLS.keep((real.levels, twin.levels, keep_bytes, in_sample, scoring, block.piece,
                     block.radial), known)
    return [c.on(block) for c in known]


def derived(coefficients, what: str, pieces, compute):
    """``compute()``, a statistic ``what`` of ``coefficients`` (BlockCoefficients) over the
    session-wide pieces ``pieces``: the one kept for the same coefficients (the very objects
    :func:`coefficients` hands out), block pieces and pieces, or worked out and kept.

    Returns
    -------
    object
        Shared with the other callers: read it, never write to it.
    """
    block = coefficients.block
    pieces_bytes = np.asarray(pieces).tobytes()

    def match(key) -> bool:
        kept_what, levels, kept_pieces, piece = key
        return kept_what == what and levels is coefficients.levels and \
            kept_pieces == pieces_bytes and np.array_equal(piece, block.piece)

    known = _DERIVED.find(match)
    if known is None:
        known = compute()
        _DERIVED.keep((what, coefficients.levels, pieces_bytes, block.piece), known)
    return known
