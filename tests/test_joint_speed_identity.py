"""benchmarks/joint_speed.py's identity check, which every speed change of the joint method must
pass on the simulated session and on the real recordings: the same parameters estimated and
dropped, none moved by more than 0.1 σ, no σ changed by more than 1 %."""
from __future__ import annotations

import copy

import pytest

from benchmarks import joint_speed

BASE = {"acc_bias_x": [0.1, 0.01], "gyr_scale_z": [0.002, 0.0005], "mag_hard_x": [40.0, 1.0]}


@pytest.mark.parametrize("change, same", [
    (None, True),
    (("acc_bias_x", 0, 0.1 + 0.0005), True),          # 0.05 σ
    (("acc_bias_x", 0, 0.1 + 0.002), False),          # 0.2 σ
    (("gyr_scale_z", 1, 0.0005 * 1.02), False),       # σ 2 % larger
])
def test_compare_holds_parameters_and_sigma(change, same, capsys):
    now = copy.deepcopy(BASE)
    if change:
        name, k, value = change
        now[name][k] = value
    assert joint_speed.compare(now, BASE, ["gyr_gsens_xx"], ["gyr_gsens_xx"], "base") is same


def test_compare_holds_the_dropped_and_estimated_sets(capsys):
    assert not joint_speed.compare(BASE, BASE, ["gyr_gsens_xx"], [], "base")
    fewer = {k: v for k, v in BASE.items() if k != "mag_hard_x"}
    assert not joint_speed.compare(fewer, BASE, [], [], "base")


def test_the_real_recordings_check_runs_and_the_joint_fit_repeats_itself(shared_data, capsys,
                                                                         monkeypatch):
    """On the smallest real recording (the MPU-6050 run), this tree against itself in two fresh
    processes: the check runs on real data and finds the fit repeating itself."""
    sessions = [s for s in joint_speed.real_sessions() if s[0].startswith("mpu6050")]
    assert sessions
    monkeypatch.setattr(joint_speed, "real_sessions", lambda: sessions)
    assert joint_speed.real_identity(joint_speed.ROOT, "this tree")
    assert "results unchanged: yes" in capsys.readouterr().out
