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
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

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
