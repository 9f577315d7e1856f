"""Run a solver with single-threaded BLAS.

Why: the solvers' BLAS calls are small (3×3 by 3×n products, 9×n Gram matrices, 4-column
least squares): memory-bound, so a second thread gains little on an idle machine, while on a
busy one (2 cores shared with other work) OpenBLAS's threads wait for each other at every
call. Measured on the 10-minute 400 Hz session (``benchmarks/end_to_end.py``) with the
machine loaded: magnetometer 2.7-3.4 s with threaded BLAS, 1.5 s single-threaded; Ferraris
0.37-0.52 s against 0.20 s; undoing the firmware's correction, (n, 3) by 3×3 products,
0.1 s per sensor against a few ms. threadpoolctl (a dependency) sets and restores the limit
in ~3 ms; ``apmcal log`` runs wholly under it, the two heaviest solvers also when called
from elsewhere. Light on purpose: the command line imports this module for its parser.
"""
from __future__ import annotations

import functools

_ONE_THREAD_FROM_START = False     # set by one_blas_thread_from_start: nothing left to limit


def single_threaded_blas(fn):
    """Decorator: ``fn`` runs with BLAS limited to one thread (restored afterwards)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if _ONE_THREAD_FROM_START:          # the process has one BLAS thread: skip ~40 ms
            return fn(*args, **kwargs)
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)
    return wrapper


def one_blas_thread_from_start() -> bool:
    """Ask OpenBLAS for one thread before numpy loads it (``OPENBLAS_NUM_THREADS=1`` unless
    the user set it); False, and nothing done, when numpy is already imported.

    Why, beyond :func:`single_threaded_blas`: OpenBLAS starts its threads when numpy is
    imported, and on a busy 2-core machine they cost CPU even while limited to one: a whole
    ``apmcal log`` run of the 10-minute 400 Hz session took 2.5 s with them, 2.0 s without
    (min of 8 each, ``benchmarks/end_to_end.py``'s session).
    """
    import os
    import sys

    global _ONE_THREAD_FROM_START
    if "numpy" in sys.modules:
        return False
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    _ONE_THREAD_FROM_START = os.environ["OPENBLAS_NUM_THREADS"] == "1"
    return True

