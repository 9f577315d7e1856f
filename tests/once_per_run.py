"""An expensive test input made once per test run, not once per pytest-xdist worker (not a test
module).

Under ``pytest -n 2`` the tests of one module are spread over both workers, so a module-scoped
fixture runs in each of them: a recording of ArduPilot's firmware would be made twice. Here the
first worker that asks makes it in a folder under the run's shared temporary root, holding a
lock; the others wait for it and use the same folder.
"""
from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path


def once_per_run(tmp_path_factory, name: str, make) -> Path:
    """The folder ``name`` under the test run's temporary root, filled by ``make(folder)`` the
    first time any worker asks (a failed ``make`` leaves it to the next one to try again)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent                      # shared by the workers of this run
    folder = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (folder / ".done").exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir(parents=True)
            make(folder)
            (folder / ".done").write_text("")
    return folder
