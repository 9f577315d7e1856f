"""A session averaged over blocks of samples: the same holds, moves, pieces and folds at a
lower rate, where the effects that change the signal slowly are scored in a fraction of the time.

Averaging ``k`` consecutive samples keeps every Haar level of the gap but the ``log2 k`` finest
(a Haar approximation is a block mean), so an effect that acts on the slow part of the signal
(drift, temperature, geometry, moves) leaves the same evidence in the averaged session. What
lives in the finest levels does not survive it: rounding to a lattice, a low-pass filter above
the new Nyquist frequency, the shape of the noise distribution. Those effects are scored at the
recorded rate (:data:`FINE_EFFECTS`).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from apmcal.diagnosis.session.log import MagAxis, Pieces, Segment, Session, map_pieces
from apmcal.preprocessing.decimation import block_means

SLOW_RATE_HZ = 100.0    # the rate slow effects are scored at, when the recording is faster
FINE_EFFECTS = ("quantization", "lowpass_filter", "uniform_noise")
# of those, the one that still shapes the block means: a filter colours the noise across the
# whole band, so once found at the recorded rate it is part of every slow model (its cutoff
# refitted there); rounding and the noise distribution's shape average out
SHAPES_BLOCK_MEANS = ("lowpass_filter",)


def block_factor(fs: float, target_hz: float = SLOW_RATE_HZ) -> int:
    """Samples per block that bring ``fs`` [Hz] down to between ``target_hz`` and twice it (a
    power of two, so that the blocks are whole Haar levels; 1: below twice ``target_hz``).

    Parameters
    ----------
    fs : float
        Recorded sample rate [Hz].
    target_hz : float
        Lowest rate the blocks may bring it down to [Hz] (within 1 %).

    Returns
    -------
    int
        Block length k [samples], a power of two.
    """
    k = 1
    while fs / (2 * k) >= target_hz * 0.99:
        k *= 2
    return k


def _inner(i0, i1, k: int):
    """The blocks lying wholly inside the sample range(s) [i0, i1) (half-open)."""
    return -(-np.asarray(i0) // k), np.asarray(i1) // k


def _hold(h, k: int):
    a, b = _inner(h.i0, h.i1, k)
    excluded = tuple((int(x // k), int(-(-y // k))) for x, y in h.excluded)
    kept = int(b - a - sum(y - x for x, y in excluded))
    return dataclasses.replace(h, i0=int(a), i1=int(b), n=kept, excluded=excluded)


def _segment(s: Segment, k: int) -> Segment:
    a, b = _inner(s.i0, s.i1, k)
    return dataclasses.replace(s, i0=int(a), i1=int(b))


def decimated(session: Session, k: int) -> Session:
    """``session`` averaged over blocks of ``k`` samples (``k`` = 1: the session itself).

    Holds, moves and pieces keep their identity and fold, each shrunk to the blocks wholly
    inside it. The mean of ``k`` readings rounded to a step lies on a lattice of step / ``k``:
    a sensor the log stores as integers stays one, on that finer lattice (left out, the twin's
    continuous block means would differ from the real ones at the finest scale by the lattice
    alone).

    Parameters
    ----------
    session : Session
        The session at its recorded rate.
    k : int
        Block length [samples] (:func:`block_factor`).

    Returns
    -------
    Session
        Times, samples, temperature and current as block means (rate fs / k), sample
        ranges in blocks; a compass on its own slower time axis is kept as it is, its pieces
        remapped.
    """
    if k == 1:
        return session
    pc = session.pieces
    i0, i1 = _inner(pc.i0, pc.i1, k)
    pieces = Pieces(i0, np.maximum(i1, i0), pc.segment.copy(), pc.fold.copy(),
                    pc.is_hold.copy())
    out = dataclasses.replace(
        session, t=block_means(session.t, k), acc=block_means(session.acc, k),
        gyr=block_means(session.gyr, k), holds=[_hold(h, k) for h in session.holds],
        segments=[_segment(s, k) for s in session.segments], pieces=pieces,
        temp=block_means(session.temp, k), current=block_means(session.current, k),
        notes=list(session.notes),
        resolution={s: step / (1 if s == "mag" and _own_axis(session) else k)
                    for s, step in session.resolution.items()}, truncated=False,
        block_length=session.block_length * k)
    if session.mag is not None:
        out.mag = _mag(session, out, k)
    return out


def _own_axis(session: Session) -> bool:
    """Whether the compass has its own (slower) time axis, kept as it is in block means."""
    return session.mag is not None and len(session.mag.t) != len(session.t)


def _mag(session: Session, out: Session, k: int) -> MagAxis:
    m = session.mag
    if _own_axis(session):      # on its own (slower) time axis: kept, pieces remapped
        i0, i1 = map_pieces(out.t, m.t, out.pieces)
        return MagAxis(m.t, m.values, i0, i1, m.current)
    return MagAxis(out.t, block_means(m.values, k), out.pieces.i0, out.pieces.i1, out.current)
