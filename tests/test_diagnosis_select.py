"""The rules that decide whether a candidate effect is supported, beyond its evidence: the Wald
test of its parameters, their physical limits, and holds too short to score."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from apmcal.diagnosis.model.plausible import implausible
from apmcal.diagnosis.model.wald import wald_p_value
from apmcal.diagnosis.session.log import scorable_holds


def _param(value, sigma):
    return {"value": value, "sigma": sigma, "unit": "-"}


def test_wald_test_against_the_values_that_switch_an_effect_off():
    # two parameters one sigma away: chi2 = 2 on 2 dof, whose survival is exp(-chi2/2) by hand
    both = {"vertical": _param(1e-5, 1e-5), "horizontal": _param(-2e-5, 2e-5)}
    assert wald_p_value("earth_rate", both) == pytest.approx(np.exp(-1.0), rel=1e-9)
    # gyro scale is off at 1, not 0: one sigma away on each axis is chance ...
    sigma = [1e-4] * 3
    near = {"scale": _param([1 + 1e-4, 1 - 1e-4, 1 + 1e-4], sigma),
            "misalignment": _param([0.0] * 6, [1e-4] * 6)}
    assert wald_p_value("gyro_scale", near) > 0.5
    # ... ten sigmas on one axis is not
    far = dict(near, scale=_param([1 + 1e-3, 1.0, 1.0], sigma))
    assert wald_p_value("gyro_scale", far) < 1e-10


def test_effects_without_a_sigma_are_not_wald_tested():
    assert wald_p_value("lowpass_filter", {"acc_cutoff": _param(20.0, np.nan)}) is None
    assert wald_p_value("bias_drift", {"gyro_drift": _param([1e-6] * 3, [np.nan] * 3)}) is None


def test_physical_limits_and_undetermined_parameters():
    assert implausible("cross_axis", {"alpha": _param([0.01, -0.02, 0.0], [np.nan] * 3)}) is None
    assert "beyond the physical limit" in implausible(
        "cross_axis", {"alpha": _param([0.01, -0.3, 0.0], [np.nan] * 3)})
    assert "not determined" in implausible(
        "scale_nonlinearity", {"k2": _param([np.nan] * 3, [np.nan] * 3)})
    assert "Earth's rate" in implausible("earth_rate", {"vertical": _param(2e-3, 1e-6)})


def _hold(i0: int, i1: int) -> SimpleNamespace:
    """A still period of samples i0 .. i1-1, none of them left out."""
    return SimpleNamespace(i0=i0, i1=i1, kept=lambda: np.arange(i0, i1))


def test_a_hold_too_short_to_score_joins_the_moves():
    t = np.arange(0.0, 100.0, 0.01)                    # 100 Hz
    holds = [_hold(0, 1000), _hold(1200, 1350), _hold(1500, 3000)]      # 10 s, 1.5 s, 15 s
    kept, short = scorable_holds(t, holds)
    assert [h.i0 for h in kept] == [0, 1500] and short == 1
