"""Speed of ``apmcal fleet``'s engine: logs per second serial and on 2 local Dask workers, the
scheduler's overhead per log, peak memory per worker.

    python benchmarks/fleet.py [--vehicles 4] [--flights 3] [--rate 400] [--hold 150] [--repeat 2]

A simulated fleet (``python -m apmcal_sim.fleet``, seed 7) is written to a temporary folder:
by default 12 flights of 5.6 min logged at 400 Hz (about 10 MB each, like a real flight; the
test fleet's 25 Hz, 45 s logs are too small to say anything about the engine).
Every mode processes the same logs without the cache (each log read and measured), after a
warm-up log on every process (imports and compiled readers loaded), and each mode runs
``--repeat`` times, modes interleaved so that all see the same machine load; the best time
of each counts. Modes:

- serial: :func:`apmcal.fleet.engine.run_serial` in this process (the peer: no Dask);
- dask 1 worker: a LocalCluster of one single-threaded worker process; its CPU time (this
  process, which hosts the LocalCluster's scheduler, plus the worker's) minus the serial CPU
  time, per log, is the scheduler's overhead (serialising the task and the record, the round
  trips to the scheduler and the worker); CPU time, unlike wall time, barely depends on what
  else runs on the machine, so it is the figure to quote on a shared machine (wall also shown);
- dask 2 workers: a LocalCluster of two single-threaded worker processes; the ratio
  serial / 2 workers is the speed-up.

The LocalClusters are made as ``apmcal fleet`` makes its own (apmcal.fleet.engine.WORKER_ENV:
workers without Dask's MALLOC_TRIM_THRESHOLD_, dashboard-only timers slowed;
``--dask-default-env`` keeps Dask's defaults, to measure what they cost).
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
sys.path[:0] = [str(ROOT), str(ROOT / "sitl")]   # the package and the simulator


DASK_DEFAULT_ENV = "--dask-default-env" in sys.argv


def peak_rss_mb() -> float:
    """Peak resident memory of the calling process [MB] (Linux ru_maxrss is in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cpu_s() -> float:
    """CPU time [s] of the calling process (all its threads)."""
    return time.process_time()


def timed(fn, clients=()):
    """(wall [s], CPU [s] of this process plus every worker of ``clients``, result) of fn().

    A LocalCluster's scheduler runs in this process, so its CPU time is in this process's."""
    before = [c.run(cpu_s) for c in clients]
    c0, t0 = cpu_s(), time.perf_counter()
    out = fn()
    wall, cpu = time.perf_counter() - t0, cpu_s() - c0
    for c, b in zip(clients, before):
        after = c.run(cpu_s)
        cpu += sum(after[w] - b[w] for w in after)
    return wall, cpu, out


def cluster(n: int, warm_path: str):
    import dask
    from dask.distributed import Client, LocalCluster

    from apmcal.fleet.engine import WORKER_ENV, process_log

    t0 = time.perf_counter()
    with dask.config.set(WORKER_ENV if not DASK_DEFAULT_ENV else {}):
        c = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                         dashboard_address=None, silence_logs=logging.ERROR)
    client = Client(c)
    client.wait_for_workers(n)
    started = time.perf_counter() - t0
    client.run(process_log, warm_path, None)          # every worker: imports, readers compiled
    return c, client, started


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vehicles", type=int, default=4)
    ap.add_argument("--flights", type=int, default=3)
    ap.add_argument("--rate", type=float, default=400.0, help="log rate [Hz] of IMU and MAG")
    ap.add_argument("--hold", type=float, default=150.0, help="each still hold [s]")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--fleet", default=None, metavar="DIR",
                    help="simulate into DIR, or reuse the logs already there (default: a "
                         "temporary folder)")
    ap.add_argument("--dask-default-env", action="store_true",
                    help="LocalClusters with Dask's defaults (apmcal fleet changes a few; "
                         "see apmcal.fleet.engine.WORKER_ENV)")
    args = ap.parse_args()
    logging.getLogger("distributed").setLevel(logging.ERROR)

    from apmcal.fleet.discover import discover
    from apmcal.fleet.engine import process_log, run_dask, run_serial
    from apmcal_sim.fleet import write_fleet

    with tempfile.TemporaryDirectory() as tmp:
        tmp = args.fleet or tmp
        if not (Path(tmp) / "truth.json").exists():
            t0 = time.perf_counter()
            write_fleet(args.vehicles, args.flights, Path(tmp), seed=7, rate=args.rate,
                        hold_s=args.hold)
            print(f"fleet simulated in {time.perf_counter() - t0:.0f} s")
        paths = discover([tmp])
        n = len(paths)
        size = sum(p.stat().st_size for p in paths) / n / 1e6
        print(f"{n} logs ({args.vehicles} vehicles × {args.flights} flights), {size:.1f} MB "
              f"each, {args.rate:g} Hz; {os.cpu_count()} cores, load average "
              f"{os.getloadavg()[0]:.1f}")
        process_log(str(paths[0]), None)                 # warm this process too
        c1, client1, start1 = cluster(1, str(paths[0]))
        c2, client2, start2 = cluster(2, str(paths[0]))
        warm_rss = client2.run(peak_rss_mb)
        times = {"serial": [], "dask 1 worker": [], "dask 2 workers": []}
        cpus = {k: [] for k in times}
        runs = {"serial": (lambda: run_serial(paths), ()),
                "dask 1 worker": (lambda: run_dask(paths, client=client1), (client1,)),
                "dask 2 workers": (lambda: run_dask(paths, client=client2), (client2,))}
        records = {}
        for _ in range(args.repeat):
            for mode, (fn, clients) in runs.items():
                wall, cpu, records[mode] = timed(fn, clients)
                times[mode].append(wall)
                cpus[mode].append(cpu)
        key = lambda recs: sorted(map(str, recs))
        assert key(records["serial"]) == key(records["dask 1 worker"]) == \
            key(records["dask 2 workers"]), "the modes gave different records"
        rss = client2.run(peak_rss_mb)
        for c, client in ((c1, client1), (c2, client2)):
            client.close()
            c.close()
        best = {k: min(v) for k, v in times.items()}
        cpu = {k: min(v) for k, v in cpus.items()}
        print(f"{'mode':16s} {'wall [s]':>9s} {'logs/s':>8s} {'CPU [s]':>8s}   all runs wall / CPU [s]")
        for k, v in times.items():
            print(f"{k:16s} {best[k]:9.2f} {n / best[k]:8.2f} {cpu[k]:8.2f}   "
                  + ", ".join(f"{x:.2f}/{y:.2f}" for x, y in zip(v, cpus[k])))
        print(f"speed-up, 2 workers vs serial (wall): {best['serial'] / best['dask 2 workers']:.2f}×")
        per_log = cpu["serial"] / n
        for mode in ("dask 1 worker", "dask 2 workers"):
            over = (cpu[mode] - cpu["serial"]) / n
            print(f"scheduler overhead per log, {mode} (CPU − serial CPU): {over * 1000:.1f} ms, "
                  f"{100 * over / per_log:.1f} % of a log's {per_log * 1000:.0f} ms CPU")
        over_wall = (best["dask 1 worker"] - best["serial"]) / n
        print(f"same from wall time, 1 worker: {over_wall * 1000:.1f} ms per log "
              f"({100 * over_wall / (best['serial'] / n):.1f} %)")
        print(f"LocalCluster start: {start1:.1f} s (1 worker), {start2:.1f} s (2 workers)")
        for addr in rss:
            print(f"worker {addr}: peak RSS {warm_rss[addr]:.0f} MB after warm-up, "
                  f"{rss[addr]:.0f} MB after {args.repeat} runs")
        print(f"this process (serial runs): peak RSS {peak_rss_mb():.0f} MB; load average now "
              f"{os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
