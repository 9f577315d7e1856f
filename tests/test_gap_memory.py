"""The diagnosis's processes give freed full-rate arrays back to the system (glibc)."""
from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

# an 8 MB array made and freed three times, then how much the resident set grew [bytes]
GROWTH = """
import sys
import numpy as np
from apmcal.diagnosis.compute import workers
if sys.argv[1] == "fixed":
    workers.give_back_large_blocks()
rss = lambda: int(open("/proc/self/statm").read().split()[1]) * 4096
np.ones(1)
before = rss()
for _ in range(3):
    a = np.ones(1 << 20)
    del a
print(rss() - before)
"""


def _growth(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", GROWTH, mode], capture_output=True, text=True,
                         check=True,
                         env={k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")})
    return int(out.stdout)


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc" or not os.path.exists("/proc/self/statm"),
                    reason="glibc's malloc and /proc only")
def test_a_freed_large_array_leaves_the_process():
    # glibc's default: the first freed 8 MB block raises its mmap threshold, the next ones
    # stay in its heap (the process keeps them); fixed: each goes back when freed
    assert _growth("default") >= 6 << 20
    assert _growth("fixed") < 1 << 20
