"""A small ``python -m apmcal_sim.gap_benchmark``: sessions simulated with one effect withheld from the twin.

Each case is diagnosed blind (the diagnosis is not told which effect is on) and must rank the
withheld effect first; the session without an extra effect must report nothing supported.
The full benchmark (30 single cases, 3 pairs, 40 null sessions) is ``python -m apmcal_sim.gap_benchmark``.
"""
from __future__ import annotations

import pytest

from apmcal_sim.gap_benchmark import QUICK, run_case

RATE_HZ = 50.0      # the quick benchmark's rate: every logged sample is one sensor sample


@pytest.mark.parametrize("withheld", QUICK, ids=lambda w: "+".join(w) or "none")
def test_the_withheld_effect_is_ranked_first(withheld):
    case = run_case(withheld, 1, RATE_HZ, RATE_HZ)
    if withheld:
        assert case.top in withheld, (case.top, case.selected)
        assert case.shrink >= 0.5           # these three are strong in the diagnosis script
    else:
        assert case.top is None and case.selected == [], case.selected
