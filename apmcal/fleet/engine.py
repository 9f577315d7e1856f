"""Run one task per log on Dask (dask.distributed): a LocalCluster of worker processes on this
machine, or an existing cluster through its scheduler's address.

Each task (:func:`process_log`) hashes its file, returns the cached record when there is one,
else reads and measures the log (:func:`apmcal.fleet.extract.extract`) and caches the record.
The scheduler and this process see only these small records (a few hundred bytes of fields),
never samples. A LocalCluster's workers run one thread each, so a worker holds one log at a
time; on an existing cluster start the workers with ``--nthreads 1`` for the same bound. The
workers of an existing cluster must see the log paths and the output folder (a shared file
system). No process pool, queue or RPC of our own: Dask's scheduler assigns the tasks.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

from apmcal.core.errors import ApmcalError

INSTALL_HINT = "apmcal fleet needs Dask and pyarrow: pip install 'apmcal[fleet]'"


def require_dask() -> None:
    """Raise ApmcalError with the install line when dask.distributed or pyarrow is missing."""
    try:
        import dask.distributed  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError:
        raise ApmcalError(INSTALL_HINT) from None


def process_log(path: str, cache_dir: str | None, site=None) -> dict:
    """One task: the log's record, from the cache when its content was seen before.

    Never raises: an unreadable file becomes a record with its reason.
    """
    from apmcal.fleet.cache import RecordCache, content_key
    from apmcal.fleet.extract import base_record, extract

    try:
        key = content_key(path)
    except OSError as e:
        rec = base_record(Path(path))
        rec["reason"] = f"{path}: cannot read: {e.strerror or e}"
        return rec
    cache = RecordCache(cache_dir) if cache_dir else None
    rec = cache.load(key) if cache else None
    if rec is not None:
        rec.update(path=str(path), cached=True)
        return rec
    rec = extract(path, site)
    rec["content_key"] = key
    if cache:
        try:
            cache.store(key, rec)
        except Exception as exc:      # a full disk costs the cache, not the run
            rec["notes"] = "; ".join(filter(None, [rec.get("notes"), f"not cached: {exc}"]))
    rec["cached"] = False
    return rec


def run_serial(paths, cache_dir=None, site=None, progress=None) -> list[dict]:
    """The tasks one after the other in this process (no Dask): the benchmark's baseline."""
    out = []
    for p in paths:
        out.append(process_log(str(p), cache_dir, site))
        if progress:
            progress()
    return out


# The LocalCluster's configuration (dask.config keys):
# - Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536 so that they hand freed memory back
#   to the system at once; glibc then also stops adapting its mmap threshold, so every large
#   numpy array of a log is mapped and unmapped afresh. Measured (benchmarks/fleet.py setup,
#   400 Hz logs): twice the CPU time per log, the extra all system time (page faults). One log at
#   a time per worker keeps the memory bounded without it, so the workers start without it.
# - the statistical profiler (every 10 ms), the event-loop tick check (every 20 ms) and the
#   system monitor (every 0.5 s) serve the dashboard, which is off: slower, they cost a third of
#   the CPU time an idle worker and scheduler spend (about 22 → 7 ms per second each, measured
#   with a LocalCluster of one worker idle for 5 s).
WORKER_ENV = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
              "distributed.worker.profile.enabled": False,
              "distributed.admin.tick.interval": "1s",
              "distributed.admin.system-monitor.interval": "2s"}


def _client(workers: int | None, scheduler: str | None):
    import dask
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as exc:
            raise ApmcalError(f"cannot reach the Dask scheduler: {exc}", scheduler) from None
    n = workers or os.cpu_count() or 1
    with dask.config.set(WORKER_ENV):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
    return Client(cluster), cluster


def run_dask(paths, cache_dir=None, site=None, *, workers: int | None = None,
             scheduler: str | None = None, progress=None, client=None) -> list[dict]:
    """The tasks on Dask; the records in completion order.

    Parameters
    ----------
    paths : list of Path
    cache_dir : str, optional
        The record cache folder (None: no cache).
    site : (lat, lon, alt), optional
    workers : int, optional
        LocalCluster worker processes (default the core count).
    scheduler : str, optional
        "tcp://HOST:PORT" of an existing scheduler (then ``workers`` is ignored).
    progress : callable, optional
        Called once per finished log.
    client : dask.distributed.Client, optional
        Use this client (left open) instead of making one from ``workers``/``scheduler``.
    """
    own = client is None
    client, cluster = _client(workers, scheduler) if own else (client, None)
    try:
        return _gather(client, paths, cache_dir, site, progress)
    finally:
        if own:
            client.close()
        if cluster is not None:
            cluster.close()


def _gather(client, paths, cache_dir, site, progress) -> list[dict]:
    """Submit one task per log and collect the records as they finish."""
    from dask.distributed import as_completed

    futures = client.map(process_log, [str(p) for p in paths], cache_dir=cache_dir,
                         site=site, pure=False)
    index = {f.key: str(p) for f, p in zip(futures, paths)}
    records = []
    for fut in as_completed(futures):
        try:
            records.append(fut.result())
        except Exception as exc:     # a worker died on this log: a row, not a stop
            from apmcal.fleet.extract import base_record

            rec = base_record(Path(index[fut.key]))
            rec["reason"] = f"task failed on its worker: {type(exc).__name__}: {exc}"
            records.append(rec)
        fut.release()
        if progress:
            progress()
    return records
