"""The diagnosis's forked workers (apmcal/diagnosis/compute/workers.py) end on a SIGTERM that
reaches them while they start, in a process with a Python SIGTERM handler of its own (as
``apmcal ui``'s job process has). Such a SIGTERM — a pool stopped right after it was forked —
used to run the inherited handler inside CPython's after-fork hooks, which ignore its
SystemExit: the worker lived on, and the pool's stop waited for it forever (a gap job of the ui
hung so in a CI run)."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from apmcal.diagnosis.compute import workers

# The SIGTERM is sent by the worker to itself from an after-fork hook: the moment at which
# the pool's stop reached the hung worker, made certain instead of left to the scheduler.
SCRIPT = textwrap.dedent("""
    import os, signal, sys, time
    from apmcal.diagnosis.compute import workers

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))      # as the ui's job process
    marker = sys.argv[1]

    def sigterm_while_starting():       # in the first worker only
        if not os.path.exists(marker):
            with open(marker, "w") as f:
                f.write(str(os.getpid()))
            os.kill(os.getpid(), signal.SIGTERM)

    os.register_at_fork(after_in_child=sigterm_while_starting)
    with workers.per_fold(object(), (0, 1)):
        pid = int(open(marker).read())
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                with open(f"/proc/{pid}/stat") as f:
                    alive = f.read().split(") ")[1][0] != "Z"
            except FileNotFoundError:
                alive = False
            if not alive:
                break
            time.sleep(0.05)
        print("worker ended" if not alive else "worker still running")
""")


@pytest.mark.skipif(not workers.parallel(), reason="one core: no workers are forked")
def test_a_worker_given_sigterm_while_it_starts_ends(tmp_path):
    run = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "first-worker")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip() == "worker ended", run.stderr[-2000:]
