"""The simplest sufficient explanation: ArduPilot SITL's triangle drift on a warming board.

A still recording like one from ArduPilot's own SITL: the gyro bias follows SITL's triangle
drift (the same on every axis, turning back after 5 minutes), the temperature rises the whole
time but has no effect, and the firmware's 20 Hz low-pass filter shapes the logged noise at
200 Hz. Before the change a random walk was selected beside the triangle (it bends to the
triangle as well); a temperature drift fits the rising half as well. Only the triangle holds
where temperature and time part.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from apmcal.cli import main
from apmcal.diagnosis.scoring.select import EffectScore, simplest_best
from apmcal.diagnosis.session.decimate import FINE_EFFECTS

ROOT = Path(__file__).resolve().parents[1]


def test_a_random_walk_gives_way_to_a_deterministic_effect_within_the_share():
    rw = EffectScore("bias_random_walk", evidence=1000.0, supported=True)
    tri = EffectScore("triangle_drift", evidence=960.0, supported=True)
    far = EffectScore("temperature_drift", evidence=900.0, supported=True)
    assert simplest_best([rw, tri, far]).name == "triangle_drift"
    assert simplest_best([rw, far]).name == "bias_random_walk"          # 10 % short: not
    weak = EffectScore("triangle_drift", evidence=990.0, supported=False)
    assert simplest_best([rw, weak]).name == "bias_random_walk"         # must be supported
    assert simplest_best([tri, far]).name == "triangle_drift"
    assert simplest_best([]) is None


@pytest.fixture(scope="module")
def triangle(tmp_path_factory):
    from apmcal.sensor_model.truth import NOMINAL_EFFECTS, Truth

    out = tmp_path_factory.mktemp("triangle")
    truth = Truth.random(7).with_effects(
        disable=["all"], enable=list(NOMINAL_EFFECTS) + ["triangle_drift", "temperature_drift",
                                                         "lowpass_filter"], prefer="diagnosis")
    truth.temperature.update({"acc_coef": [0.0] * 3, "gyro_coef": [0.0] * 3, "ambient_c": 25.0,
                              "rise_k": 20.0, "tau_s": 300.0})      # SIM_IMUT_* defaults
    truth.gyro_noise, truth.acc_noise = 4.0e-5, 4.1e-4             # SITL's size per sample
    truth.lowpass_hz = 20.0
    truth.save(out / "truth.json")
    log = out / "sitl.bin"
    subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", "warmup", "--out",
                    str(log), "--rate", "200", "--fs", "200", "--duration", "628", "--seed", "7",
                    "--truth", str(out / "truth.json")], check=True, cwd=ROOT, timeout=300)
    assert main(["gap", str(log), "--json", str(out / "gap.json"), "--quiet"]) == 0
    return json.loads((out / "gap.json").read_text())


def test_the_triangle_alone_among_the_slow_effects(triangle):
    slow = [n for n in triangle["selected"] if n not in FINE_EFFECTS]
    assert slow == ["triangle_drift"], triangle["selected"]
    by_name = {e["name"]: e for e in triangle["effects"]}
    temp = by_name["temperature_drift"]
    assert temp["supported_alone"] and not temp["significant"]          # it fits, alone ...
    assert temp["confounded_with"] == "triangle_drift"                  # ... where they agree
    assert not by_name["bias_random_walk"]["significant"]
    speed = by_name["triangle_drift"]["params"]["speed"]["value"]
    assert speed == pytest.approx(0.05, abs=0.002)                      # °/s per minute
    assert by_name["triangle_drift"]["params"]["drift_time"]["value"] == pytest.approx(5.0)
    assert "lowpass_filter" in triangle["selected"]                     # the firmware's 20 Hz
    cutoff = by_name["lowpass_filter"]["params"]["gyr_cutoff"]["value"]
    assert 15.0 < cutoff < 27.0
