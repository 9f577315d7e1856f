"""Compiled framing scans for .tlog and dataflash .bin files (numba).

Why hand-written: pymavlink decodes every packet in Python (a few MB/s). Finding frame boundaries
is inherently sequential, so it is done here in one compiled pass; field decoding is then
vectorised with numpy structured dtypes on the gathered records (see tlog.py / dataflash.py).

Every scan is resumable: it writes at most ``len(out_off)`` records, and its ``state`` array
(``[pos, bytes_skipped, n_damage]``) lets the caller continue where it stopped. This keeps the
index arrays bounded whatever the file size.
"""
from __future__ import annotations

import numpy as np
from numba import njit

# the wire constants, shared with the numpy fast path (which must not import numba)
from apmcal.sources._fastscan import DF_FMT_LEN, DF_FMT_TYPE, DF_HEAD1, DF_HEAD2, MAV1_MAGIC, MAV2_MAGIC

# state vector layout
POS, SKIPPED, NDAMAGE = 0, 1, 2


@njit(cache=True, nogil=True)
def x25_crc(buf, start, stop, extra):
    """MAVLink CRC-16/MCRF4XX over ``buf[start:stop]`` followed by the CRC_EXTRA byte."""
    crc = 0xFFFF
    for i in range(start, stop):
        tmp = (buf[i] ^ crc) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    tmp = (extra ^ crc) & 0xFF
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF


@njit(cache=True, nogil=True)
def _tlog_frame_len(buf, p, n):
    """Length of the tlog frame (8-byte stamp + MAVLink packet) at ``p``, or -1 if no magic."""
    if p + 9 > n:
        return -1, 0, 0, 0
    magic = buf[p + 8]
    if magic == MAV1_MAGIC:
        if p + 14 > n:
            return -1, 0, 0, 0
        plen = np.int64(buf[p + 9])
        msgid = np.int64(buf[p + 13])
        return 8 + 6 + plen + 2, 6, plen, msgid
    if magic == MAV2_MAGIC:
        if p + 18 > n:
            return -1, 0, 0, 0
        plen = np.int64(buf[p + 9])
        msgid = (np.int64(buf[p + 15]) | (np.int64(buf[p + 16]) << 8)
                 | (np.int64(buf[p + 17]) << 16))
        sig = 13 if (buf[p + 10] & 1) else 0
        return 8 + 10 + plen + 2 + sig, 10, plen, msgid
    return -1, 0, 0, 0


@njit(cache=True, nogil=True)
def _next_is_frame(buf, q, n):
    """True when a tlog frame could start at ``q`` (MAVLink magic after the stamp) or q is EOF."""
    return q == n or (q + 9 <= n and (buf[q + 8] == MAV1_MAGIC or buf[q + 8] == MAV2_MAGIC))


@njit(cache=True, nogil=True)
def _tlog_frame_ok(buf, p, n, crc_extra, max_len, wanted):
    """(frame length, header length, payload length, msgid) if a valid frame starts at ``p``.

    Wanted messages must pass the MAVLink CRC (with CRC_EXTRA), exactly as pymavlink demands.
    Other messages are only framed, so to save the CRC they are accepted without it when their
    msgid is known, their length fits the dialect and the next frame starts where expected; if
    any of that fails the CRC decides. Messages unknown to the dialect cannot be CRC-checked and
    are accepted on the next-frame test alone.
    """
    flen, hlen, plen, msgid = _tlog_frame_len(buf, p, n)
    if flen < 0 or p + flen > n:
        return -1, 0, 0, 0
    known = msgid < crc_extra.shape[0] and crc_extra[msgid] >= 0
    nxt = _next_is_frame(buf, p + flen, n)
    if known:
        if nxt and plen <= max_len[msgid] and not wanted[msgid]:
            return flen, hlen, plen, msgid
        end = p + 8 + hlen + plen                     # first CRC byte
        crc = x25_crc(buf, p + 9, end, crc_extra[msgid])
        if (crc & 0xFF) != buf[end] or (crc >> 8) != buf[end + 1]:
            return -1, 0, 0, 0
        return flen, hlen, plen, msgid
    if nxt:
        return flen, hlen, plen, msgid
    return -1, 0, 0, 0


@njit(cache=True, nogil=True)
def scan_tlog(buf, state, crc_extra, max_len, wanted, out_off, out_len, out_id, damage):
    """Frame a tlog from ``state[POS]``; record frame offset, payload length, msgid of wanted ones.

    Parameters
    ----------
    buf : uint8 array, the whole file (may be a memmap).
    state : int64[3], ``[pos, bytes_skipped, n_damage]`` updated in place.
    crc_extra : int16[65536], CRC_EXTRA per msgid (-1 when unknown to the dialect).
    max_len : int16[65536], full MAVLink 2 payload length per msgid.
    wanted : bool[65536], msgids whose payload positions are returned.
    out_off, out_len, out_id : output arrays (frame byte offset (its 8-byte stamp), payload
        length, msgid).
    damage : int64 array receiving byte offsets where skipped runs begin.

    Returns
    -------
    int : number of records written (== len(out_off) means "call again").
    """
    n = buf.shape[0]
    p = state[POS]
    k = 0
    cap = out_off.shape[0]
    in_skip = False
    while p < n and k < cap:
        flen, hlen, plen, msgid = _tlog_frame_ok(buf, p, n, crc_extra, max_len, wanted)
        if flen < 0:
            if not in_skip:
                in_skip = True
                if state[NDAMAGE] < damage.shape[0]:
                    damage[state[NDAMAGE]] = p
                state[NDAMAGE] += 1
            state[SKIPPED] += 1
            p += 1
            continue
        in_skip = False
        if msgid < wanted.shape[0] and wanted[msgid]:
            out_off[k] = p
            out_len[k] = plen
            out_id[k] = msgid
            k += 1
        p += flen
    state[POS] = p
    return k


@njit(cache=True, nogil=True)
def _df_record_ok(buf, p, n, lengths):
    """Length of the dataflash record at ``p`` or -1.

    A record is accepted when its header is 0xA3 0x95, its type has been defined by a FMT
    record, it is complete, and the next record header follows it (or the file ends within
    three bytes). The last rule rejects records cut short by a truncated write, which have no
    checksum to reveal them.
    """
    if p + 3 > n or buf[p] != DF_HEAD1 or buf[p + 1] != DF_HEAD2:
        return -1
    L = np.int64(lengths[buf[p + 2]])
    if L < 3 or p + L > n:
        return -1
    q = p + L
    if q + 3 > n:
        return L
    if buf[q] != DF_HEAD1 or buf[q + 1] != DF_HEAD2:
        return -1
    nt = buf[q + 2]
    if lengths[nt] >= 3:
        return L
    # a FMT record may be followed by the first record of the type it defines
    if buf[p + 2] == DF_FMT_TYPE and L == DF_FMT_LEN and buf[p + 3] == nt and buf[p + 4] >= 3:
        return L
    return -1


@njit(cache=True, nogil=True)
def scan_dataflash(buf, state, lengths, out_off, out_type, damage):
    """Frame a dataflash .bin from ``state[POS]``, recording offset and type of every record.

    FMT records (type 0x80) update ``lengths`` as they are met, as pymavlink's DFReader does.
    Returns the number of records written (== len(out_off) means "call again").
    """
    n = buf.shape[0]
    p = state[POS]
    k = 0
    cap = out_off.shape[0]
    in_skip = False
    while p < n and k < cap:
        L = _df_record_ok(buf, p, n, lengths)
        if L < 0:
            if not in_skip:
                in_skip = True
                if state[NDAMAGE] < damage.shape[0]:
                    damage[state[NDAMAGE]] = p
                state[NDAMAGE] += 1
            state[SKIPPED] += 1
            p += 1
            continue
        in_skip = False
        t = buf[p + 2]
        if t == DF_FMT_TYPE and L == DF_FMT_LEN:
            newlen = buf[p + 4]
            if newlen >= 3 and buf[p + 3] != DF_FMT_TYPE:   # FMT itself is fixed at 89 bytes
                lengths[buf[p + 3]] = newlen
        out_off[k] = p
        out_type[k] = t
        k += 1
        p += L
    state[POS] = p
    return k


@njit(cache=True, nogil=True)
def gather_into(buf, off, lens, out):
    """Copy ``lens[i]`` bytes from ``buf[off[i]:]`` into row i of the zeroed (n, width) ``out``.

    MAVLink 2 truncates trailing zero bytes of a payload; the zeros of ``out`` restore them.
    (Outputs are allocated by the caller with numpy so memory tracing sees them.)
    """
    width = out.shape[1]
    for i in range(off.shape[0]):
        ln = min(np.int64(lens[i]), width)
        o = off[i]
        out[i, :ln] = buf[o:o + ln]


@njit(cache=True, nogil=True)
def gather_fixed_into(buf, off, skip, out):
    """Rows ``buf[off[i]+skip : off[i]+skip+width]`` into the (n, width) ``out`` (dataflash)."""
    width = out.shape[1]
    for i in range(off.shape[0]):
        o = off[i] + skip
        out[i, :] = buf[o:o + width]


def gather(buf, off, lens, width):
    """(n, width) zero-padded rows of ``lens[i]`` bytes from ``buf[off[i]:]``."""
    out = np.zeros((off.shape[0], width), dtype=np.uint8)
    gather_into(buf, off, lens, out)
    return out


def gather_fixed(buf, off, skip, width):
    """(n, width) rows ``buf[off[i]+skip:][:width]``."""
    out = np.empty((off.shape[0], width), dtype=np.uint8)
    gather_fixed_into(buf, off, skip, out)
    return out
