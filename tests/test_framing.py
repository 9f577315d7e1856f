"""The vectorised resynchronising scans (apmcal.sources._framing) against a byte-by-byte loop.

The loop below is the sequential rule written out in plain Python (it is what the compiled scans
did before numpy replaced them): at each byte, take the record that starts there if it is valid
and jump past it, else skip the byte. Pieces of the real logs are damaged (seeded numpy RNG:
bytes overwritten, inserted, cut) and both must give the same records, bytes skipped and damage
offsets, also when the chunks are a few kilobytes (so damage and records straddle chunk ends).
"""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.sources import _fastscan, _framing, tlog

DAMAGE = 1000
TLOGS = ["ardupilot/sitl_vtol.tlog", "ardupilot/ardusub_small.tlog"]
BINS = ["ardupilot/pixhawk1_copter368.bin", "ardupilot/ardusub_small.BIN",
        "ardupilot/pxf_copter_mag.BIN"]


def _x25(b, extra: int) -> int:
    crc = 0xFFFF
    for x in list(b) + [extra]:
        tmp = (x ^ crc) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


def _loop_tlog(b: bytes, crc_extra, max_len, wanted):
    n, p = len(b), 0
    offs, skipped, damage, in_skip = [], 0, [], False

    def frame(p):
        if p + 9 > n or b[p + 8] not in (0xFE, 0xFD):
            return -1, 0, 0, 0
        if b[p + 8] == 0xFE:
            if p + 14 > n:
                return -1, 0, 0, 0
            return 8 + 6 + b[p + 9] + 2, 6, b[p + 9], b[p + 13]
        if p + 18 > n:
            return -1, 0, 0, 0
        sig = 13 if b[p + 10] & 1 else 0
        return 8 + 10 + b[p + 9] + 2 + sig, 10, b[p + 9], b[p + 15] | b[p + 16] << 8 | b[p + 17] << 16

    def ok(p):
        flen, hlen, plen, mid = frame(p)
        if flen < 0 or p + flen > n:
            return -1, mid
        q = p + flen
        nxt = q == n or (q + 9 <= n and b[q + 8] in (0xFE, 0xFD))
        if mid < len(crc_extra) and crc_extra[mid] >= 0:
            if nxt and plen <= max_len[mid] and not wanted[mid]:
                return flen, mid
            end = p + 8 + hlen + plen
            c = _x25(b[p + 9:end], int(crc_extra[mid]))
            return (flen, mid) if (c & 0xFF) == b[end] and (c >> 8) == b[end + 1] else (-1, mid)
        return (flen, mid) if nxt else (-1, mid)

    while p < n:
        flen, mid = ok(p)
        if flen < 0:
            if not in_skip:
                in_skip = True
                damage.append(p)
            skipped += 1
            p += 1
            continue
        in_skip = False
        if mid < len(wanted) and wanted[mid]:
            offs.append(p)
        p += flen
    return offs, skipped, damage[:DAMAGE]


def _loop_dataflash(b: bytes):
    n, p = len(b), 0
    lengths = [0] * 256
    lengths[0x80] = 89
    offs, skipped, damage, in_skip = [], 0, [], False

    def ok(p):
        if p + 3 > n or b[p] != 0xA3 or b[p + 1] != 0x95:
            return -1
        L = lengths[b[p + 2]]
        if L < 3 or p + L > n:
            return -1
        q = p + L
        if q + 3 > n:
            return L
        if b[q] != 0xA3 or b[q + 1] != 0x95:
            return -1
        nt = b[q + 2]
        if lengths[nt] >= 3:
            return L
        if b[p + 2] == 0x80 and L == 89 and b[p + 3] == nt and b[p + 4] >= 3:
            return L
        return -1

    while p < n:
        L = ok(p)
        if L < 0:
            if not in_skip:
                in_skip = True
                damage.append(p)
            skipped += 1
            p += 1
            continue
        in_skip = False
        if b[p + 2] == 0x80 and b[p + 4] >= 3 and b[p + 3] != 0x80:
            lengths[b[p + 3]] = b[p + 4]
        offs.append(p)
        p += L
    return offs, skipped, damage[:DAMAGE]


def _damaged(raw: bytes, seed: int, size: int = 60_000) -> bytes:
    """A piece of ``raw`` with runs of bytes overwritten, inserted and cut (and the start cut:
    the scan must find its feet anywhere)."""
    rng = np.random.default_rng(seed)
    start = int(rng.integers(0, max(1, len(raw) - size)))
    b = bytearray(raw[start:start + size])
    for _ in range(12):
        at, k = int(rng.integers(0, len(b) - 64)), int(rng.integers(1, 64))
        choice = rng.integers(3)
        chunk = rng.integers(0, 256, k, dtype=np.uint8).tobytes()
        if choice == 0:
            b[at:at + k] = chunk
        elif choice == 1:
            b[at:at] = chunk
        else:
            del b[at:at + k]
    return bytes(b)


@pytest.fixture(params=[0, 1])
def small_chunks(request, monkeypatch):
    """Chunks of 4 kB (many chunk ends inside records and damaged runs) or the default."""
    if request.param:
        monkeypatch.setattr(_framing, "CHUNK", 4096)
    return request.param


@pytest.mark.parametrize("name", TLOGS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tlog_scan_matches_byte_loop(shared_data, name, seed, small_chunks):
    crc, max_len, by_name = tlog._tables()
    wanted = np.zeros(1 << 16, dtype=bool)
    for m in tlog.IMU_MESSAGES + ("ATTITUDE",):
        wanted[by_name[m][0]] = True
    b = _damaged((shared_data / name).read_bytes(), seed)
    want_off, want_skipped, want_damage = _loop_tlog(b, crc, max_len, wanted)
    buf = np.frombuffer(b, dtype=np.uint8)
    (off, ln, mid), skipped, damage = _framing.scan_tlog(buf, crc, max_len, wanted, DAMAGE)
    assert skipped > 0                                  # the damage did bite
    assert off.tolist() == want_off
    assert (skipped, damage) == (want_skipped, want_damage)
    assert np.array_equal(mid, np.where(buf[off + 8] == 0xFE, buf[off + 13], mid))


@pytest.mark.parametrize("name", BINS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dataflash_scan_matches_byte_loop(shared_data, name, seed, small_chunks):
    raw = (shared_data / name).read_bytes()
    # keep the FMT records at the start so the piece defines its types
    b = raw[:20_000] + _damaged(raw[20_000:], seed)
    want_off, want_skipped, want_damage = _loop_dataflash(b)
    off, typ, skipped, damage = _framing.scan_dataflash(np.frombuffer(b, dtype=np.uint8), DAMAGE)
    assert skipped > 0
    assert off.tolist() == want_off
    assert typ.tolist() == [b[o + 2] for o in want_off]
    assert (skipped, damage) == (want_skipped, want_damage)


def test_dataflash_false_fmt_in_payload_is_not_learnt():
    """An FMT-looking byte run inside a record's payload must not define a length (the scan
    never stands on it), even though the first guess takes every FMT candidate."""
    fmt = lambda t, ln, name: (bytes([0xA3, 0x95, 0x80, t, ln]) + name.ljust(4, b"\0")
                               + b"B".ljust(16, b"\0") + b"x".ljust(64, b"\0"))
    rec_a = bytes([0xA3, 0x95, 0x81]) + bytes([0xA3, 0x95, 0x80, 0x82, 3]) + bytes(20)
    body = fmt(0x81, 28, b"AAA") + fmt(0x82, 4, b"BBB") + rec_a * 3 + bytes([0xA3, 0x95, 0x82, 7])
    b = body * 5
    want = _loop_dataflash(b)
    got = _framing.scan_dataflash(np.frombuffer(b, dtype=np.uint8), DAMAGE)
    assert got[0].tolist() == want[0] and (got[2], got[3]) == want[1:]


def test_crc_matches_the_bitwise_crc():
    """The two-bytes-a-step table CRC equals the bitwise MAVLink CRC on every frame length."""
    rng = np.random.default_rng(5)
    k = 400
    plen = rng.integers(0, 256, k)
    hlen = np.where(rng.random(k) < 0.5, 6, 10)
    extra = rng.integers(0, 256, k)
    span = hlen - 1 + plen
    off = np.concatenate(([0], np.cumsum(span + 11)[:-1]))     # frames back to back
    buf = rng.integers(0, 256, int(off[-1] + span[-1] + 11), dtype=np.uint8)
    crc = np.array([_x25(buf[o + 9:o + 9 + s].tolist(), int(e)) for o, s, e in zip(off, span, extra)])
    end = off + 9 + span
    buf[end[::2]] = crc[::2] & 0xFF                     # every other frame carries its CRC
    buf[end[::2] + 1] = crc[::2] >> 8
    good = _framing._crc_matches(buf, off, hlen, plen, extra)
    assert good[::2].all() and not good[1::2].any()
    ref = np.array([_fastscan.x25_crc_rows(buf[None, o + 9:o + 9 + s], [e])[0]
                    for o, s, e in zip(off, span, extra)])
    assert np.array_equal(ref, crc)


@pytest.mark.parametrize("name", TLOGS + BINS)
def test_chunked_scan_equals_one_pass_scan_on_undamaged_logs(shared_data, name, small_chunks):
    """On an undamaged log the chunked scan (.bin files > 32 MB; the reference of the .tlog
    walkers) takes the records of the one-pass scan."""
    buf = np.fromfile(shared_data / name, dtype=np.uint8)
    if name.endswith(".tlog"):
        crc, max_len, by_name = tlog._tables()
        wanted = np.zeros(1 << 16, dtype=bool)
        for m in tlog.IMU_MESSAGES + tlog.META_MESSAGES:
            wanted[by_name[m][0]] = True
        one = _fastscan.scan_tlog(buf, crc, max_len, wanted)
        (off, ln, mid), skipped, damage = _framing.scan_tlog(buf, crc, max_len, wanted, DAMAGE)
        assert one is not None and (skipped, damage) == (0, [])
        assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(one, (off, ln, mid)))
    else:
        one = _fastscan.scan_dataflash(buf)
        off, typ, skipped, damage = _framing.scan_dataflash(buf, DAMAGE)
        assert one is not None and (skipped, damage) == (0, [])
        assert np.array_equal(one[0], off) and np.array_equal(one[1], typ)
