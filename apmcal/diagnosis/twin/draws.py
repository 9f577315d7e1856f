"""Random draws made once and replayed: the twin's noise for every model of a fold.

Every model of a fold simulates its twin with the same seed (common random numbers, see
:meth:`apmcal.diagnosis.scoring.evaluate.Evaluator._fold`), so sitl's generators draw the same
samples model after model — a sizeable share of a model's time at 400 Hz. :func:`replayed`
wraps those generators: a draw is keyed by the generator's seed and every call made on it
so far, and served from the cache when made before; the generator itself catches up on the
calls it skipped before it draws anything new. The samples are the very ones it would draw,
bit for bit.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

MAX_DRAWS = 24          # cached arrays (a 400 Hz session's are ~6 MB each) ...
BUDGET = 32 << 20       # ... within this many bytes: a longer session keeps fewer draws
_DRAWS: OrderedDict = OrderedDict()


class ReplayedGenerator:
    """The draws of one seeded :class:`numpy.random.Generator` (``standard_normal``,
    ``uniform``), each made once per process and shared (read-only) afterwards."""

    def __init__(self, rng: np.random.Generator, key: tuple):
        self._rng = rng
        self._history = key         # the seed, then every call made so far
        self._skipped: list = []    # calls served from the cache, not yet made by _rng

    def standard_normal(self, size=None):
        """``Generator.standard_normal(size)``, served from the cache when drawn before.

        Returns
        -------
        float or array of shape ``size``
            Read-only when an array (shared by every later replay).
        """
        return self._draw("standard_normal", (size,))

    def uniform(self, low=0.0, high=1.0, size=None):
        """``Generator.uniform(low, high, size)``, served from the cache when drawn before.

        Returns
        -------
        float or array of shape ``size``
            Read-only when an array (shared by every later replay).
        """
        return self._draw("uniform", (low, high, size))

    def _draw(self, method: str, args: tuple):
        call = (method, tuple(_hashable(a) for a in args))
        self._history = self._history + (call,)
        if self._history in _DRAWS:
            _DRAWS.move_to_end(self._history)
            self._skipped.append((method, args))
            return _DRAWS[self._history]
        for skipped, skipped_args in self._skipped:     # catch up: the same state as without
            getattr(self._rng, skipped)(*skipped_args)  # the cache
        self._skipped = []
        out = getattr(self._rng, method)(*args)
        if isinstance(out, np.ndarray):
            out.flags.writeable = False     # shared by every later replay
        _DRAWS[self._history] = out
        while len(_DRAWS) > MAX_DRAWS or (len(_DRAWS) > 1 and _cached_bytes() > BUDGET):
            _DRAWS.popitem(last=False)
        return out


def _cached_bytes() -> int:
    return sum(v.nbytes for v in _DRAWS.values() if isinstance(v, np.ndarray))


def replayed(generators: dict, seed) -> dict:
    """``{name: generator}`` with each generator's draws cached under (``seed``, name)."""
    return {name: ReplayedGenerator(rng, (seed, name)) for name, rng in generators.items()}


def _hashable(a):
    if isinstance(a, np.ndarray):
        return ("array", a.dtype.str, a.shape, a.tobytes())
    if isinstance(a, list):
        return tuple(_hashable(x) for x in a)
    return a
