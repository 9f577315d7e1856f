"""``apmcal fleet`` at scale on real-firmware logs: logs per second and peak memory per worker on
a local Dask cluster, against reading the same logs with pymavlink on the same cluster.

    python benchmarks/fleet_firmware.py [--logs 200] [--workers 2] [--fleet DIR] [--peer-all]

The logs: flights recorded from ArduPilot's own firmware (ArduCopter 4.7 SITL, tests/
sitl_fleet.py: 4 vehicles × 2 flights of about 2.3 min, takeoff, a square, two slow turns,
land, logged from boot: about 8 MB each, the firmware's own log layout and rates), written into
``--fleet DIR`` (or reused from there), then linked under ``--logs`` names (hard links, else
copies: the same content over and over, so the file system's cache serves every mode alike;
apmcal's record cache is off, so every log is read and measured).

Modes, one after the other, each on a fresh LocalCluster of ``--workers`` single-threaded
worker processes (as ``apmcal fleet`` makes it, apmcal.fleet.engine.WORKER_ENV), each worker
warmed up on one log first (imports, compiled readers):

- apmcal fleet's engine (:func:`apmcal.fleet.engine.run_dask`, no cache): per log the content
  hash, the reading, the health figures and the flight compass check (the figures ``apmcal
  log`` prints);
- the peer, pymavlink (DFReader) reading the messages apmcal's readers use from each log
  (IMU, MAG, ATT, GPS, PARM, MSG, BAT, VIBE, CTUN, RCOU, with ``recv_match(type=...)``, which
  unpacks only those), one task per log on the same kind of cluster;
- with ``--peer-all``: pymavlink reading every message of each log (as mavlogdump does).

Printed: wall time, logs/s and the ratio to the peer; the peak resident memory of each worker
(``ru_maxrss``) after its warm-up and after the mode; the time one log takes in this process
for apmcal's reading alone and for its flight compass check, so the split of the cost is known;
the load average (the machine is shared: other work slows every mode alike).
"""
from __future__ import annotations

import argparse
import logging
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl"), str(ROOT / "tests")]

PEER_TYPES = ["IMU", "MAG", "ATT", "GPS", "PARM", "MSG", "BAT", "VIBE", "CTUN", "RCOU"]


def peak_rss_mb() -> float:
    """Peak resident memory of the calling process [MB] (Linux ru_maxrss is in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def pymavlink_read(path: str, types: list[str] | None = PEER_TYPES) -> int:
    """Read a dataflash log with pymavlink: the messages of ``types`` (None: all); the count."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(path)
    n = 0
    while True:
        msg = log.recv_match(type=types) if types else log.recv_msg()
        if msg is None:
            return n
        n += 1


def record(folder: Path) -> list[Path]:
    """The SITL flights in ``folder``/bin (recorded there when absent)."""
    from sitl_fleet import VehiclePlan, record_fleet

    if not (folder / "truth.json").exists():
        t0 = time.perf_counter()
        record_fleet(folder, [VehiclePlan(sysid, 2) for sysid in (21, 22, 23, 24)])
        print(f"recorded 8 flights from ArduCopter SITL in {time.perf_counter() - t0:.0f} s")
    return sorted((folder / "bin").glob("*.bin"))


def fan_out(sources: list[Path], n: int, folder: Path) -> list[Path]:
    """``n`` logs in ``folder``: the sources round-robin, hard-linked (else copied)."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(n):
        dest = folder / f"log_{i:04d}.bin"
        src = sources[i % len(sources)]
        try:
            os.link(src, dest)
        except OSError:
            shutil.copy(src, dest)
        out.append(dest)
    return out


def cluster(n: int):
    """A LocalCluster made as apmcal fleet makes its own, and its client."""
    import dask
    from dask.distributed import Client, LocalCluster

    from apmcal.fleet.engine import WORKER_ENV

    with dask.config.set(WORKER_ENV):
        c = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                         dashboard_address=None, silence_logs=logging.ERROR)
    client = Client(c)
    client.wait_for_workers(n)
    return c, client


def run_mode(name: str, n_workers: int, warm, work, paths: list[Path]) -> dict:
    """One mode on a fresh cluster: wall [s] of ``work(client, paths)`` after ``warm`` ran on
    every worker, and each worker's peak RSS [MB] after the warm-up and after the mode."""
    c, client = cluster(n_workers)
    try:
        client.run(warm)
        warm_rss = client.run(peak_rss_mb)
        t0 = time.perf_counter()
        result = work(client, [str(p) for p in paths])
        wall = time.perf_counter() - t0
        rss = client.run(peak_rss_mb)
    finally:
        client.close()
        c.close()
    print(f"{name}: {wall:.1f} s, {len(paths) / wall:.2f} logs/s; peak RSS per worker "
          + ", ".join(f"{warm_rss[w]:.0f} → {rss[w]:.0f} MB" for w in sorted(rss)))
    return {"wall": wall, "rss": rss, "result": result}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--logs", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--fleet", default=None, metavar="DIR",
                    help="record the SITL flights into DIR, or reuse those already there")
    ap.add_argument("--peer-all", action="store_true",
                    help="also time pymavlink reading every message (slow: ~10× the peer)")
    args = ap.parse_args()
    logging.getLogger("distributed").setLevel(logging.ERROR)

    from dask.distributed import as_completed

    from apmcal.calibration.health import flight_compass
    from apmcal.fleet.engine import process_log, run_dask
    from apmcal.sources import read_log

    with tempfile.TemporaryDirectory() as tmp:
        fleet = Path(args.fleet) if args.fleet else Path(tmp) / "fleet"
        sources = record(fleet)
        paths = fan_out(sources, args.logs, Path(tmp) / "logs")
        mb = sum(p.stat().st_size for p in sources) / len(sources) / 1e6
        print(f"{len(paths)} logs ({len(sources)} distinct flights, {mb:.1f} MB each); "
              f"{args.workers} workers on {os.cpu_count()} cores; load average "
              f"{os.getloadavg()[0]:.1f}")
        one = str(sources[0])
        t0 = time.perf_counter()
        read_log(one)
        t1 = time.perf_counter()
        flight_compass(one)
        t2 = time.perf_counter()
        print(f"one log in this process: apmcal's reading {t1 - t0:.2f} s, its flight compass "
              f"check {t2 - t1:.2f} s (reads the flight series itself)")

        def peer(types):
            def work(client, ps):
                futures = client.map(pymavlink_read, ps, types=types, pure=False)
                return sum(f.result() for f in as_completed(futures))
            return work

        modes = {"apmcal fleet (run_dask, no cache)": (
                     lambda: process_log(one, None),
                     lambda client, ps: run_dask(ps, None, client=client)),
                 "pymavlink, the messages apmcal reads": (
                     lambda: pymavlink_read(one), peer(PEER_TYPES))}
        if args.peer_all:
            modes["pymavlink, every message"] = (lambda: pymavlink_read(one, None), peer(None))
        res = {name: run_mode(name, args.workers, warm, work, paths)
               for name, (warm, work) in modes.items()}
        ours = res["apmcal fleet (run_dask, no cache)"]
        bad = [r for r in ours["result"] if r["status"] != "ok"]
        assert not bad, bad[:1]
        for name, r in res.items():
            print(f"  {name}: {r['wall'] / ours['wall']:.2f}× apmcal's wall time")
        print(f"load average now {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
