"""Make a big (default ≥ 100 MB) .tlog or .bin by repeating a real log with shifted timestamps.

    python benchmarks/make_big_log.py ../shared/data/ardupilot/ardusub_small.tlog
    python benchmarks/make_big_log.py ../shared/data/ardupilot/pixhawk_3imu_log171.bin --mb 120
    python benchmarks/make_big_log.py ../shared/data/ardupilot/ardusub_small.tlog --damage 200

Output goes to benchmarks/_data/ (gitignored). Each copy's timestamps are shifted by the span of
the source so time keeps increasing: for .tlog the 8-byte big-endian frame stamps and the
time_usec / time_boot_ms field of every message that starts with one (its CRC is rewritten; MAVLink 2
signatures are left stale); for .bin the leading TimeUS/TimeMS field of every record.
``--damage N`` then overwrites N runs of 1-200 random bytes at random places (seeded numpy RNG)
and inserts N more such runs, so the reader must resynchronise (name ends in ``_damagedN``).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator

from apmcal.sources import _fastscan, dataflash, sniff_format, tlog  # noqa: E402
from apmcal.sources._common import load_bytes  # noqa: E402


def _recrc(buf, starts, hlens, plens, extras):
    """Rewrite the CRC of the frames at ``starts`` after their payload was changed."""
    span = hlens - 1 + plens
    for m in np.unique(span):
        sel = np.flatnonzero(span == m)
        rows = _fastscan.gather_fixed(buf, starts[sel], 9, int(m))
        crc = _fastscan.x25_crc_rows(rows, extras[sel])
        end = starts[sel] + 9 + m
        buf[end] = crc & 0xFF
        buf[end + 1] = crc >> 8


def _timed_frames(src: np.ndarray):
    """Frames whose payload starts with time_usec (u8) or time_boot_ms (u4), e.g. RAW_IMU,
    SCALED_IMU2, ATTITUDE: (start, header length, payload length, crc_extra, width, µs scale)."""
    start, end, mid = tlog.frame_spans(src)
    crc, max_len, by_name = tlog._tables()
    width = np.zeros(1 << 16, np.int64)
    scale = np.zeros(1 << 16, np.int64)
    for msgid, cls in by_name.values():
        if msgid < width.shape[0] and cls.ordered_fieldnames[0] in ("time_usec", "time_boot_ms"):
            usec = cls.ordered_fieldnames[0] == "time_usec"
            width[msgid], scale[msgid] = (8, 1) if usec else (4, 1000)
    hlen = tlog._header_len(src, start)
    plen = end - start - 8 - hlen - 2
    signed = plen > src[start + 9]                    # 13 signature bytes counted in the span
    plen = np.where(signed, plen - 13, plen)
    keep = (width[mid] > 0) & (plen >= width[mid])
    return (start[keep], hlen[keep], plen[keep], crc[mid[keep]].astype(np.int64),
            width[mid[keep]], scale[mid[keep]])


def _shift_tlog(src: np.ndarray, copies: int) -> bytes:
    """Shift the 8-byte frame stamps and the messages' own time fields (CRC rewritten)."""
    stamps = tlog.frame_spans(src)[0]
    idx = stamps[:, None] + np.arange(8)
    t = src[idx].copy().view(">u8").reshape(-1)
    span = int(t.max() - t.min()) + 1_000_000 if len(t) else 0
    fs, fh, fp, fx, fw, fsc = _timed_frames(src)
    fields = []
    for w, dt in ((8, "<u8"), (4, "<u4")):
        sel = fw == w
        fidx = (fs[sel] + 8 + fh[sel])[:, None] + np.arange(w)
        fields.append((fidx, src[fidx].copy().view(dt).reshape(-1), dt, int(fsc[sel][:1].sum())))
    # span of the boot-relative clocks; absolute times (GPS/Unix µs, > 1e11) do not count
    boot = [int(v[v.astype(np.float64) * sc < 1e11].max(initial=0)) * sc for _, v, _, sc in fields]
    span_us = max(boot + [0]) + 1_000_000
    parts = []
    for k in range(copies):
        b = src.copy()
        b[idx] = (t + np.uint64(k * span)).astype(">u8").view(np.uint8).reshape(-1, 8)
        for fidx, vals, dt, sc in fields:
            if len(vals):
                shifted = (vals.astype(np.uint64) + np.uint64(k * span_us // sc)).astype(dt)
                b[fidx] = shifted.view(np.uint8).reshape(fidx.shape)
        _recrc(b, fs, fh, fp, fx)
        parts.append(b.tobytes())
    return b"".join(parts)


def _shift_bin(src: np.ndarray, copies: int) -> bytes:
    off, typ, _, _ = dataflash.scan(src)
    segs = dataflash._format_segments(src, off, typ)
    timed = {}  # type → (numpy dtype of the time field, scale to µs)
    for _, t, _, _name, fmt, cols in segs:
        if cols and cols[0] == "TimeUS" and fmt[:1] == "Q":
            timed[t] = ("<u8", 1)
        elif cols and cols[0] == "TimeMS" and fmt[:1] == "I":
            timed[t] = ("<u4", 1000)
    parts = []
    span_us = None
    fields = []
    for t, (dt, scale) in timed.items():
        o = off[typ == t] + 3
        w = np.dtype(dt).itemsize
        idx = o[:, None] + np.arange(w)
        vals = src[idx].copy().view(dt).reshape(-1)
        fields.append((idx, vals, dt, scale))
        if len(vals):
            s = int(vals.max()) * scale
            span_us = max(span_us or 0, s)
    span_us = (span_us or 0) + 1_000_000
    for k in range(copies):
        b = src.copy()
        for idx, vals, dt, scale in fields:
            shifted = vals.astype(np.uint64) + np.uint64(k * span_us // scale)
            b[idx] = shifted.astype(dt).view(np.uint8).reshape(-1, np.dtype(dt).itemsize)
        parts.append(b.tobytes())
    return b"".join(parts)


def damage(data: bytes, runs: int, seed: int = 0) -> bytes:
    """``data`` with ``runs`` runs of 1-200 random bytes overwritten and ``runs`` more inserted
    (the file starts intact: the first 4096 bytes, where the format is sniffed, are spared)."""
    rng = np.random.default_rng(seed)
    b = bytearray(data)
    for _ in range(runs):
        at, k = int(rng.integers(4096, len(b) - 200)), int(rng.integers(1, 201))
        b[at:at + k] = rng.integers(0, 256, k, dtype=np.uint8).tobytes()
    for _ in range(runs):
        at, k = int(rng.integers(4096, len(b))), int(rng.integers(1, 201))
        b[at:at] = rng.integers(0, 256, k, dtype=np.uint8).tobytes()
    return bytes(b)


def make_big_log(src: Path, mb: float = 100.0, out_dir: Path = ROOT / "benchmarks" / "_data",
                 damaged: int = 0) -> Path:
    """Write ``src`` repeated to at least ``mb`` megabytes (10⁶ bytes), with ``damaged`` runs of
    overwritten and as many of inserted random bytes when > 0; returns the new path."""
    kind = sniff_format(src)
    buf = load_bytes(src)
    copies = int(np.ceil(mb * 1e6 / buf.shape[0]))
    data = _shift_tlog(buf, copies) if kind == "tlog" else _shift_bin(buf, copies)
    if damaged:
        data = damage(data, damaged)
    out_dir.mkdir(parents=True, exist_ok=True)
    ext = ".tlog" if kind == "tlog" else ".bin"
    tag = f"_damaged{damaged}" if damaged else ""
    out = out_dir / f"{Path(src).stem}_x{copies}{tag}{ext}"
    out.write_bytes(data)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path)
    ap.add_argument("--mb", type=float, default=100.0, help="minimum size [MB], default 100")
    ap.add_argument("--damage", type=int, default=0, metavar="N",
                    help="overwrite N runs of random bytes and insert N more (default 0: intact)")
    args = ap.parse_args(argv)
    out = make_big_log(args.source, args.mb, damaged=args.damage)
    print(f"{out} {out.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
