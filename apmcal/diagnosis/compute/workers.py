"""Methods of one object run in forked worker processes, one job per call, on every core.

Workers are forked, so they inherit the object (a session and what is cached so far) without
it being sent; only the jobs' results travel back. A large result travels through a file in
memory (/dev/shm), not through the pool's pipe: on this kind of machine (a virtual 2-core box)
the pipe moved about 35 MB/s — two 28 MB motion paths took 1.6 s, a file 0.1 s. With each
result come the entries the job added to the memos of :mod:`apmcal.diagnosis.compute.memo`, which this
process keeps: workers forked later start with them.

:func:`run`, :func:`run_lanes` and :func:`beside` fork their workers for one call;
:func:`per_fold` forks one worker per fold that serves many calls (each new worker starts cold:
it faults its memory in and fills its caches anew, which for many small calls costs as much as
the work).
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import tempfile
from dataclasses import dataclass

from apmcal.diagnosis.compute import memo

SHIP_BY_FILE_BYTES = 1 << 20    # results at least this large [bytes] travel through a file

_TARGET = None                  # the object a forked worker inherits
_SHIP_DIR: str | None = None    # where a worker leaves a large result
_IN_WORKER = False              # True in a forked worker: it must not fork again


def parallel() -> bool:
    """Whether work may be spread over forked workers (more than one core, not in a worker)."""
    return not _IN_WORKER and (os.cpu_count() or 1) >= 2


def run(target, jobs: list[tuple[str, tuple]]) -> list:
    """``[target.method(*args) for method, args in jobs]``, spread over every core."""
    workers = min(len(jobs), os.cpu_count() or 1)
    if workers < 2 or not parallel():
        return [getattr(target, method)(*args) for method, args in jobs]
    with _pool(target, workers) as pool:
        return [_unship(r) for r in pool.map(_call, jobs, chunksize=1)]


def run_lanes(target, lanes: list[list[tuple[str, tuple]]]) -> list[list]:
    """Each lane's jobs (as for :func:`run`) one after the other in one forked worker, the
    lanes side by side: ``[[target.method(*args) for method, args in lane] for lane in lanes]``.

    For jobs that build on what an earlier one of the same lane leaves in the worker (the
    nominal fit of a fold, then the other models of that fold), where :func:`run` would
    have to send that state back and fork new workers that inherit it."""
    if len(lanes) < 2 or not parallel():
        return [[getattr(target, method)(*args) for method, args in lane] for lane in lanes]
    with _pool(target, min(len(lanes), os.cpu_count() or 1)) as pool:
        return [_unship(r) for r in pool.map(_call, [("_lane", (lane,)) for lane in lanes],
                                             chunksize=1)]


def beside(target, jobs: list[tuple[str, tuple]], work, hand_over: bool = False):
    """``work()`` in this process while ``jobs`` (as for :func:`run`) run in forked workers,
    one per job up to one per core; returns (work's result, the jobs' results).

    ``hand_over``: ``work`` is called with a function that returns job i's result as soon as
    that job is done, while the others may still run (work that needs one of them)."""
    if not parallel():
        done: dict = {}

        def result_here(i: int):
            if i not in done:
                method, args = jobs[i]
                done[i] = getattr(target, method)(*args)
            return done[i]

        out = work(result_here) if hand_over else work()
        return out, [result_here(i) for i in range(len(jobs))]
    with _pool(target, max(1, min(len(jobs), os.cpu_count() or 1))) as pool:
        pending = [pool.apply_async(_call, (job,)) for job in jobs]     # in order, one each
        got: dict = {}

        def result(i: int):
            if i not in got:
                got[i] = _unship(pending[i].get())
            return got[i]

        out = work(result) if hand_over else work()
        return out, [result(i) for i in range(len(jobs))]


@contextlib.contextmanager
def _pool(target, workers: int):
    from threadpoolctl import threadpool_limits

    global _TARGET, _SHIP_DIR
    shm = "/dev/shm" if os.path.isdir("/dev/shm") else None
    # one BLAS thread per worker: OpenBLAS's own threads in forked workers spin against each
    # other (measured: six models on two cores took as long as in one process)
    with tempfile.TemporaryDirectory(dir=shm, prefix="apmcal-") as ship_dir, \
            threadpool_limits(limits=1):
        _TARGET, _SHIP_DIR = target, ship_dir
        try:
            with _fork_pool(multiprocessing.get_context("fork"), workers) as pool:
                yield pool
        finally:
            _TARGET = _SHIP_DIR = None


class FoldWorkers:
    """One forked worker per fold, kept across calls (:func:`per_fold`): each runs every job of
    its fold, so what a job leaves in its worker (the fold's fits, the content memos, the
    integration plans) serves the next job of that fold, and the worker faults its memory in
    once, not once per call."""

    def __init__(self, pools: dict):
        self._pools = pools

    def run(self, jobs: list[tuple[str, tuple]], fold_of) -> list:
        """``[target.method(*args) for method, args in jobs]``, job i in the worker of fold
        ``fold_of(jobs[i])``."""
        pending = [self._pools[fold_of(job)].apply_async(_call, (job,)) for job in jobs]
        return [_unship(p.get()) for p in pending]


@contextlib.contextmanager
def per_fold(target, folds):
    """:class:`FoldWorkers` for ``folds``, forked now (they inherit ``target`` as it is now:
    what it learns later they find themselves) and stopped on leaving; None where work is not
    spread (:func:`parallel`)."""
    if not parallel() or (os.cpu_count() or 1) < len(folds):
        yield None
        return
    global _TARGET, _SHIP_DIR
    shm = "/dev/shm" if os.path.isdir("/dev/shm") else None
    with tempfile.TemporaryDirectory(dir=shm, prefix="apmcal-") as ship_dir:
        _TARGET, _SHIP_DIR = target, ship_dir
        context = multiprocessing.get_context("fork")
        pools = {}
        try:
            for fold in folds:
                pools[fold] = _fork_pool(context, 1)
            _TARGET = _SHIP_DIR = None      # the workers keep theirs
            yield FoldWorkers(pools)
        finally:
            _TARGET = _SHIP_DIR = None
            for pool in pools.values():
                pool.terminate()
                pool.join()


def _fork_pool(context, workers: int):
    """A pool of ``workers`` forked workers, forked with SIGTERM held back (and so pending in a
    worker until it is ready for it, :func:`_worker_start`).

    Why: a worker inherits this process's Python-level SIGTERM handler (``apmcal ui``'s job
    process has one, to exit cleanly). A SIGTERM from the pool's ``terminate()`` that reaches a
    worker while it is still setting itself up after the fork runs that handler inside
    CPython's after-fork hooks, which ignore its SystemExit: the worker lives on, waits
    forever for a task, and ``terminate()`` waits forever for it (seen as a hung gap job in the
    ui; ``tests/test_workers.py`` sends a starting worker that SIGTERM)."""
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
    try:
        return context.Pool(workers, _worker_start)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def _worker_start() -> None:
    """A worker leaves Ctrl-C to the main process, which stops the pool and says so in one
    line (a worker's own KeyboardInterrupt would print its traceback on the terminal); a
    SIGTERM ends it at once (the default action), one that came during its start included."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})


@dataclass(frozen=True)
class _Shipped:
    path: str       # a pickled result left in a file by a worker


def _call(job):
    global _IN_WORKER
    _IN_WORKER = True
    method, args = job
    memo.start_recording()
    if method == "_lane":       # run_lanes: the lane's jobs in turn
        result = [getattr(_TARGET, m)(*a) for m, a in args[0]]
    else:
        result = getattr(_TARGET, method)(*args)
    data = pickle.dumps((result, memo.recorded()), protocol=pickle.HIGHEST_PROTOCOL)
    if len(data) < SHIP_BY_FILE_BYTES or _SHIP_DIR is None:
        return data
    fd, path = tempfile.mkstemp(dir=_SHIP_DIR, suffix=".pickle")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    return _Shipped(path)


def _unship(item):
    if isinstance(item, _Shipped):
        with open(item.path, "rb") as f:
            item = f.read()
    result, memo_entries = pickle.loads(item)
    memo.keep(memo_entries)
    return result
