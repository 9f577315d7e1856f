"""Speed of ``apmcal fleet``'s engine: logs per second serial and on 2 local Dask workers, the
scheduler's overhead per log, peak memory per worker.

    python benchmarks/fleet.py [--vehicles 8] [--flights 6] [--rate 50] [--repeat 2]

A simulated fleet (``python -m apmcal_sim.fleet``, seed 7) is written to a temporary folder.
Every mode processes the same logs without the cache (each log read and measured), after a
warm-up log on every process (imports and compiled readers loaded), and each mode runs
``--repeat`` times, modes interleaved so that all see the same machine load; the best time
of each counts. Modes:

- serial: :func:`apmcal.fleet.engine.run_serial` in this process (the peer: no Dask);
- dask 1 worker: a LocalCluster of one single-threaded worker process; its time minus the
  serial time, per log, is the scheduler's overhead (serialising the task and the record,
  the round trips to the scheduler and the worker);
- dask 2 workers: a LocalCluster of two single-threaded worker processes; the ratio
  serial / 2 workers is the speed-up.

Also printed: the time to start each LocalCluster (paid once per run), the peak resident memory
of each worker process (``ru_maxrss``, after the warm-up and after the run) and of this process,
and the load average (the machine is shared: other work slows every mode alike).
"""
from __future__ import annotations

import argparse
import logging
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def peak_rss_mb() -> float:
    """Peak resident memory of the calling process [MB] (Linux ru_maxrss is in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cluster(n: int, warm_path: str):
    from dask.distributed import Client, LocalCluster

    from apmcal.fleet.engine import process_log

    t0 = time.perf_counter()
    c = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                     silence_logs=logging.ERROR)
    client = Client(c)
    client.wait_for_workers(n)
    started = time.perf_counter() - t0
    client.run(process_log, warm_path, None)          # every worker: imports, readers compiled
    return c, client, started


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vehicles", type=int, default=8)
    ap.add_argument("--flights", type=int, default=6)
    ap.add_argument("--rate", type=float, default=50.0, help="log rate [Hz] of IMU and MAG")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    logging.getLogger("distributed").setLevel(logging.ERROR)

    from apmcal.fleet.discover import discover
    from apmcal.fleet.engine import process_log, run_dask, run_serial
    from apmcal_sim.fleet import write_fleet

    with tempfile.TemporaryDirectory() as tmp:
        write_fleet(args.vehicles, args.flights, Path(tmp), seed=7, rate=args.rate)
        paths = discover([tmp])
        n = len(paths)
        size = sum(p.stat().st_size for p in paths) / n / 1024
        print(f"{n} logs ({args.vehicles} vehicles × {args.flights} flights), {size:.0f} kB "
              f"each, {args.rate:g} Hz; {os.cpu_count()} cores, load average "
              f"{os.getloadavg()[0]:.1f}")
        process_log(str(paths[0]), None)                 # warm this process too
        c1, client1, start1 = cluster(1, str(paths[0]))
        c2, client2, start2 = cluster(2, str(paths[0]))
        warm_rss = client2.run(peak_rss_mb)
        times = {"serial": [], "dask 1 worker": [], "dask 2 workers": []}
        for _ in range(args.repeat):
            t = time.perf_counter()
            serial = run_serial(paths)
            times["serial"].append(time.perf_counter() - t)
            t = time.perf_counter()
            one = run_dask(paths, client=client1)
            times["dask 1 worker"].append(time.perf_counter() - t)
            t = time.perf_counter()
            two = run_dask(paths, client=client2)
            times["dask 2 workers"].append(time.perf_counter() - t)
        assert sorted(map(str, serial)) == sorted(map(str, one)) == sorted(map(str, two)), \
            "the modes gave different records"
        rss = client2.run(peak_rss_mb)
        for c, client in ((c1, client1), (c2, client2)):
            client.close()
            c.close()
        best = {k: min(v) for k, v in times.items()}
        print(f"{'mode':16s} {'best [s]':>9s} {'logs/s':>8s}   all runs [s]")
        for k, v in times.items():
            print(f"{k:16s} {best[k]:9.2f} {n / best[k]:8.2f}   "
                  + ", ".join(f"{x:.2f}" for x in v))
        per_log = best["serial"] / n
        over = (best["dask 1 worker"] - best["serial"]) / n
        print(f"speed-up, 2 workers vs serial: {best['serial'] / best['dask 2 workers']:.2f}×")
        print(f"scheduler overhead per log (1 worker − serial): {over * 1000:.1f} ms, "
              f"{100 * over / per_log:.1f} % of a log's {per_log * 1000:.0f} ms")
        print(f"LocalCluster start: {start1:.1f} s (1 worker), {start2:.1f} s (2 workers)")
        for addr in rss:
            print(f"worker {addr}: peak RSS {warm_rss[addr]:.0f} MB after warm-up, "
                  f"{rss[addr]:.0f} MB after {args.repeat} runs")
        print(f"this process (serial runs): peak RSS {peak_rss_mb():.0f} MB; load average now "
              f"{os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
