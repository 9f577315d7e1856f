"""Framing of damaged or large .tlog and dataflash .bin files with numpy (resynchronising scans).

The rule is the sequential scan pymavlink applies: at byte ``p``, if a valid record starts there
take it and jump past it, else skip one byte and try again. Written as a loop over bytes it needs
a compiler to be fast; here it is found in vectorised steps, chunk by chunk (``CHUNK`` bytes, so
memory stays bounded whatever the file size):

1. every byte where a record could start (a MAVLink magic byte 8 bytes on, or the dataflash
   header 0xA3 0x95) is a candidate; each candidate's validity and end are computed at once
   (lengths, the next-record test, CRCs where pymavlink would check them);
2. from a valid record ending at ``e`` the scan goes to the first valid candidate at or after
   ``e`` (the bytes between are skipped: one damaged run); this successor map is searched with
   ``np.searchsorted``;
3. the records taken are the nodes reachable from the chunk's first valid candidate along the
   successor map (:func:`_reachable`).

Dataflash record lengths are learnt from FMT records as the scan meets them, so validity
depends on which FMT records the scan takes; :func:`scan_dataflash` guesses that every FMT
candidate is taken, walks, and repeats with the candidates it proved false until the guess
agrees with the walk (in practice once; see :func:`_df_chunk`). The result is the sequential
scan's, byte for byte (tests/test_corruption.py, benchmarks/readers.py).

.tlog files are read through :mod:`apmcal.sources._tlogwalk` (walkers following frame lengths,
a frame every ~40 bytes, instead of a candidate at every magic byte), which runs
:func:`_tlog_chunk` here only across damage; :func:`scan_tlog` stays as the reference the
tests compare the walkers with.
"""
from __future__ import annotations

import numpy as np

from apmcal.sources._fastscan import (
    DF_FMT_LEN,
    DF_FMT_TYPE,
    DF_HEAD1,
    DF_HEAD2,
    MAV1_MAGIC,
    MAV2_MAGIC,
    gather,
)

CHUNK = 8 << 20             # bytes of candidates examined at once (bounds memory)
_NEAR = 2048                # bytes after a failed CRC whose candidates are checked at once
_PRUNE_ROUNDS = 4           # cheap rounds before the walk by runs (see _reachable)


# ------------------------------------------------------------------------- the walk

def _reachable(succ: np.ndarray) -> np.ndarray:
    """Indices of the nodes reachable from node 0 along ``succ`` (node i → succ[i] > i;
    ``len(succ)``: none).

    A node is reachable when it is node 0 or the successor of a reachable node. Starting from
    "all nodes", a few rounds of keeping only node 0 and the successors of those kept remove
    most false candidates (most have no predecessor at all); the set is exact once a round
    changes nothing (a kept node outside the reachable set would need an endless chain of kept
    predecessors). What is left is walked run by run: among the kept nodes, a run of nodes
    each followed by the next is taken whole, so the Python loop turns once per run (once per
    damaged stretch or surviving false chain), not once per record.
    """
    m = len(succ)
    alive = np.ones(m, dtype=bool)
    inside = succ < m
    src, dst = np.flatnonzero(inside), succ[inside]
    for _ in range(_PRUNE_ROUNDS):
        kept = np.zeros(m, dtype=bool)
        kept[dst[alive[src]]] = True
        kept[0] = True
        if np.array_equal(kept, alive):
            return np.flatnonzero(alive)
        alive = kept
    idx = np.flatnonzero(alive)               # closed under succ: succ(kept) ⊆ kept
    rank = np.full(m + 1, len(idx), dtype=np.int64)
    rank[idx] = np.arange(len(idx))
    s = rank[succ[idx]]
    ends = np.flatnonzero(s != np.arange(1, len(idx) + 1))
    last = len(idx) - 1
    pieces = []
    i = 0
    while i < len(idx):
        k = int(ends[np.searchsorted(ends, i)]) if i <= (ends[-1] if len(ends) else -1) else last
        pieces.append(np.arange(i, k + 1))
        i = int(s[k])
    return idx[np.concatenate(pieces)]


class _Scan:
    """State of a sequential scan carried across chunks: position, whether a skipped run is
    open, bytes skipped, the offsets where skipped runs begin (at most ``max_damage``)."""

    def __init__(self, max_damage: int):
        self.pos = 0
        self.in_skip = False
        self.skipped = 0
        self.damage: list[int] = []
        self.max_damage = max_damage

    def _run(self, at: np.ndarray) -> None:
        room = self.max_damage - len(self.damage)
        if room > 0:
            self.damage.extend(int(x) for x in at[:room])

    def take(self, start: np.ndarray, end: np.ndarray, stop: int) -> None:
        """Account for the records ``[start, end)`` taken in file order from ``self.pos``;
        ``stop``: where the chunk's examined candidates end (used when none was taken)."""
        if not len(start):
            if stop > self.pos:
                if not self.in_skip:
                    self._run(np.array([self.pos]))
                self.in_skip = True
                self.skipped += stop - self.pos
                self.pos = stop
            return
        prev_end = np.concatenate(([self.pos], end[:-1]))
        gap = start - prev_end
        runs = np.flatnonzero(gap > 0)
        if self.in_skip and len(runs) and runs[0] == 0:
            runs = runs[1:]            # the run open at the chunk start goes on
        self._run(prev_end[runs])
        self.skipped += int(gap.sum())
        self.in_skip = False
        self.pos = int(end[-1])

    def finish(self, n: int) -> None:
        """Skip the bytes after the last record (a truncated tail)."""
        self.take(np.empty(0, np.int64), np.empty(0, np.int64), n)


def _walk(cand: np.ndarray, end: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Indices into ``cand`` of the records the sequential scan takes, starting at or before
    ``cand[0]`` (valid candidates ``ok``, record ends ``end``)."""
    node = np.flatnonzero(ok)
    if not len(node):
        return node
    succ = np.searchsorted(cand[node], end[node], side="left")
    return node[_reachable(succ)]


# ------------------------------------------------------------------------- tlog

def _tlog_candidates(buf: np.ndarray, a: int, b: int) -> np.ndarray:
    """Offsets p in [a, b) whose byte p + 8 is a MAVLink magic byte."""
    magic = buf[a + 8:b + 8]
    return a + np.flatnonzero((magic - np.uint8(MAV2_MAGIC)) < 2)   # 0xFD or 0xFE


def _tlog_frames(buf: np.ndarray, cand: np.ndarray):
    """(frame length or -1, header length, payload length, msgid) of the tlog frames whose
    MAVLink magic is at ``cand + 8``: ``_fastscan._tlog_frames`` reading the ten header bytes
    of each candidate in one gather (the bytes past the end of the file read as zeros)."""
    n = buf.shape[0]
    rows = gather(buf, cand + 8, np.minimum(n - cand - 8, 10), 10)
    v2 = rows[:, 0] == MAV2_MAGIC
    hlen = np.where(v2, 10, 6)
    plen = rows[:, 1].astype(np.int64)
    msgid = np.where(v2, rows[:, 7].astype(np.int32) | (rows[:, 8].astype(np.int32) << 8)
                     | (rows[:, 9].astype(np.int32) << 16), rows[:, 5])
    flen = 8 + hlen + plen + 2 + np.where(v2 & (rows[:, 2] & 1).astype(bool), 13, 0)
    flen[(cand + 8 + hlen > n) | (cand + flen > n)] = -1
    return flen, hlen, plen, msgid


def _tlog_chunk(buf, cand, crc_extra, max_len, wanted):
    """(indices into ``cand`` of the frames taken, frame ends, payload lengths, msgids).

    As pymavlink demands, wanted messages must pass the MAVLink CRC (with CRC_EXTRA). Other
    known messages are only framed, so to save the CRC they are accepted without it when their
    length fits the dialect and the next frame starts where expected; else the CRC decides.
    Messages unknown to the dialect cannot be CRC-checked: the next-frame test alone decides.

    CRCs are computed only for frames the walk reaches: walk assuming every unchecked CRC
    passes, check the frames taken, repeat while one fails. The last walk is exact: each
    frame it takes is valid, and every candidate it passes over to reach the next one is
    invalid (assuming more candidates valid can only add to those it could stop at).
    """
    n = buf.shape[0]
    flen, hlen, plen, msgid = _tlog_frames(buf, cand)
    end = cand + flen
    framed = flen > 0
    q = np.where(framed, end, n)
    magic = buf[np.minimum(q + 8, n - 1)]
    nxt = (q == n) | ((q + 9 <= n) & ((magic == MAV1_MAGIC) | (magic == MAV2_MAGIC)))
    nxt &= framed
    in_table = msgid < crc_extra.shape[0]
    kid = np.where(in_table, msgid, 0)
    known = in_table & (crc_extra[kid] >= 0)
    free = known & nxt & (plen <= max_len[kid]) & ~wanted[kid]
    need = framed & known & ~free
    ok = (~known & nxt) | free | need          # unchecked CRCs assumed to pass
    checked = np.zeros(len(cand), dtype=bool)
    while True:
        take = _walk(cand, end, ok)
        todo = take[need[take] & ~checked[take]]
        if not len(todo):
            return take, end, plen, msgid
        passed = _crc_matches(buf, cand[todo], hlen[todo], plen[todo], crc_extra[kid[todo]])
        if passed.all():                 # nothing the walk took changed: it stands
            return take, end, plen, msgid
        checked[todo] = True
        ok[todo] = passed
        # damage: the next walk would stop at the false candidates just after a failed one,
        # one by one; check those within _NEAR bytes at once
        failed = cand[todo[~passed]]
        lo = np.searchsorted(cand, failed, side="right")
        hi = np.searchsorted(cand, failed + _NEAR, side="right")
        near = np.zeros(len(cand) + 1, dtype=np.int64)
        np.add.at(near, lo, 1)
        np.add.at(near, hi, -1)
        near = np.flatnonzero((np.cumsum(near[:-1]) > 0) & need & ~checked)
        if len(near):
            checked[near] = True
            ok[near] = _crc_matches(buf, cand[near], hlen[near], plen[near],
                                    crc_extra[kid[near]])


def _crc_tables() -> tuple[np.ndarray, np.ndarray]:
    """Lookup tables of CRC-16/MCRF4XX (reflected polynomial 0x8408): one byte (256 entries)
    and two bytes at a time (65536 entries: a 16-bit register fed 16 bits is a function of
    register ^ word alone)."""
    t = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        t = np.where(t & 1, (t >> 1) ^ 0x8408, t >> 1)
    t8 = t.astype(np.uint16)
    w = np.arange(1 << 16, dtype=np.uint32)
    c1 = t8[w & 0xFF].astype(np.uint32)                       # the low byte, then the high
    t16 = (c1 >> 8) ^ t8[((c1 ^ (w >> 8)) & 0xFF)]
    return t8, t16.astype(np.uint16)


_CRC8, _CRC16 = _crc_tables()


def _words(buf: np.ndarray, parity: int) -> np.ndarray:
    """``buf`` as little-endian uint16 words starting at byte ``parity`` (0 or 1)."""
    m = (buf.shape[0] - parity) // 2
    return np.asarray(buf[parity:parity + 2 * m]).view("<u2")


def _crc_matches(buf, off, hlen, plen, extra) -> np.ndarray:
    """Per frame: its CRC (bytes after the magic through the payload, then CRC_EXTRA) equals
    the two bytes after its payload.

    Table-driven, two bytes per step, over all frames at once: the frames are grouped by the
    parity of their first byte (so each reads whole words of one uint16 view of the file) and
    sorted by span, longest first, so the frames still running at step j are a prefix. The same
    CRC as ``_fastscan.x25_crc_rows`` (tests/test_framing.py compares them).
    """
    good = np.empty(len(off), dtype=bool)
    span_all = (hlen - 1 + plen).astype(np.int64)
    for parity in (0, 1):
        sel = np.flatnonzero((off + 9) % 2 == parity)
        if not len(sel):
            continue
        words = _words(buf, parity)
        order = sel[np.argsort(-span_all[sel], kind="stable")]
        start = off[order] + 9
        sp = span_all[order]
        w0 = (start - parity) // 2
        crc = np.full(len(order), 0xFFFF, dtype=np.uint16)
        pairs = np.searchsorted(-sp, -2 * np.arange(1, int(sp.max()) // 2 + 1) + 1, side="left")
        for j, k in enumerate(pairs):                 # frames with span ≥ 2j + 2
            crc[:k] = _CRC16[crc[:k] ^ words[w0[:k] + j]]
        odd = np.flatnonzero(sp % 2 == 1)             # their last byte alone
        last = buf[start[odd] + sp[odd] - 1]
        crc[odd] = (crc[odd] >> 8) ^ _CRC8[(crc[odd] ^ last) & 0xFF]
        crc = (crc >> 8) ^ _CRC8[(crc ^ extra[order].astype(np.uint16)) & 0xFF]
        end = start + sp
        good[order] = ((crc & 0xFF) == buf[end]) & ((crc >> 8) == buf[end + 1])
    return good


def scan_tlog(buf: np.ndarray, crc_extra: np.ndarray, max_len: np.ndarray, wanted: np.ndarray,
              max_damage: int):
    """Frame a whole tlog as the sequential scan does, resynchronising after damage.

    Parameters
    ----------
    buf : uint8 array, the whole file (may be a memmap).
    crc_extra : int16[65536], CRC_EXTRA per msgid (-1 when unknown to the dialect).
    max_len : int16[65536], full MAVLink 2 payload length per msgid.
    wanted : bool[65536], msgids whose frames are returned.
    max_damage : at most this many damage offsets are kept.

    Returns
    -------
    (frame offsets int64 (their 8-byte stamp), payload lengths int16, msgids int32) of the
    wanted frames, bytes skipped, offsets where skipped runs begin.
    """
    n = buf.shape[0]
    st = _Scan(max_damage)
    offs, lens, mids = [], [], []
    while st.pos < n:
        a = st.pos
        b = min(n, a + CHUNK)
        cand = _tlog_candidates(buf, a, min(b, n - 8)) if n >= 9 else np.empty(0, np.int64)
        take, end, plen, msgid = _tlog_chunk(buf, cand, crc_extra, max_len, wanted)
        st.take(cand[take], end[take], b)
        if b == n and st.pos < n:
            st.finish(n)
        mid = msgid[take]
        keep = take[(mid < wanted.shape[0]) & wanted[np.minimum(mid, wanted.shape[0] - 1)]]
        offs.append(cand[keep])
        lens.append(plen[keep].astype(np.int16))
        mids.append(msgid[keep].astype(np.int32))
    if not offs:
        return (np.empty(0, np.int64), np.empty(0, np.int16), np.empty(0, np.int32)), 0, []
    return ((np.concatenate(offs), np.concatenate(lens), np.concatenate(mids)),
            st.skipped, st.damage)


# ------------------------------------------------------------------------- dataflash

class _Timeline:
    """Dataflash record length per type as the scan learns it: the lengths known before the
    chunk, then the FMT records at ``pos`` (sorted) setting ``typ`` to ``length``."""

    def __init__(self, before: np.ndarray, pos: np.ndarray, typ: np.ndarray, length: np.ndarray):
        self.before = before
        order = np.lexsort((pos, typ))
        self.key = typ[order].astype(np.int64) << 40 | pos[order]
        self.typ = typ[order]
        self.length = length[order]

    def at(self, typ: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Length of type ``typ`` known to the scan at byte ``p`` (FMT records before ``p``)."""
        typ = typ.astype(np.int64)
        out = self.before[typ]
        if not len(self.key):
            return out
        i = np.searchsorted(self.key, typ << 40 | p, side="left") - 1
        hit = i >= 0
        hit[hit] = self.typ[i[hit]] == typ[hit]
        out = out.copy()
        out[hit] = self.length[i[hit]]
        return out


def _df_valid(buf: np.ndarray, cand: np.ndarray, tl: _Timeline):
    """(valid, record end) of the dataflash records at ``cand``.

    A record is accepted when its type is known (length ≥ 3), it is complete, and the next
    record header follows it with a known type (or the file ends within three bytes); the last
    rule rejects records cut short by a truncated write, which have no checksum to reveal them.
    A FMT record may be followed by the first record of the type it defines.
    """
    n = buf.shape[0]
    typ = buf[cand + 2]
    L = tl.at(typ, cand)
    end = cand + L
    ok = (L >= 3) & (end <= n)
    q = np.where(ok & (end + 3 <= n), end, 0)
    tail = ok & (end + 3 > n)
    head = ok & ~tail & (buf[q] == DF_HEAD1) & (buf[q + 1] == DF_HEAD2)
    nt = buf[q + 2]
    known = tl.at(nt, cand) >= 3
    fmt = cand + DF_FMT_LEN <= n
    fc = np.where(fmt, cand, 0)
    defines_next = ((typ == DF_FMT_TYPE) & (L == DF_FMT_LEN) & fmt
                    & (buf[fc + 3] == nt) & (buf[fc + 4] >= 3))
    return tail | (head & (known | defines_next)), end


def _fmt_candidates(buf: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """Indices into ``cand`` of the candidates that would set a length if taken: FMT records
    (89 bytes in the file) defining a type other than FMT with a length ≥ 3."""
    n = buf.shape[0]
    i = np.flatnonzero((buf[cand + 2] == DF_FMT_TYPE) & (cand + DF_FMT_LEN <= n))
    c = cand[i]
    return i[(buf[c + 4] >= 3) & (buf[c + 3] != DF_FMT_TYPE)]


def _effect(before: np.ndarray, buf: np.ndarray, fmts: np.ndarray):
    """The length changes the FMT records at ``fmts`` (taken in order) make: (pos, type, len)
    of those that change the length in force (re-definitions to the same length dropped)."""
    typ = buf[fmts + 3].astype(np.int64)
    length = buf[fmts + 4].astype(np.int64)
    prev = np.empty_like(length)
    order = np.lexsort((fmts, typ))
    t_s, l_s = typ[order], length[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = t_s[1:] != t_s[:-1]
    p_s = np.where(first, before[t_s], np.roll(l_s, 1))
    prev[order] = p_s
    change = length != prev
    return fmts[change], typ[change], length[change]


def _df_chunk(buf: np.ndarray, cand: np.ndarray, before: np.ndarray):
    """Indices into ``cand`` of the records taken, given the lengths known before the chunk.

    The guess: every FMT candidate not yet proved false is taken. The walk under that guess is
    exact up to the first FMT candidate where the guess and the walk's own FMT records differ
    (decisions at a byte use only FMT records before it), so every candidate the walk left out
    up to there is proved false; repeat until the guess agrees with the walk. Each round proves
    at least one candidate false (the first difference is a guessed FMT record the walk left
    out: a record the walk took cannot be one proved false, as its decision is exact), so the
    rounds end; a false FMT candidate (0xA3 0x95 0x80 inside a payload) is rare.
    """
    fmt_idx = _fmt_candidates(buf, cand)
    fmt_all = cand[fmt_idx]
    false = np.zeros(len(fmt_all), dtype=bool)
    took = np.zeros(len(cand), dtype=bool)
    for _ in range(len(fmt_all) + 1):
        guess = fmt_all[~false]
        tl = _Timeline(before, *_effect(before, buf, guess))
        ok, end = _df_valid(buf, cand, tl)
        take = _walk(cand, end, ok)
        took[:] = False
        took[take] = True
        taken = took[fmt_idx]
        g_eff = _effect(before, buf, guess)
        w_eff = _effect(before, buf, fmt_all[taken])
        if all(np.array_equal(x, y) for x, y in zip(g_eff, w_eff)):
            return take, ok, end
        # first FMT candidate where guess and walk differ: all left out up to it are false
        k = min(len(g_eff[0]), len(w_eff[0]))
        diff = np.flatnonzero((g_eff[0][:k] != w_eff[0][:k]) | (g_eff[1][:k] != w_eff[1][:k])
                              | (g_eff[2][:k] != w_eff[2][:k]))
        upto = (min(g_eff[0][diff[0]], w_eff[0][diff[0]]) if len(diff)
                else (g_eff[0][k] if len(g_eff[0]) > k else w_eff[0][k]))
        newly = ~taken & ~false & (fmt_all <= upto)
        if not newly.any():
            break
        false |= newly
    raise RuntimeError("dataflash framing: FMT records did not settle")  # pragma: no cover


def scan_dataflash(buf: np.ndarray, max_damage: int):
    """Frame a whole dataflash .bin as the sequential scan does, resynchronising after damage.

    FMT records (type 0x80) define record lengths as they are met, as pymavlink's DFReader
    does. Returns (record offsets int64, types uint8, bytes skipped, offsets where skipped
    runs begin (at most ``max_damage``)).
    """
    n = buf.shape[0]
    st = _Scan(max_damage)
    lengths = np.zeros(256, dtype=np.int64)
    lengths[DF_FMT_TYPE] = DF_FMT_LEN
    offs, types = [], []
    while st.pos < n:
        a = st.pos
        b = min(n, a + CHUNK)
        hi = min(b, n - 2)
        if hi > a:
            cand = a + np.flatnonzero(buf[a:hi] == DF_HEAD1)
            cand = cand[buf[cand + 1] == DF_HEAD2]
        else:
            cand = np.empty(0, np.int64)
        take, _, end = _df_chunk(buf, cand, lengths)
        off = cand[take]
        st.take(off, end[take], b)
        if b == n and st.pos < n:
            st.finish(n)
        typ = buf[off + 2]
        fm = off[(typ == DF_FMT_TYPE) & (end[take] - off == DF_FMT_LEN)]
        fm = fm[(buf[fm + 4] >= 3) & (buf[fm + 3] != DF_FMT_TYPE)][::-1]
        defined, last = np.unique(buf[fm + 3], return_index=True)   # the last one per type
        lengths[defined] = buf[fm[last] + 4]
        offs.append(off)
        types.append(typ)
    if not offs:
        return np.empty(0, np.int64), np.empty(0, np.uint8), 0, []
    return np.concatenate(offs), np.concatenate(types), st.skipped, st.damage
