"""Framing of big or damaged .tlog files by many walkers stepping in lockstep (numpy).

Why: the chunked scan of :mod:`apmcal.sources._framing` examines every byte where a frame could
start (a MAVLink magic byte 8 bytes on); a .tlog has a frame every ~40 bytes and a false
candidate every ~128 besides, so most of its time goes to candidates. Here the file is cut into
segments of ``SEGMENT`` bytes and one walker per segment follows frame lengths, all walkers
one step at a time in a single numpy operation (a step reads the 8 bytes after every walker's
stamp with one gather and looks the frame length up in a table): the work follows the frames,
not the bytes, with a few numpy calls per step for all walkers (:func:`propose`).

A walker starts ``PREROLL`` bytes before its segment (by then it has found the frame chain:
false starts die within a frame or two) and records the positions it stands on inside its
segment; on a byte that cannot start a frame it steps one byte. The recorded positions are
only proposals: each is then validated at once by the rule of the sequential scan (the same
as ``_framing._tlog_chunk``: lengths, the next-frame test, the MAVLink CRC where pymavlink
checks it; :func:`_validate`), and the sequential scan is replayed over them
(:func:`_replay`): from a valid proposal it takes the run of proposals that follow one another
and are valid; where it stands on a byte no valid proposal covers (damage, a segment whose
walker had not found its feet, the file's tail) it follows the valid frames among all bytes
just after the run ends (:func:`_gap_frames`), and past those the exact chunked scan of
:mod:`apmcal.sources._framing`, until it stands on a valid proposal again. The result is
therefore the sequential scan's, byte for byte, whatever the walkers proposed
(tests/test_tlog_walk_reader.py compares it with a byte-by-byte loop, with small segments and
blocks so damage straddles their ends); the walkers only decide how fast it is found. Files
are processed in blocks of ``BLOCK`` bytes, the scan carried across (bounded memory).
docs/tlog-walkers.md describes the design and its measurements.
"""
from __future__ import annotations

import numpy as np

from apmcal.sources import _framing
from apmcal.sources._fastscan import MAV1_MAGIC, MAV2_MAGIC

SEGMENT = 16 << 10          # bytes per walker
BLOCK = 128 << 20           # bytes walked, validated and replayed at once (bounds memory)
_INT32_MAX = (1 << 31) - 1024   # smaller files keep positions as int32
PREROLL = 512               # bytes a walker walks before its segment (finding its feet)
_CHECK_EVERY = 8            # steps between tests whether every walker is done
_WINDOW = 2048              # bytes of the first exact scan where no proposal is valid
_MAX_WINDOW = _framing.CHUNK
_ROWS_MIN = 64              # frames of one span worth a gather of rows (crc_matches)


def _step_table() -> np.ndarray:
    """int32[2**17]: frame length (8-byte stamp included) indexed by the magic byte, the
    payload length byte and bit 0 of the next byte (MAVLink 2 incompat flags: signed, 13 more
    bytes); 1 where the magic byte is not MAVLink's (the walker steps one byte)."""
    idx = np.arange(1 << 17, dtype=np.int64)
    magic, plen, signed = idx & 0xFF, (idx >> 8) & 0xFF, idx >> 16
    out = np.ones(1 << 17, dtype=np.int32)
    out[magic == MAV1_MAGIC] = (8 + 6 + 2 + plen[magic == MAV1_MAGIC])
    v2 = magic == MAV2_MAGIC
    out[v2] = 8 + 10 + 2 + plen[v2] + 13 * signed[v2]
    return out


_STEP = _step_table()


def _at_every_byte(buf: np.ndarray, dtype: str) -> np.ndarray:
    """``buf`` as ``dtype`` items starting at every byte (a stride-1 view, no copy)."""
    size = np.dtype(dtype).itemsize
    return np.ndarray(shape=(max(buf.shape[0] - size + 1, 0),), dtype=dtype, buffer=buf,
                      strides=(1,))


def _pack(w: np.ndarray) -> np.ndarray:
    """The header word of a frame from the 8 bytes after its stamp (little-endian uint64):
    bits 0-16 the magic byte, payload length and bit 0 of the next byte (:data:`_STEP`'s
    index), bits 17-24 byte 13 of the frame (the msgid of a MAVLink 1 frame)."""
    return ((w & 0x1FFFF) | ((w >> 23) & 0x1FE0000)).astype(np.uint32)


def _heads(buf: np.ndarray, at: np.ndarray) -> np.ndarray:
    """:func:`_pack` of the frames at ``at`` (reads past the file's end are clipped: such
    frames cannot be complete, and the lengths read make them end past it all the same)."""
    n = buf.shape[0]
    if n < 16:
        return np.zeros(len(at), dtype=np.uint32)
    return _pack(_at_every_byte(buf, "<u8")[np.minimum(at + 8, n - 8)])


def _stamp_top(buf: np.ndarray, tops: np.ndarray) -> int:
    """The two top bytes (as a little-endian uint16) most common among the stamps of the
    positions in the first 64 kB whose byte 8 on is a MAVLink magic byte: frames outnumber
    false candidates there, so a file whose first bytes are not a stamp (its head cut or
    damaged) still gets its walkers' stamp test right."""
    head = buf[8:min(buf.shape[0], (64 << 10) + 8)]
    cand = np.flatnonzero((head - np.uint8(MAV2_MAGIC)) < 2)
    if not len(cand):
        return int(tops[0])
    values, counts = np.unique(tops[cand], return_counts=True)
    return int(values[np.argmax(counts)])


def propose(buf: np.ndarray, segment: int = SEGMENT, preroll: int = PREROLL, lo: int = 0,
            hi: int | None = None, top: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sorted offsets where the walkers stood in ``[lo, hi)`` (default: the whole file; int32
    in files under 2 GB: half the memory traffic of int64 in every pass over them), and the
    :func:`_pack` header word read there.

    Walker k starts at ``lo + k * segment - preroll`` (walker 0 of the file at byte 0) and
    records the positions in its segment ``lo + [k * segment, (k + 1) * segment)``; positions
    are therefore unique and, read walker by walker, in file order. A step reads the frame
    length at the walker's position (one byte on where no MAVLink magic byte is). A walker
    finding its feet (at its start, and after each one-byte step) also demands that the
    stamp's two top bytes be the file's (``top``, by default :func:`_stamp_top`; they change
    once in 8.9 years of µs): without that it would stop on a 0xFD inside the stamp before a
    frame (3 bytes before it, so met first when stepping byte by byte) and could stay off the
    chain for a whole segment. A walker stops once past its segment or after as many steps as
    its span could hold frames (a run of bytes that are no frame leaves the rest of its
    segment to the exact scan); walkers that are done are dropped from the arrays every
    ``_CHECK_EVERY`` steps.
    """
    n = buf.shape[0]
    hi = n if hi is None else hi
    if n < 16 or hi <= lo:
        return np.empty(0, np.int64), np.empty(0, np.uint32)
    k = -(-(hi - lo) // segment)
    seg_start = lo + np.arange(k, dtype=np.int64) * segment
    words = _at_every_byte(buf, "<u8")
    tops = _at_every_byte(buf, "<u2")
    top = _stamp_top(buf, tops) if top is None else top
    cap = (segment + preroll) // 16 + 2
    small = n < _INT32_MAX
    at = np.empty((cap, k), dtype=np.int32 if small else np.int64)     # rows filled as used
    head = np.empty((cap, k), dtype=np.uint32)
    ids = slice(None)                          # all walkers; an index array once some are done
    pos = np.maximum(seg_start - preroll, 0)
    end_all = end = np.minimum(seg_start + segment, hi)
    lost = np.ones(k, dtype=bool)              # finding its feet: the stamp is tested too
    idx = np.empty(k, dtype=np.int64)
    rows = 0                                               # rows of ``at`` written
    for step in range(cap):
        if step % _CHECK_EVERY == 0:
            going = pos < end
            if not going.any():
                break
            if going.sum() < 0.75 * len(pos):
                keep = np.flatnonzero(going)
                ids = keep if isinstance(ids, slice) else ids[keep]
                pos, end, lost = pos[keep], end[keep], lost[keep]
                idx = np.empty(len(pos), dtype=np.int64)
        np.add(pos, 8, out=idx)
        np.minimum(idx, n - 8, out=idx)
        w = words[idx]
        low = w & 0x1FFFF
        flen = np.take(_STEP, low.view(np.int64))        # np.take: a fast path for intp
        w >>= 23                                           # :func:`_pack`, in place
        w &= 0x1FE0000
        w |= low
        seek = np.flatnonzero(lost)
        if len(seek):
            flen[seek[tops[idx[seek] - 8] != top]] = 1
        np.equal(flen, 1, out=lost)
        if not isinstance(ids, slice):
            at[step] = -1                                  # walkers done: nothing
        at[step, ids] = pos
        head[step, ids] = w
        pos += flen
        rows = step + 1
    at = at[:rows].T                                       # (walker, step): file order
    inside = ((at - seg_start[:, None].astype(at.dtype)).view(np.uint32 if small else np.uint64)
              < (end_all - seg_start)[:, None])            # -1 and past the end: huge
    return at[inside], head[:rows].T[inside]


def _fields(buf: np.ndarray, at: np.ndarray, head: np.ndarray):
    """(payload length, msgid) as int32 of the frames at ``at`` with header words ``head``
    (a MAVLink 2 msgid, three bytes, is read from the file)."""
    n = buf.shape[0]
    plen = ((head >> 8) & 0xFF).astype(np.int32)
    msgid = (head >> 17).astype(np.int32)
    two = np.flatnonzero((head & 0xFF) == MAV2_MAGIC)
    if len(two):
        b = _at_every_byte(buf, "<u4")[np.minimum(at[two] + 14, n - 4)]
        msgid[two] = (b >> 8).astype(np.int32)
    return plen, msgid


def _validate(buf, at, crc_extra, max_len, wanted, head=None):
    """Per proposal: (valid, frame end), by the sequential scan's rule (that of
    ``_framing._tlog_chunk``, with every CRC it would need computed); the header words; the
    indices of the valid frames of wanted messages (all of which needed their CRC).

    ``head``: the :func:`_pack` header words (read here when None). The next-frame test is
    read from the proposals where a frame ends on the next one (almost everywhere), from the
    file elsewhere. MAVLink 1 frames are classed by one table look-up on (msgid, payload
    length); MAVLink 2 ones field by field.
    """
    n = buf.shape[0]
    m = len(at)
    if head is None:
        head = _heads(buf, at)
    word = head.astype(np.intp)                     # np.take is fastest with intp indices
    flen = np.take(_STEP, word & 0x1FFFF)
    end = at + flen
    magic = flen > 1
    nxt = np.zeros(m, dtype=bool)
    np.equal(end[:-1], at[1:], out=nxt[:-1])
    nxt[:-1] &= magic[1:]
    tail = int(np.searchsorted(at, at.dtype.type(max(n - 320, 0))))   # may run past the end
    # (keys of ``at``'s dtype: else numpy converts all of ``at`` to search it)
    framed = magic.copy()
    framed[tail:] &= end[tail:] <= n
    rest = np.flatnonzero(~nxt & framed)
    rest = np.union1d(rest, tail + np.flatnonzero(framed[tail:]))
    if len(rest):
        q = end[rest]
        nxt[rest] = (q == n) | ((q + 9 <= n)
                               & (buf[np.minimum(q + 8, n - 1)] - np.uint8(MAV2_MAGIC) < 2))
    word >>= 8
    code = np.take(_classes(crc_extra, max_len, wanted), word)
    del word
    two = np.flatnonzero(((head & 0xFF) == MAV2_MAGIC) & framed)
    if len(two):
        plen, msgid = _fields(buf, at[two], head[two])
        kid = np.where(msgid < crc_extra.shape[0], msgid, 0)
        known = (msgid < crc_extra.shape[0]) & (crc_extra[kid] >= 0)
        light = (plen <= max_len[kid]) & ~wanted[kid]
        code[two] = np.where(known, np.where(light, _FREE, _NEED), _UNKNOWN)
    valid = (code < _NEED) & nxt & framed             # _UNKNOWN, _FREE: the next frame decides
    need = np.flatnonzero((code != _UNKNOWN) & ~valid & framed)   # else the CRC decides
    plen, msgid = _fields(buf, at[need], head[need])
    kid = np.minimum(msgid, crc_extra.shape[0] - 1)
    hlen = np.where((head[need] & 0xFF) == MAV2_MAGIC, 10, 6)
    passed = crc_matches(buf, at[need], hlen, plen.astype(np.int64), crc_extra[kid])
    valid[need] = passed
    return valid, end, head, need[passed & wanted[kid]]


_UNKNOWN, _FREE, _NEED = 0, 1, 2


def _classes(crc_extra, max_len, wanted) -> np.ndarray:
    """uint8[2**17] indexed by a MAVLink 1 frame's header word >> 8 (bits 0-7 payload length,
    bit 8 ignored, bits 9-16 msgid): _UNKNOWN (not in the dialect: the next-frame test
    decides), _FREE (known, not wanted, length within the dialect's: accepted when the next
    frame follows, else its CRC decides), _NEED (its CRC decides)."""
    key = (crc_extra[:256].tobytes(), max_len[:256].tobytes(), wanted[:256].tobytes())
    hit = _CLASS_CACHE.get(key)
    if hit is None:
        i = np.arange(1 << 17)
        mid, plen = i >> 9, i & 0xFF
        known = crc_extra[mid] >= 0
        light = (plen <= max_len[mid]) & ~wanted[mid]
        hit = np.where(known, np.where(light, _FREE, _NEED), _UNKNOWN).astype(np.uint8)
        _CLASS_CACHE.clear()
        _CLASS_CACHE[key] = hit
    return hit


_CLASS_CACHE: dict = {}


def crc_matches(buf, off, hlen, plen, extra) -> np.ndarray:
    """Per frame at ``off`` (its stamp): its MAVLink CRC (bytes after the magic through the
    payload, then CRC_EXTRA) equals the two bytes after its payload. The same CRC as
    ``_framing._crc_matches`` (tests compare them), faster on many frames: the frames of a
    span shared by at least ``_ROWS_MIN`` frames are copied as rows in one gather (in file
    order, so memory is read forward), the rows turned into columns, and the CRC run two bytes
    a step down the columns; the other frames (damage: false frames of every length) go to
    ``_framing._crc_matches`` together."""
    n = buf.shape[0]
    good = np.zeros(len(off), dtype=bool)
    if not len(off):
        return good
    span = (hlen - 1 + plen).astype(np.int16)
    order = np.argsort(span, kind="stable")        # a radix sort on int16
    cuts = np.flatnonzero(np.diff(span[order])) + 1
    rest = []
    for sel in np.split(order, cuts):
        m = int(span[sel[0]])
        width = m + 2 + (m % 2)             # the span, the two CRC bytes, even
        start = off[sel] + 9
        ok = start + width <= n             # rows that would run off the file: the other CRC
        if len(sel) < _ROWS_MIN or not ok.any():
            rest.append(sel)
            continue
        if not ok.all():
            rest.append(sel[~ok])
            sel, start = sel[ok], start[ok]
        rows = _at_every_byte(buf, f"V{width}")[start].view(np.uint8).reshape(-1, width)
        words = np.ascontiguousarray(rows.view("<u2")[:, :m // 2].T)     # a column a row
        crc = np.full(len(sel), 0xFFFF, dtype=np.uint16)
        tmp = np.empty_like(crc)
        for j in range(m // 2):             # np.take into a buffer: ~5x faster than crc = T[i]
            np.bitwise_xor(crc, words[j], out=tmp)
            np.take(_CRC16, tmp, out=crc)
        if m % 2:
            crc = (crc >> 8) ^ _CRC8[(crc ^ rows[:, m - 1]) & 0xFF]
        crc = (crc >> 8) ^ _CRC8[(crc ^ extra[sel].astype(np.uint16)) & 0xFF]
        good[sel] = ((crc & 0xFF) == rows[:, m]) & ((crc >> 8) == rows[:, m + 1])
    if rest:
        few = np.concatenate(rest)
        good[few] = _framing._crc_matches(buf, off[few], hlen[few], plen[few], extra[few])
    return good


_CRC8, _CRC16 = _framing._CRC8, _framing._CRC16


def _exact(buf, a, width, crc_extra, max_len, wanted):
    """The chunked scan's records taken from byte ``a`` over candidates in ``[a, a + width)``:
    (starts, ends, payload lengths, msgids)."""
    n = buf.shape[0]
    b = min(n, a + width)
    hi = min(b, n - 8)
    cand = _framing._tlog_candidates(buf, a, hi) if hi > a else np.empty(0, np.int64)
    take, end, plen, msgid = _framing._tlog_chunk(buf, cand, crc_extra, max_len, wanted)
    return cand[take], end[take], plen[take], msgid[take], b


def _gap_frames(buf, at, valid, end, link, crc_extra, max_len, wanted):
    """The frames that can start in the bytes after the runs of valid proposals, all at once.

    Where a run ends and the next valid proposal does not follow, the replay needs the
    sequential scan from there on until it meets a valid proposal again (a damaged stretch,
    typically a few hundred bytes). Every byte in ``_WINDOW`` bytes after each run end is
    examined here in one vectorised pass: the candidates there (a MAVLink magic byte 8 on) are
    validated by the same rule as the proposals (``link``: proposal i is valid and ends where
    the valid proposal i + 1 starts). Returns (interval starts, interval ends: the
    examined bytes, merged; the valid candidates' starts, ends, payload lengths, msgids).
    """
    n = buf.shape[0]
    q = end[np.flatnonzero(valid & np.append(~link, True))]
    q = np.concatenate(([0], q[q < n]))
    lo = np.unique(q)
    hi = np.minimum(lo + _WINDOW, n)
    keep = np.ones(len(lo), dtype=bool)                 # merge overlapping windows
    reach = np.maximum.accumulate(hi)
    keep[1:] = lo[1:] > reach[:-1]
    starts = lo[keep]
    ends = reach[np.append(np.flatnonzero(keep)[1:] - 1, len(lo) - 1)]
    span = np.minimum(ends, n - 8) - starts
    span = np.maximum(span, 0)
    total = int(span.sum())
    if total == 0:
        e = np.empty(0, np.int64)
        return starts, ends, e, e, e, e
    rel = np.arange(total) - np.repeat(np.cumsum(span) - span, span)
    pos = np.repeat(starts, span) + rel
    cand = pos[(buf[pos + 8] - np.uint8(MAV2_MAGIC)) < 2]
    ok, cend, head, _ = _validate(buf, cand, crc_extra, max_len, wanted)
    g = np.flatnonzero(ok)
    return (starts, ends, cand[g], cend[g], *_fields(buf, cand[g], head[g]))


def _replay(buf, at, valid, end, crc_extra, max_len, wanted, pos: int, stop: int):
    """Records of the sequential scan from byte ``pos`` until it passes ``stop``, over the
    proposals ``at`` (sorted; valid ones end at ``end``): (pieces in file order, where the
    scan stands after them). Pieces are index ranges ``(i, j)`` of ``at`` (runs of valid
    proposals each ending where the next begins) and (starts, ends, payload lengths, msgids)
    of the records between them.

    Between runs the sequential scan is followed frame by frame over the valid frames of
    :func:`_gap_frames` while it stays inside the bytes examined there, else by the exact
    chunked scan of :mod:`apmcal.sources._framing` (a long damaged stretch).
    """
    m = len(at)
    link = valid[:-1] & valid[1:] & (end[:-1] == at[1:])
    run_last = np.flatnonzero(np.append(~link, True))
    lo, hi, gs, ge, gp, gm = _gap_frames(buf, at, valid, end, link, crc_extra, max_len, wanted)
    pieces, loose = [], []                 # loose: gap frames taken one by one (indices)

    def flush():
        if loose:
            sel = np.array(loose)
            pieces.append((gs[sel], ge[sel], gp[sel], gm[sel]))
            loose.clear()

    key = at.dtype.type
    width = _WINDOW
    while pos < stop:
        i = int(np.searchsorted(at, key(pos)))        # (a key of another dtype: a copy of at)
        if i < m and at[i] == pos and valid[i]:
            flush()
            j = int(run_last[np.searchsorted(run_last, i)])
            pieces.append((i, j + 1))
            pos = int(end[j])
            width = _WINDOW
            continue
        w = int(np.searchsorted(lo, pos, side="right")) - 1
        if w >= 0 and pos < hi[w]:                     # inside examined bytes
            c = int(np.searchsorted(gs, pos))
            if c < len(gs) and gs[c] < hi[w]:
                if gs[c] > pos:                        # bytes skipped up to a valid frame
                    pos = int(gs[c])
                    continue                           # (it may be a valid proposal)
                loose.append(c)
                pos = int(ge[c])
            else:
                pos = int(hi[w])                       # no frame starts in the rest
            continue
        flush()
        s, e, pl, mid, b = _exact(buf, pos, width, crc_extra, max_len, wanted)
        if len(s):
            # keys of ``at``'s dtype: else numpy converts all of ``at`` on every call
            k = np.minimum(np.searchsorted(at, s.astype(at.dtype)), m - 1)
            land = np.flatnonzero((at[k] == s) & valid[k]) if m else np.empty(0, np.int64)
            cut = int(land[0]) if len(land) else len(s)
            if cut:
                pieces.append((s[:cut], e[:cut], pl[:cut], mid[:cut]))
            pos = int(s[cut]) if len(land) else int(e[-1])
        else:
            pos = b
        width = min(2 * width, _MAX_WINDOW)      # long damage: fewer, larger exact scans
    flush()
    return pieces, pos


def scan_tlog(buf: np.ndarray, crc_extra: np.ndarray, max_len: np.ndarray, wanted: np.ndarray,
              max_damage: int, segment: int = SEGMENT):
    """Frame a whole tlog as the sequential scan does; the same result as
    ``_framing.scan_tlog`` (see there for the parameters and the return).

    Blocks of ``BLOCK`` bytes are walked, validated and replayed one after the other, the scan
    carried from one to the next, so memory stays bounded whatever the file size.
    """
    n = buf.shape[0]
    top = _stamp_top(buf, _at_every_byte(buf, "<u2")) if n >= 16 else 0
    spans, offs, lens, mids = [], [], [], []
    pos = 0
    for lo in range(0, n, BLOCK):
        hi = min(lo + BLOCK, n)
        if pos >= hi:
            continue
        at, head = propose(buf, segment, lo=lo, hi=hi, top=top)
        valid, end, head, want = _validate(buf, at, crc_extra, max_len, wanted, head)
        pieces, pos = _replay(buf, at, valid, end, crc_extra, max_len, wanted, pos, hi)
        for p in pieces:
            if len(p) == 2:                 # a run: no gap inside, its wanted frames known
                i, j = p
                spans.append((at[i:i + 1], end[j - 1:j]))
                w = want[np.searchsorted(want, i):np.searchsorted(want, j)]
                plen, msgid = _fields(buf, at[w], head[w])
                offs.append(at[w])
                lens.append(plen)
                mids.append(msgid)
            else:
                s, e, pl, mid = p
                spans.append((s, e))
                w = np.flatnonzero((mid < wanted.shape[0])
                                   & wanted[np.minimum(mid, wanted.shape[0] - 1)])
                offs.append(s[w])
                lens.append(pl[w])
                mids.append(mid[w])
    st = _framing._Scan(max_damage)
    if spans:
        st.take(np.concatenate([a for a, _ in spans]).astype(np.int64),
                np.concatenate([b for _, b in spans]).astype(np.int64), n)
    st.finish(n)
    if not offs:
        empty = (np.empty(0, np.int64), np.empty(0, np.int16), np.empty(0, np.int32))
        return empty, st.skipped, st.damage
    return ((np.concatenate(offs).astype(np.int64), np.concatenate(lens).astype(np.int16),
             np.concatenate(mids).astype(np.int32)), st.skipped, st.damage)
