"""Damaged, truncated, empty and foreign files: only ApmcalError escapes, good records survive.

The intact file's record boundaries (from the reader's own framing, which test_readers_* check
against pymavlink) give the truth: how many IMU/MAG samples lie wholly before a cut, or wholly
outside damaged bytes. Damage is drawn from a seeded numpy RNG so failures are reproducible.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from apmcal.core.errors import ApmcalError
from apmcal.core.recording import LogContents
from apmcal.sources import dataflash, read_log, tlog

TLOG_IMU = ["RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU"]
CASES = {  # file → kind
    "ardupilot/sitl_vtol.tlog": "tlog",
    "ardupilot/ardusub_small.tlog": "tlog",
    "ardupilot/pixhawk1_copter368.bin": "bin",
    "ardupilot/ardusub_small.BIN": "bin",
    "ardupilot/copter311_nan.log": "log",
}


def _samples(c: LogContents) -> int:
    return sum(len(r) for r in c.recordings)


def _read(path: Path) -> LogContents | None:
    """read_log, mapping ApmcalError to None; any other exception fails the test."""
    try:
        return read_log(path)
    except ApmcalError as e:
        assert "\n" not in str(e)
        return None


def _spans(buf: np.ndarray, kind: str):
    """(start, end) of every sensor record of the intact file, and of every record at all."""
    if kind == "tlog":
        s, e, _ = tlog.frame_spans(buf, TLOG_IMU)
        a, b, _ = tlog.frame_spans(buf)
        return s, e, a, b
    if kind == "bin":
        s, e, names = dataflash.record_spans(buf)
        imu = np.array([dataflash.IMU_RE.match(n) is not None for n in names], dtype=bool)
        return s[imu], e[imu], s, e
    text = bytes(buf)
    starts, ends, is_imu = [], [], []
    pos = 0
    for line in text.split(b"\n")[:-1]:
        starts.append(pos)
        ends.append(pos + len(line) + 1)
        is_imu.append(dataflash.IMU_RE.match(line.split(b",")[0].decode()) is not None)
        pos += len(line) + 1
    s, e, m = np.array(starts), np.array(ends), np.array(is_imu)
    return s[m], e[m], s, e


@pytest.fixture(params=list(CASES))
def intact(request, shared_data):
    path = shared_data / request.param
    buf = np.fromfile(path, dtype=np.uint8)
    c = read_log(path)
    kind = CASES[request.param]
    return kind, buf, c, _spans(buf, kind)


def test_intact_sample_count_matches_spans(intact):
    """Every sensor record the framing finds becomes a sample (except dropped all-zero streams)."""
    kind, buf, c, (s, e, _, _) = intact
    dropped = any("has no non-zero sensor data" in m for m in c.messages)
    assert _samples(c) == len(s) or (dropped and _samples(c) < len(s))


def test_truncation_keeps_every_complete_record(intact, tmp_path):
    kind, buf, c, (s, e, all_s, all_e) = intact
    full = _samples(c)
    dropped_stream = full < len(s)
    rng = np.random.default_rng(1)
    cuts = np.concatenate([rng.integers(1, len(buf), 12), all_e[len(all_e) // 2:][:1] + 5])
    for cut in cuts:
        p = tmp_path / f"cut{cut}.{kind}"
        p.write_bytes(buf[:cut].tobytes())
        got = _read(p)
        expected = int(np.sum(e <= cut))
        if got is None:
            assert expected == 0 or dropped_stream, f"cut at {cut}: lost {expected} samples"
            continue
        if not dropped_stream:
            assert _samples(got) == expected, f"cut at {cut}"
        else:
            assert expected - len(s) + full <= _samples(got) <= expected
        at_boundary = cut in set(all_e.tolist())
        if not at_boundary and kind != "log":
            assert got.bytes_skipped > 0 and got.damaged_at, f"cut at {cut}"


def test_flipped_bytes_lose_only_hit_records(intact, tmp_path):
    kind, buf, c, (s, e, all_s, all_e) = intact
    rng = np.random.default_rng(2)
    # FMT records define everything after them; damage there is not recoverable by design
    body = int(all_e[min(len(all_e) - 1, 200)]) if kind != "tlog" else 0
    for trial in range(4):
        pos = np.sort(rng.integers(body, len(buf), 20))
        bad = buf.copy()
        bad[pos] ^= rng.integers(1, 256, len(pos)).astype(np.uint8)
        p = tmp_path / f"flip{trial}.{kind}"
        p.write_bytes(bad.tobytes())
        got = _read(p)
        assert got is not None
        # a record is lost if a flip hits it or, for dataflash, the header of the next record
        # (its end can then not be confirmed); in text logs only the line hit.
        hit = np.zeros(len(s), bool)
        for x in pos:
            hit |= (s <= x) & (x < e)
            if kind == "bin":
                hit |= (e <= x) & (x < e + 3)
        allowed_loss = int(hit.sum())
        assert _samples(got) >= _samples(c) - allowed_loss, f"trial {trial}"
        if kind == "tlog":  # CRC-checked: nothing invented, nothing hit survives
            assert _samples(got) <= _samples(c)


def test_inserted_garbage_is_skipped(intact, tmp_path):
    kind, buf, c, (s, e, all_s, all_e) = intact
    rng = np.random.default_rng(3)
    k = len(all_s) * 2 // 3
    at = int(all_s[k])                              # a record boundary in the second half
    junk = rng.integers(0, 256, 777).astype(np.uint8)
    if kind == "log":
        junk = np.frombuffer(b"IMU, garbage, 1, 2\n" * 3 + b"#$%&\n", dtype=np.uint8)
    bad = np.concatenate([buf[:at], junk, buf[at:]])
    p = tmp_path / f"junk.{kind}"
    p.write_bytes(bad.tobytes())
    got = _read(p)
    # dataflash: the record just before the junk cannot have its end confirmed
    lost = 1 if kind == "bin" and np.any(e == at) else 0
    assert _samples(got) >= _samples(c) - lost
    assert got.bytes_skipped >= len(junk) - 3 and got.bytes_skipped > 0
    first = int(all_s[k - 1]) if kind == "bin" else at   # bin: the unconfirmed record before
    assert any(first <= d <= at + len(junk) for d in got.damaged_at)


@pytest.mark.parametrize("kind", ["tlog", "bin", "log", "none"])
def test_random_bytes_raise_only_apmcal_error(shared_data, tmp_path, kind):
    """Random junk after a real file head (or alone): LogContents or ApmcalError, nothing else."""
    rng = np.random.default_rng(4)
    heads = {"tlog": "ardupilot/sitl_vtol.tlog", "bin": "ardupilot/pixhawk1_copter368.bin",
             "log": "ardupilot/copter311_nan.log"}
    head = (np.fromfile(shared_data / heads[kind], dtype=np.uint8)[:3000]
            if kind in heads else np.zeros(0, np.uint8))
    for i in range(25):
        junk = rng.integers(0, 256, int(rng.integers(1, 5000))).astype(np.uint8)
        if i % 5 == 0:   # also sprinkle valid-looking magic bytes
            junk[rng.integers(0, len(junk), len(junk) // 10 + 1)] = [0xFE, 0xFD, 0xA3, 0x95][i % 4]
        p = tmp_path / f"rnd{i}.{kind}"
        p.write_bytes(np.concatenate([head, junk]).tobytes())
        got = _read(p)
        assert got is None or isinstance(got, LogContents)


def test_missing_file(tmp_path):
    with pytest.raises(ApmcalError, match="cannot open file") as e:
        read_log(tmp_path / "nope.tlog")
    assert "nope.tlog" in str(e.value) and "\n" not in str(e.value)


def test_empty_file(tmp_path):
    p = tmp_path / "empty.bin"
    p.write_bytes(b"")
    with pytest.raises(ApmcalError, match="empty file"):
        read_log(p)


def test_directory(tmp_path):
    with pytest.raises(ApmcalError, match="directory"):
        read_log(tmp_path)


def test_unknown_binary_format(tmp_path):
    p = tmp_path / "x.dat"
    p.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(ApmcalError) as e:
        read_log(p)
    assert str(e.value) == f"{p}: byte 0: unknown format: not a tlog, dataflash or CSV file"
