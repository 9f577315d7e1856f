"""Reader speed: apmcal.sources.read_log against pymavlink (and fasttlogparser) on the same files.

    python benchmarks/readers.py FILE [FILE ...]        (make big files with make_big_log.py;
                                                          damaged ones with its --damage N)
    python benchmarks/readers.py --framing FILE.tlog ... (.tlog framing only: one pass against
                                                          the walkers, no pymavlink)
    python benchmarks/readers.py --no-peer FILE ...      (apmcal alone: times, memory)

For each file: apmcal is run cold (first call in the process) and warm (best of 3); an undamaged
file up to 32 MB is framed in one numpy pass, a larger or damaged .bin by the chunked numpy scan
(``_framing``), a larger or damaged .tlog by lockstep walkers (``_tlogwalk``).
pymavlink reads the IMU messages with mavutil.mavlink_connection + recv_match (DFReader for
.bin/.log); the IMU values of both are asserted identical (exact float64 equality, after the
documented unit conversion; on a damaged file, where the two resynchronise differently, on the
samples both read, matched by time stamp, with the counts each read alone printed). For .tlog,
fasttlogparser is timed too when importable. Peak memory
is the tracemalloc peak of Python/numpy allocations during one apmcal read (the read-only memory
map of the file itself is not an allocation and is not counted) and the ru_maxrss growth of the
process over the cold read (which includes the mapped file pages touched, shared with the page
cache). The CPU seconds of each read are printed too (time.process_time: on a shared machine the
wall time also counts other processes' turns). The last lines are ``ratio_cpu_vs_pymavlink=N``
and ``ratio_vs_pymavlink=N``: the smallest pymavlink/apmcal CPU and wall time ratios over the
files.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator
sys.path.insert(0, str(ROOT / "tests"))       # pymavlink_ref: the tests' reference decoder

import pymavlink_ref as ref  # noqa: E402

from apmcal.sources import read_log, sniff_format  # noqa: E402


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


@contextlib.contextmanager
def _quiet_stdout():
    """Silence C-level stdout (file descriptor 1) inside the block."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "wb") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def _timed(fn, *a, **k):
    t0 = time.perf_counter()
    r = fn(*a, **k)
    return r, time.perf_counter() - t0


def _cpu(fn, *a, **k):
    """(result, CPU seconds of this process): on a shared machine the wall time also counts
    the other processes' turns, the CPU time does not."""
    t0 = time.process_time()
    r = fn(*a, **k)
    return r, time.process_time() - t0


def compare_damaged(contents, expected: dict) -> tuple[int, int, int]:
    """A damaged file: the two readers resynchronise differently, so some records one keeps the
    other drops. Samples are matched by time stamp within each (message, instance); every
    column of the matched ones must be equal. Returns (values compared, samples only apmcal
    read, samples only pymavlink read)."""
    got = {(r.message, r.instance): r for r in contents.recordings}
    n = only_ours = only_theirs = 0
    for key, cols in expected.items():
        rec = got.get(key)
        if rec is None or "t" not in cols:
            continue
        t_have, t_want = rec.data["t"].to_numpy(), cols["t"]
        _, ih, iw = np.intersect1d(t_have, t_want, return_indices=True)
        only_ours += len(t_have) - len(ih)
        only_theirs += len(t_want) - len(iw)
        for c, want in cols.items():
            if c in rec.data.columns:
                have = rec.data[c].to_numpy()
                np.testing.assert_array_equal(have[ih], want[iw], err_msg=f"{key} {c}")
                n += len(ih)
    return n, only_ours, only_theirs


def bench_file(path: Path, skip_pymavlink: bool = False) -> dict:
    size_mb = path.stat().st_size / 1e6
    kind = sniff_format(path)
    rss0 = _maxrss_mb()
    _, cold = _timed(read_log, path)
    rss = _maxrss_mb() - rss0
    warm = min(_timed(read_log, path)[1] for _ in range(3))
    warm_cpu = min(_cpu(read_log, path)[1] for _ in range(3))
    tracemalloc.start()
    contents = read_log(path)        # memory run, separate: tracemalloc slows allocations
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    n_imu = sum(len(r) for r in contents.recordings)
    print(f"{path.name}: {size_mb:.1f} MB {kind}, {n_imu} IMU/MAG samples in "
          f"{len(contents.recordings)} recordings, {contents.bytes_skipped} bytes skipped")
    print(f"  apmcal       cold {cold:7.3f} s  warm {warm:7.3f} s (CPU {warm_cpu:.3f} s)  "
          f"{size_mb / warm:8.1f} MB/s  "
          f"peak tracemalloc {peak / 1e6:.1f} MB ({peak / 1e6 / size_mb:.2f}x file), "
          f"ru_maxrss growth over the cold read {rss:.1f} MB")
    res = {"apmcal": warm, "apmcal_cpu": warm_cpu}
    if skip_pymavlink:
        return res
    types = ref.TLOG_READ if kind == "tlog" else None
    c0 = time.process_time()
    msgs, t_pm = _timed(ref.pymavlink_messages, path, types)
    cpu_pm = time.process_time() - c0
    expected = ref.tlog_expected(msgs) if kind == "tlog" else ref.df_expected(msgs)
    if contents.bytes_skipped:
        n, ours, theirs = compare_damaged(contents, expected)
        same = (f"values identical on the samples both read ({n} compared; apmcal read {ours} "
                f"samples pymavlink did not, pymavlink {theirs} apmcal did not)")
    else:
        same = f"values identical ({ref.compare(contents, expected)} compared)"
    print(f"  pymavlink    {t_pm:7.3f} s (CPU {cpu_pm:.3f} s)  {size_mb / t_pm:8.2f} MB/s  "
          f"{same}  ratio {t_pm / warm:.1f}x (CPU {cpu_pm / warm_cpu:.1f}x)")
    res["pymavlink"], res["pymavlink_cpu"] = t_pm, cpu_pm
    if kind == "tlog":
        try:
            import fasttlogparser
        except ImportError:
            print("  fasttlogparser not importable: skipped")
        else:
            with _quiet_stdout():   # it prints a BAD_CRC line per damaged packet
                r, t_f = _timed(fasttlogparser.parseTLog, str(path), whitelist=ref.TLOG_READ)
            got = r[0]
            for name in ref.TLOG_IMU:   # sanity: same number of IMU messages
                want = sum(1 for m in msgs if m.get_type() == name)
                have = len(got[name]["time_usec" if "time_usec" in got[name] else
                               "time_boot_ms"]) if name in got else 0
                assert have == want, f"fasttlogparser {name}: {have} != {want}"
            print(f"  fasttlogparser {t_f:7.3f} s  {size_mb / t_f:8.1f} MB/s  "
                  f"ratio {t_f / warm:.1f}x")
            res["fasttlogparser"] = t_f
    return res


def bench_framing(path: Path) -> None:
    """.tlog framing alone: the one-pass scan (``_fastscan``, at any size) against the walkers
    (``_tlogwalk``), CPU seconds best of 5, the same frames asserted; what
    ``tlog.ONE_PASS_MAX_BYTES`` rests on."""
    from apmcal.sources import _fastscan, _tlogwalk, tlog
    from apmcal.sources._common import load_bytes

    buf = load_bytes(path)
    crc, max_len, by_name = tlog._tables()
    wanted = np.zeros(1 << 16, dtype=bool)
    for m in tlog.IMU_MESSAGES + tlog.META_MESSAGES:
        wanted[by_name[m][0]] = True
    _fastscan.MAX_BYTES = 1 << 62
    one = _fastscan.scan_tlog(buf, crc, max_len, wanted)
    walk = _tlogwalk.scan_tlog(buf, crc, max_len, wanted, 1000)
    if one is None:
        print(f"{path.name}: damaged, the one-pass scan does not apply")
        return
    assert walk[1] == 0 and all(np.array_equal(a, b) for a, b in zip(one, walk[0]))
    t_one = min(_cpu(_fastscan.scan_tlog, buf, crc, max_len, wanted)[1] for _ in range(5))
    t_walk = min(_cpu(_tlogwalk.scan_tlog, buf, crc, max_len, wanted, 1000)[1]
                 for _ in range(5))
    print(f"{path.name}: {buf.shape[0] / 1e6:.1f} MB, one pass {t_one * 1e3:.1f} ms CPU, "
          f"walkers {t_walk * 1e3:.1f} ms CPU (same frames)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="+", type=Path)
    ap.add_argument("--framing", action="store_true",
                    help=".tlog framing only: one-pass scan against walkers (no pymavlink)")
    ap.add_argument("--no-peer", action="store_true",
                    help="apmcal only (times and memory), no pymavlink: no ratio printed")
    args = ap.parse_args(argv)
    if args.framing:
        for p in args.paths:
            bench_framing(p)
        return
    if args.no_peer:
        for p in args.paths:
            bench_file(p, skip_pymavlink=True)
        return
    results = [bench_file(p) for p in args.paths]
    ft = [r["fasttlogparser"] / r["apmcal"] for r in results if "fasttlogparser" in r]
    if ft:
        print(f"ratio_vs_fasttlogparser={min(ft):.1f}")
    print(f"ratio_cpu_vs_pymavlink="
          f"{min(r['pymavlink_cpu'] / r['apmcal_cpu'] for r in results):.1f}")
    print(f"ratio_vs_pymavlink={min(r['pymavlink'] / r['apmcal'] for r in results):.1f}")


if __name__ == "__main__":
    main()
