"""The walker framing of big or damaged .tlog files (apmcal.sources._tlogwalk) against the
byte-by-byte loop of test_framing.py and against the other two scans.

The walkers only propose where frames are; the replay must give the sequential scan's records,
bytes skipped and damage offsets whatever they proposed. So damaged pieces of the real logs are
framed with segments of 16 kB (the default), 1 kB and 333 bytes (so damage, frames and the
bytes a walker spends finding its feet straddle segment ends), in blocks of a few kB, with
int64 positions (files of 2 GB and more), with damage put exactly on the
segment ends, with long damaged runs (past the bytes examined after a run: the exact chunked
scan takes over), with stamps of another epoch in half the file (the walkers' stamp test fails
there: the exact scan frames it) and the head cut mid-frame, with MAVLink 2 and signed frames,
and truncated. Undamaged logs must give the one-pass scan's result,
and read_tlog the same LogContents through either path.
"""
from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2
from test_framing import DAMAGE, TLOGS, _damaged, _loop_tlog, _x25

from apmcal.sources import _fastscan, _framing, _tlogwalk, tlog
from apmcal.sources.tlog import read_tlog

SEGMENTS = [_tlogwalk.SEGMENT, 1024, 333]


def _tables(extra=("ATTITUDE",)):
    crc, max_len, by_name = tlog._tables()
    wanted = np.zeros(1 << 16, dtype=bool)
    for m in tlog.IMU_MESSAGES + tlog.META_MESSAGES + tuple(extra):
        wanted[by_name[m][0]] = True
    return crc, max_len, wanted


def _check(b: bytes, segment: int, damaged: bool = True):
    """Walker scan of ``b`` equals the byte loop and the chunked scan (records, dtypes,
    payload lengths, msgids, bytes skipped, damage offsets)."""
    crc, max_len, wanted = _tables()
    want_off, want_skipped, want_damage = _loop_tlog(b, crc, max_len, wanted)
    buf = np.frombuffer(b, dtype=np.uint8)
    (off, ln, mid), skipped, damage = _tlogwalk.scan_tlog(buf, crc, max_len, wanted, DAMAGE,
                                                           segment=segment)
    assert off.tolist() == want_off
    assert (skipped, damage) == (want_skipped, want_damage)
    if damaged:
        assert skipped > 0                              # the damage did bite
    ref = _framing.scan_tlog(buf, crc, max_len, wanted, DAMAGE)
    assert all(np.array_equal(a, r) and a.dtype == r.dtype for a, r in zip((off, ln, mid), ref[0]))
    return off


@pytest.mark.parametrize("name", TLOGS)
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("segment", SEGMENTS)
def test_walk_scan_matches_byte_loop(shared_data, name, seed, segment):
    _check(_damaged((shared_data / name).read_bytes(), seed), segment)


@pytest.mark.parametrize("name", TLOGS)
@pytest.mark.parametrize("seed", [4, 5])
@pytest.mark.parametrize("block", [5000, 8192])
def test_blocks(shared_data, name, seed, block, monkeypatch):
    """Files walked, validated and replayed in blocks (here of a few kB: damage, frames and the
    exact scan straddle block ends, the scan carried from block to block)."""
    monkeypatch.setattr(_tlogwalk, "BLOCK", block)
    _check(_damaged((shared_data / name).read_bytes(), seed), 1024)


@pytest.mark.parametrize("seed", [0, 1])
def test_int64_positions(shared_data, seed, monkeypatch):
    """Files of 2 GB and more keep positions as int64: the same result."""
    monkeypatch.setattr(_tlogwalk, "_INT32_MAX", 0)
    raw = (shared_data / TLOGS[0]).read_bytes()
    _check(_damaged(raw, seed), 4096)
    _check(raw[:200_000], 4096, damaged=False)


@pytest.mark.parametrize("name", TLOGS)
@pytest.mark.parametrize("segment", [1024, 4096])
def test_damage_on_segment_ends(shared_data, name, segment):
    """Random bytes written over every segment end (and over the preroll before it) and a
    few bytes inserted right at some."""
    rng = np.random.default_rng(segment)
    b = bytearray((shared_data / name).read_bytes()[:80_000])
    for end in range(segment, len(b) - 64, segment):
        k = int(rng.integers(1, 40))
        at = end - int(rng.integers(0, k))
        b[at:at + k] = rng.integers(0, 256, k, dtype=np.uint8).tobytes()
    for end in range(3 * segment, len(b) - 64, 7 * segment):
        b[end:end] = rng.integers(0, 256, 5, dtype=np.uint8).tobytes()
    _check(bytes(b), segment)


@pytest.mark.parametrize("segment", [1024, _tlogwalk.SEGMENT])
def test_long_damage_falls_back_to_the_chunked_scan(shared_data, segment, monkeypatch):
    """Runs of random bytes far longer than the bytes examined after a run end (and than a
    segment), a run of zeros, and a truncated last frame."""
    calls = []
    exact = _tlogwalk._exact
    monkeypatch.setattr(_tlogwalk, "_exact", lambda *a: calls.append(a[1]) or exact(*a))
    raw = (shared_data / TLOGS[0]).read_bytes()[:120_000]
    rng = np.random.default_rng(7)
    b = (raw[:30_000] + rng.integers(0, 256, 9_000, dtype=np.uint8).tobytes() + raw[30_000:60_000]
         + bytes(5_000) + raw[60_000:] + rng.integers(0, 256, 3_000, dtype=np.uint8).tobytes()
         + raw[1000:1030])
    _check(b, segment)
    assert calls                                        # the chunked scan did take over


def test_stamps_of_another_epoch(shared_data, monkeypatch):
    """The walkers' stamp test wants the top bytes of most stamps at the start: where the stamps
    have other top bytes (here the second half of the file) they propose nothing valid and the
    exact scan must frame that part; a head cut mid-frame must not mislead the test."""
    raw = (shared_data / TLOGS[0]).read_bytes()[:60_000]
    crc, max_len, wanted = _tables()
    starts = _loop_tlog(raw, crc, max_len, np.ones(1 << 16, dtype=bool))[0]
    b = bytearray(raw)
    for p in starts:
        if p > 30_000:
            b[p:p + 2] = b"\xff\xee"
    calls = []
    exact = _tlogwalk._exact
    monkeypatch.setattr(_tlogwalk, "_exact", lambda *a: calls.append(a[1]) or exact(*a))
    off = _check(bytes(b), 4096, damaged=False)
    assert len(off) > 100 and max(calls) > 40_000       # the exact scan framed the second half
    cut = bytes(b[13:])                                                 # head cut mid-frame
    assert _tlogwalk._stamp_top(np.frombuffer(cut, dtype=np.uint8),
                                _tlogwalk._at_every_byte(np.frombuffer(cut, dtype=np.uint8),
                                                         "<u2")) == raw[0] | raw[1] << 8
    _check(cut, 4096)


def _synthetic() -> bytes:
    """MAVLink 2 frames, some signed, some with truncated payloads, and MAVLink 1 frames."""
    from test_readers_tlog import frame, v2

    out = []
    plain, signed = v2(), v2(signed=True)
    for i in range(1500):
        m = plain if i % 3 else signed
        t = 1_700_000_000_000_000 + 2500 * i
        if i % 5 == 0:
            msg = mav2.MAVLink_raw_imu_message(t, i % 7, 0, 0, 1, 2, 3, 4, 5, 0, 0)
        elif i % 5 == 1:
            msg = mav2.MAVLink_scaled_imu2_message(i, 10, 20, 30, 40, 50, 60, 70, 80, 90)
        elif i % 5 == 2:
            msg = mav2.MAVLink_attitude_message(i, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
        elif i % 5 == 3:
            msg = mav2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)
        else:
            msg = mav2.MAVLink_system_time_message(t, i)
        out.append(frame(msg, m, t))
    return b"".join(out)


@pytest.mark.parametrize("segment", [512, 4096])
@pytest.mark.parametrize("seed", [0, 1])
def test_mavlink2_and_signed_frames(segment, seed):
    b = _synthetic()
    _check(b, segment, damaged=False)
    _check(_damaged(b, seed, size=len(b)), segment)


@pytest.mark.parametrize("tail", [0, 1, 7, 15, 16, 40])
def test_tiny_and_truncated(tail):
    b = _synthetic()[:tail]
    crc, max_len, wanted = _tables()
    want = _loop_tlog(b, crc, max_len, wanted)
    (off, _, _), skipped, damage = _tlogwalk.scan_tlog(np.frombuffer(b, dtype=np.uint8), crc,
                                                       max_len, wanted, DAMAGE)
    assert (off.tolist(), skipped, damage) == want


@pytest.mark.parametrize("name", TLOGS)
def test_undamaged_equals_one_pass_scan(shared_data, name):
    buf = np.fromfile(shared_data / name, dtype=np.uint8)
    crc, max_len, wanted = _tables(())
    one = _fastscan.scan_tlog(buf, crc, max_len, wanted)
    (off, ln, mid), skipped, damage = _tlogwalk.scan_tlog(buf, crc, max_len, wanted, DAMAGE)
    assert one is not None and (skipped, damage) == (0, [])
    assert all(np.array_equal(a, r) and a.dtype == r.dtype for a, r in zip(one, (off, ln, mid)))


@pytest.mark.parametrize("name", TLOGS)
def test_read_tlog_same_through_either_path(shared_data, name, monkeypatch):
    """read_tlog of an undamaged log: the one-pass path (≤ 2 MB) and the walker path (what a
    bigger file takes) give the same LogContents."""
    path = shared_data / name
    one = read_tlog(path)
    monkeypatch.setattr(tlog, "ONE_PASS_MAX_BYTES", 0)
    walk = read_tlog(path)
    assert [(r.message, r.instance) for r in one.recordings] == \
        [(r.message, r.instance) for r in walk.recordings]
    for a, b in zip(one.recordings, walk.recordings):
        assert a.data.equals(b.data)
    assert one.params == walk.params and one.messages == walk.messages
    assert (one.firmware, one.vehicle, one.bytes_skipped) == (walk.firmware, walk.vehicle, 0)


def test_crc_matches_the_bitwise_crc():
    """The CRC by rows equals the bitwise MAVLink CRC for every span, odd and even, including
    a last frame whose row would run past the end of the buffer."""
    rng = np.random.default_rng(11)
    k = 600
    plen = rng.integers(0, 256, k)
    plen[-1] = 20                                   # span 25 (v1): odd, row one byte too long
    hlen = np.where(rng.random(k) < 0.5, 6, 10)
    hlen[-1] = 6
    extra = rng.integers(0, 256, k)
    span = hlen - 1 + plen
    off = np.concatenate(([0], np.cumsum(span + 11)[:-1]))
    buf = rng.integers(0, 256, int(off[-1] + span[-1] + 11), dtype=np.uint8)
    crc = np.array([_x25(buf[o + 9:o + 9 + s].tolist(), int(e))
                    for o, s, e in zip(off, span, extra)])
    end = off + 9 + span
    good = np.arange(k) % 2 == 0
    good[-1] = True
    buf[end[good]] = crc[good] & 0xFF
    buf[end[good] + 1] = crc[good] >> 8
    assert len(buf) == end[-1] + 2                  # the buffer ends with the last CRC
    got = _tlogwalk.crc_matches(buf, off, hlen, plen, extra)
    assert np.array_equal(got, good)
    assert np.array_equal(got, _framing._crc_matches(buf, off, hlen, plen, extra))


def test_stamp_test_keeps_walkers_on_the_chain():
    """A 0xFD in the stamp 3 bytes before a frame (met first when stepping byte by byte) does
    not lead a walker off the chain: every frame of such a file is proposed."""
    from test_readers_tlog import frame, v2

    m = v2()
    t0 = 0x0005_72ED_EEFD_0000                # byte 5 of the stamp is 0xFD
    frames = [frame(mav2.MAVLink_attitude_message(i + 1, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5), m,
                    t0 + i) for i in range(2000)]
    b = b"".join(frames)
    assert all(f[5] == 0xFD for f in frames)
    starts = np.cumsum([0] + [len(f) for f in frames[:-1]])
    at, _ = _tlogwalk.propose(np.frombuffer(b, dtype=np.uint8), segment=1000)
    assert np.isin(starts, at).all()


def test_last_per_name_equals_unique(monkeypatch):
    """The hashed last-row-per-name equals np.unique on the names, also when every name
    collides (the string comparison takes over) and for names of another width."""
    rng = np.random.default_rng(3)
    pool = np.array([f"INS_ACC{i:03d}".encode() for i in range(300)]      # 8 bytes shared
                    + [f"P{i}".encode() for i in range(50)], dtype="S16")
    names = pool[rng.integers(0, len(pool), 20_000)]

    def plain(a):
        _, first = np.unique(a[::-1], return_index=True)
        return np.sort(len(a) - 1 - first)

    assert np.array_equal(tlog._last_per_name(names), plain(names))
    monkeypatch.setattr(tlog, "_MIX", np.uint64(0))      # key = first 8 bytes: collisions
    words = np.ascontiguousarray(names).view("<u8").reshape(-1, 2)
    assert len(np.unique(words[:, 0])) < len(np.unique(names))
    assert np.array_equal(tlog._last_per_name(names), plain(names))
    short = names.astype("S8")
    assert np.array_equal(tlog._last_per_name(short), plain(short))


@pytest.mark.parametrize("name", TLOGS)
def test_frame_sources_by_bytes(shared_data, name):
    """The 64-bit read of (system, component) equals the bytes themselves (MAVLink 1: bytes
    11-12 after the stamp's start, MAVLink 2: 13-14), on a v1 and a v2 log."""
    buf = np.fromfile(shared_data / name, dtype=np.uint8)
    start = tlog.frame_spans(buf)[0]
    v1 = buf[start + 8] == 0xFE
    want = (np.where(v1, buf[start + 11], buf[start + 13]).astype(np.int32) << 8) \
        | np.where(v1, buf[start + 12], buf[start + 14])
    assert np.array_equal(tlog._frame_sources(buf, start), want)
