"""Framing of undamaged .tlog and dataflash .bin files up to 32 MB in one vectorised pass.

Why: most logs are undamaged:
their records tile the file from byte 0 to the end. That case is found here without a
sequential loop — every position holding a record header is a candidate, each candidate's
length gives its successor, and the records are the candidates some other record (or byte 0)
points at; the result is checked to tile the file exactly and to satisfy every rule the
sequential scan applies (types defined before use, CRCs of the wanted MAVLink messages).
When any check fails the caller falls back to the chunked scan of
:mod:`apmcal.sources._framing`, which also resynchronises after damage and returns the same
records on an undamaged file (tests/test_framing.py checks both against a byte-by-byte loop).

Functions return None for "not this fast path". Files over ``MAX_BYTES`` are left to the
chunked scan: the candidate arrays here cost ~2.5× the file in memory, there a bounded amount.
"""
from __future__ import annotations

import numpy as np

MAV1_MAGIC = 0xFE
MAV2_MAGIC = 0xFD
DF_HEAD1 = 0xA3
DF_HEAD2 = 0x95
DF_FMT_TYPE = 0x80
DF_FMT_LEN = 89
MAX_BYTES = 32 << 20        # larger files: the chunked scan (see the module docstring)


# ------------------------------------------------------------------------- gathering

def gather_fixed(buf: np.ndarray, off: np.ndarray, skip: int, width: int) -> np.ndarray:
    """(n, width) uint8 rows ``buf[off[i] + skip:][:width]`` (each row inside ``buf``).

    ``buf`` viewed as ``width``-byte items starting at every byte (stride 1, no copy) and
    indexed: one copy of ``width`` bytes per row, about twice as fast as row-indexing a 2-D
    sliding window view (and no (n, width) index array).
    """
    if not len(off) or not width:
        return np.zeros((len(off), width), dtype=np.uint8)
    items = np.ndarray(shape=(buf.shape[0] - width + 1,), dtype=f"V{width}", buffer=buf,
                       strides=(1,))
    rows = items[np.asarray(off, dtype=np.int64) + skip]
    return rows.view(np.uint8).reshape(len(rows), width)


def gather(buf: np.ndarray, off: np.ndarray, lens: np.ndarray, width: int) -> np.ndarray:
    """(n, width) rows of ``lens[i]`` bytes from ``buf[off[i]:]``, zero-padded on the right.

    MAVLink 2 truncates trailing zero bytes of a payload; the zeros restore them. Whole windows
    are copied, then each row's bytes past its length cleared, one length at a time (no (n,
    width) mask: the output is the only large allocation). Rows whose window would run past the
    end of ``buf`` are copied one by one (at most a few).
    """
    off = np.asarray(off, dtype=np.int64)
    lens = np.minimum(np.asarray(lens, dtype=np.int64), width)
    inside = off + width <= buf.shape[0]
    if inside.all():
        out = gather_fixed(buf, off, 0, width)
    else:
        out = np.zeros((len(off), width), dtype=np.uint8)
        idx = np.flatnonzero(inside)
        out[idx] = gather_fixed(buf, off[idx], 0, width)
        for i in np.flatnonzero(~inside):
            out[i, :lens[i]] = buf[off[i]:off[i] + lens[i]]
    if len(lens) and lens[0] == lens.min() == lens.max():      # one length (MAVLink 1): a slice
        out[:, int(lens[0]):] = 0
        return out
    for length in np.unique(lens[lens < width]):
        out[lens == length, length:] = 0
    return out


# ------------------------------------------------------------------------- chains

def _chain(cand: np.ndarray, nxt: np.ndarray, n: int) -> np.ndarray | None:
    """Indices into ``cand`` of the records tiling ``[0, n)``, or None.

    ``cand`` (sorted byte offsets) are possible record starts, ``nxt`` each one's successor
    offset (-1: not a valid record). A record is byte 0 or the successor of a record. Start
    from every candidate and keep, round by round, only byte 0 and the successors of those
    kept: a false candidate (header bytes inside a payload) is pointed at, if at all, only by
    other false candidates (a record's successor is a record), and offsets only grow, so such
    chains die out in a few rounds (a MAVLink magic byte sits at 1/128 of the positions: a
    false chain of d links survives ~128^-d). The records must then follow one another
    exactly, the last ending at ``n``.
    """
    if not len(cand) or cand[0] != 0:
        return None
    succ = np.searchsorted(cand, nxt)
    hit = (nxt >= 0) & (succ < len(cand))
    hit[hit] = cand[succ[hit]] == nxt[hit]
    succ = succ[hit]
    source = np.flatnonzero(hit)
    alive = np.ones(len(cand), dtype=bool)
    for _ in range(64):
        kept = np.zeros(len(cand), dtype=bool)
        kept[succ[alive[source]]] = True
        kept[0] = True
        if np.array_equal(kept, alive):
            break
        alive = kept
    else:
        return None
    idx = np.flatnonzero(alive)
    chain_next = nxt[idx]
    if np.any(chain_next[:-1] != cand[idx[1:]]) or chain_next[-1] != n:
        return None
    return idx


# ------------------------------------------------------------------------- dataflash

def _df_lengths(buf: np.ndarray, fmt_off: np.ndarray, strict: bool) -> np.ndarray | None:
    """Record length per type from the FMT records at ``fmt_off`` (int64[256]).

    ``strict``: None when a type is defined twice with different lengths (the sequential scan
    then decides); else the first definition of each type counts (candidates may include
    header bytes inside payloads, checked later).
    """
    lengths = np.zeros(256, dtype=np.int64)
    lengths[DF_FMT_TYPE] = DF_FMT_LEN
    types, lens = buf[fmt_off + 3].astype(np.int64), buf[fmt_off + 4].astype(np.int64)
    keep = (lens >= 3) & (types != DF_FMT_TYPE)
    types, lens = types[keep], lens[keep]
    _, first = np.unique(types, return_index=True)
    lengths[types[first]] = lens[first]
    if strict and np.any(lengths[types] != lens):
        return None
    return lengths


def scan_dataflash(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(record offsets int64, types uint8) of an undamaged dataflash log, or None.

    The same records as ``_framing.scan_dataflash`` with nothing skipped: each record's type
    is defined by an FMT record before it (or by the record just before it, an FMT defining
    the next type), no type changes length, and the records tile the file.
    """
    n = buf.shape[0]
    if n < 3 or n > MAX_BYTES:
        return None
    cand = np.flatnonzero((buf[:-2] == DF_HEAD1) & (buf[1:-1] == DF_HEAD2))
    typ = buf[cand + 2]
    is_fmt = (typ == DF_FMT_TYPE) & (cand + DF_FMT_LEN <= n)
    lengths = _df_lengths(buf, cand[is_fmt], strict=False)
    L = lengths[typ]
    nxt = np.where((L >= 3) & (cand + L <= n), cand + L, -1)
    idx = _chain(cand, nxt, n)
    if idx is None:
        return None
    off, typ = cand[idx], typ[idx]
    return (off, typ) if _defined_before_use(buf, off, typ) else None


def _defined_before_use(buf: np.ndarray, off: np.ndarray, typ: np.ndarray) -> bool:
    """Every type's first record comes after the first FMT record defining it (so the
    sequential scan, which learns lengths as it goes, accepts it), and the FMT records of the
    chain define the lengths the chain was built with."""
    fmt = np.flatnonzero(typ == DF_FMT_TYPE)
    defined = buf[off[fmt] + 3]
    lengths = _df_lengths(buf, off[fmt], strict=True)
    if lengths is None:
        return False
    first_def = np.full(256, len(off), dtype=np.int64)
    np.minimum.at(first_def, defined, fmt)
    first_use = np.full(256, len(off), dtype=np.int64)
    plain = typ != DF_FMT_TYPE
    np.minimum.at(first_use, typ[plain], np.flatnonzero(plain))
    used = first_use < len(off)
    return bool(np.all(first_def[used] < first_use[used])
                and np.all(lengths[np.flatnonzero(used)] >= 3))


# ------------------------------------------------------------------------- tlog

def _tlog_frames(buf: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, ...]:
    """(frame length or -1, header length, payload length, msgid) of tlog frames whose
    MAVLink magic is at ``cand + 8`` (8-byte timestamp first)."""
    n = buf.shape[0]
    v2 = buf[cand + 8] == MAV2_MAGIC
    hlen = np.where(v2, 10, 6)
    complete = cand + 8 + hlen <= n
    c = np.where(complete, cand, 0)

    def at(k: int) -> np.ndarray:       # byte k of each frame (clipped: a v1 frame at the end
        return buf[np.minimum(c + k, n - 1)].astype(np.int64)   # has no bytes 15..17)

    plen = at(9)
    msgid = np.where(v2, at(15) | (at(16) << 8) | (at(17) << 16), at(13))
    sig = np.where(v2 & (at(10) & 1).astype(bool), 13, 0)
    flen = 8 + hlen + plen + 2 + sig
    flen = np.where(complete & (cand + flen <= n), flen, -1)
    return flen, hlen, plen, msgid


def x25_crc_rows(rows: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """MAVLink CRC-16/MCRF4XX of each row of ``rows`` (k, m) uint8, then its CRC_EXTRA byte,
    column by column over all k frames at once (the bitwise steps of the MAVLink C library)."""
    crc = np.full(rows.shape[0], 0xFFFF, dtype=np.int64)
    for col in (*rows.T.astype(np.int64), np.asarray(extra, dtype=np.int64)):
        tmp = (col ^ crc) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


def _crc_ok(buf, off, hlen, plen, extra) -> bool:
    """True when every frame's CRC (bytes after the magic through the payload, then
    CRC_EXTRA) matches the two bytes after its payload; frames grouped by span length."""
    span = hlen - 1 + plen
    for m in np.unique(span):
        sel = np.flatnonzero(span == m)
        rows = gather_fixed(buf, off[sel], 9, int(m) + 2)
        crc = x25_crc_rows(rows[:, :m], extra[sel])
        if np.any((crc & 0xFF) != rows[:, m]) or np.any((crc >> 8) != rows[:, m + 1]):
            return False
    return True


def scan_tlog(buf: np.ndarray, crc_extra: np.ndarray, max_len: np.ndarray,
              wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(frame offsets int64, payload lengths int16, msgids int32) of the wanted messages of an
    undamaged tlog, or None.

    The frames must tile the file; as in ``_framing._tlog_frame_ok`` a wanted message, or a
    known one longer than its dialect allows, must pass its CRC; other known and unknown
    messages are accepted framed (the next frame starts where expected, here always).
    """
    n = buf.shape[0]
    if n < 9 or n > MAX_BYTES:
        return None
    magic = buf[8:]
    cand = np.flatnonzero((magic == MAV1_MAGIC) | (magic == MAV2_MAGIC))
    flen, hlen, plen, msgid = _tlog_frames(buf, cand)
    idx = _chain(cand, np.where(flen > 0, cand + flen, -1), n)
    if idx is None:
        return None
    off, hlen, plen, msgid = cand[idx], hlen[idx], plen[idx], msgid[idx]
    known_id = np.where(msgid < crc_extra.shape[0], msgid, 0)
    known = (msgid < crc_extra.shape[0]) & (crc_extra[known_id] >= 0)
    want = known & wanted[known_id]
    check = want | (known & (plen > max_len[known_id]))
    sel = np.flatnonzero(check)
    if not _crc_ok(buf, off[sel], hlen[sel], plen[sel], crc_extra[known_id[sel]]):
        return None
    w = np.flatnonzero(want)
    return off[w], plen[w].astype(np.int16), msgid[w].astype(np.int32)


def tlog_frame_at(head: bytes, p: int, crc_extra: np.ndarray) -> int:
    """msgid of a CRC-checked tlog frame of a known message starting at ``p`` of ``head``, or
    -1 (the format sniffer's test: a few bytes, so plain Python)."""
    b = head
    if p + 9 > len(b) or b[p + 8] not in (MAV1_MAGIC, MAV2_MAGIC):
        return -1
    v2 = b[p + 8] == MAV2_MAGIC
    hlen = 10 if v2 else 6
    if p + 8 + hlen > len(b):
        return -1
    plen = b[p + 9]
    msgid = (b[p + 15] | (b[p + 16] << 8) | (b[p + 17] << 16)) if v2 else b[p + 13]
    end = p + 8 + hlen + plen
    if end + 2 > len(b) or msgid >= crc_extra.shape[0] or crc_extra[msgid] < 0:
        return -1
    row = np.frombuffer(b[p + 9:end], dtype=np.uint8)[None, :]
    crc = int(x25_crc_rows(row, [int(crc_extra[msgid])])[0])
    return msgid if (crc & 0xFF) == b[end] and (crc >> 8) == b[end + 1] else -1
