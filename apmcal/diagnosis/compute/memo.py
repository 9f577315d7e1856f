"""Results of pure functions kept by the content of their inputs, for every model of a session.

Many models of a session repeat a fit on identical inputs: an effect that only touches the gyro
leaves the accelerometer's and the compass's hold data, their fits and their twins' data as
they are under the nominal model. A :class:`ContentMemo` keys such a function's result by a
digest of everything it reads (array contents, not identities: a twin made afresh with the same
samples still hits), so the result is the very one the function returns, bit for bit.

Forked workers (:mod:`apmcal.diagnosis.compute.workers`) send the entries they add back with each job's
result; the main process keeps them, so that workers forked later inherit them too.
"""
from __future__ import annotations

import copy
import hashlib
from collections import OrderedDict

import numpy as np

_MEMOS: dict[str, "ContentMemo"] = {}


class ContentMemo:
    """A bounded map from input digests to results (least recently used dropped first).

    Parameters
    ----------
    name : str
        Unique name (entries travel back from workers under it).
    size : int
        Entries kept.
    """

    def __init__(self, name: str, size: int):
        if name in _MEMOS:
            raise ValueError(f"a memo named {name!r} exists already")
        self.name, self.size = name, size
        self._entries: OrderedDict = OrderedDict()
        self._added: dict | None = None     # entries added in a worker's job, to send back
        _MEMOS[name] = self

    def get(self, key: bytes):
        """A copy of the result stored under ``key``, or None (results are mutable objects:
        the caller may change its copy)."""
        if key not in self._entries:
            return None
        self._entries.move_to_end(key)
        return copy.deepcopy(self._entries[key])

    def put(self, key: bytes, value) -> None:
        """Store a copy of ``value`` under ``key``."""
        self._store(key, copy.deepcopy(value))
        if self._added is not None:
            self._added[key] = self._entries[key]

    def _store(self, key: bytes, value) -> None:
        self._entries[key] = value
        self._entries.move_to_end(key)
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)


def digest(*parts) -> bytes:
    """A 20-byte digest of arrays (dtype, shape and contents), numbers, strings, None and
    (nested) tuples, lists and dicts of them.

    Raises
    ------
    TypeError
        For any other kind of part (so that nothing an input holds goes unhashed).
    """
    # SHA-1 for speed (hardware-accelerated here: 2.4× blake2b on a 1 MB array); a cache key
    # needs no more than its 160 bits against accidental collisions
    h = hashlib.sha1()
    _feed(h, parts)
    return h.digest()


def _feed(h, part) -> None:
    if isinstance(part, np.ndarray):
        h.update(f"a{part.dtype.str}{part.shape}".encode())
        h.update(np.ascontiguousarray(part).tobytes())
    elif isinstance(part, (tuple, list)):
        h.update(f"l{len(part)}".encode())
        for p in part:
            _feed(h, p)
    elif isinstance(part, dict):
        h.update(f"d{len(part)}".encode())
        for k in sorted(part):
            _feed(h, k)
            _feed(h, part[k])
    elif part is None or isinstance(part, (bool, int, float, str, np.number, np.bool_)):
        h.update(f"{type(part).__name__}:{part!r};".encode())
    else:
        raise TypeError(f"cannot digest a {type(part).__name__}")


def start_recording() -> None:
    """Note the entries every memo adds from now on (a worker, before its job)."""
    for memo in _MEMOS.values():
        memo._added = {}


def recorded() -> dict:
    """{memo name: {key: result}} added since :func:`start_recording`; recording stops."""
    out = {}
    for name, memo in _MEMOS.items():
        if memo._added:
            out[name] = memo._added
        memo._added = None
    return out


def keep(entries: dict) -> None:
    """Store entries a worker recorded (:func:`recorded`) in this process's memos."""
    for name, added in entries.items():
        for key, value in added.items():
            _MEMOS[name]._store(key, value)
