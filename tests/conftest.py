"""Shared pytest fixtures for apmcal tests.

The real recordings live outside the repository in ``../shared/data`` (relative to the project
root). Tests that need them take the ``shared_data`` fixture, which skips cleanly when the folder
is absent (a user's fresh clone has no ``shared/``).
"""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

# make the package importable when it is not installed (e.g. a plain clone + venv)
_ROOT = Path(__file__).resolve().parents[1]
for _folder in (_ROOT, _ROOT / "sitl"):      # the package; the simulator and the SITL driver
    if str(_folder) not in sys.path:
        sys.path.insert(0, str(_folder))

SKIP_REASON = "../shared/data absent: real recordings not available"


def shared_data_path() -> Path | None:
    """Path to ``../shared/data`` next to the project root, or None when it does not exist."""
    p = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    return p if p.is_dir() else None


@pytest.fixture
def shared_data() -> Path:
    """Path to the real recordings folder; skips the test when it is absent."""
    p = shared_data_path()
    if p is None:
        pytest.skip(SKIP_REASON)
    return p


# -- ArduPilot's own firmware (SITL) --------------------------------------------------------------
def pytest_collection_modifyitems(config, items):
    """Tests marked ``ardupilot_sitl`` skip, with the reason, where the firmware is absent."""
    from ardupilot_sitl import unavailable_reason

    reason = unavailable_reason()
    if reason is None:
        return
    for item in items:
        if "ardupilot_sitl" in item.keywords:
            item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture
def ardupilot_sitl(tmp_path):
    """A factory of ArduPilot SITL instances (``sitl/ardupilot_sitl.py``), each started in its
    own scratch folder under the test's tmp_path; every one is stopped when the test ends,
    whether it passed, failed or was interrupted. Skips when the firmware is absent.

    ``ardupilot_sitl(vehicle="copter", model="calibration", **kw)`` returns a started
    :class:`ardupilot_sitl.ArduPilotSitl`.
    """
    from ardupilot_sitl import ArduPilotSitl, unavailable_reason

    reason = unavailable_reason()
    if reason:
        pytest.skip(reason)
    started = []

    def start(vehicle: str = "copter", model: str = "calibration", name: str | None = None,
              **kw) -> ArduPilotSitl:
        workdir = tmp_path / (name or f"sitl-{len(started)}")
        sitl = ArduPilotSitl(workdir, vehicle=vehicle, model=model, **kw)
        started.append(sitl)
        return sitl.start()

    try:
        yield start
    finally:
        for sitl in started:
            sitl.stop()


def pytest_configure(config):
    """One screenshot folder per test run for the browser tests (tests/ui_browser.py), unless
    APMCAL_UI_SCREENSHOTS names one; set before the xdist workers start, which inherit it."""
    import os
    import tempfile
    import time

    if not hasattr(config, "workerinput") and "APMCAL_UI_SCREENSHOTS" not in os.environ:
        os.environ["APMCAL_UI_SCREENSHOTS"] = str(
            Path(tempfile.gettempdir()) / f"apmcal-ui-screenshots-{time.strftime('%Y%m%d-%H%M%S')}")


def pytest_terminal_summary(terminalreporter):
    """Where the browser tests left their screenshots (tests/ui_browser.py), when they ran."""
    from ui_browser import SHOTS

    if SHOTS.is_dir() and any(SHOTS.glob("*.png")):
        terminalreporter.write_line(f"apmcal ui screenshots: {SHOTS}")
