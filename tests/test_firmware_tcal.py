"""`apmcal tcal` on ArduPilot's own firmware (SITL): a still warm-up with a temperature drift
injected through SIM_IMUT1_* (SIM_IMUT1_TMIN/TMAX centred on INS_TCAL's 35 °C reference, so the
exact INS_TCAL1_* are the injected coefficients, per the firmware README) is recovered within
3σ from the firmware's dataflash log, on two seeds.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.ardupilot_sitl

WARMUP_S = 420.0        # simulated seconds still: 7 time constants of the board's warming
BOOT = {"SIM_IMUT1_ENABLE": 1, "SIM_IMUT_START": 25, "SIM_IMUT_END": 45,
        "SIM_IMUT_TCONST": 60, "SIM_DRIFT_SPEED": 0, "LOG_DISARMED": 1}


def injected_drift(seed: int) -> dict[str, float]:
    """SIM_IMUT1_* coefficients for ``seed`` (1e-6 m/s² or rad/s per K^k), TMIN/TMAX 25/45."""
    rng = np.random.default_rng(300 + seed)
    params = {"SIM_IMUT1_TMIN": 25.0, "SIM_IMUT1_TMAX": 45.0}
    spans = {"ACC": (3000, 120, 6), "GYR": (400, 20, 1.5)}
    for sensor, (s1, s2, s3) in spans.items():
        for k, span in ((1, s1), (2, s2), (3, s3)):
            for axis in "XYZ":
                params[f"SIM_IMUT1_{sensor}{k}_{axis}"] = round(float(rng.uniform(-span, span)), 2)
    return params


@pytest.mark.parametrize("seed", [1, 2])
def test_tcal_recovers_the_injected_temperature_drift_from_the_firmware_log(
        ardupilot_sitl, tmp_path, seed):
    injected = injected_drift(seed)
    # at boot, with the warm-up: set afterwards, each write's round trip lets simulated time
    # pass (minutes of it at this speedup), and the first part of the warm-up would have none
    sitl = ardupilot_sitl(speedup=200, boot_params={**BOOT, **injected})
    sitl.set_params(injected)                   # each value confirmed by the firmware's echo
    sitl.run_for(WARMUP_S)                      # level and still from boot: the model's rest
    sitl.stop()
    log = sitl.dataflash_logs()[-1]
    out = tmp_path / "tcal.json"
    run = subprocess.run([sys.executable, "-m", "apmcal", "tcal", str(log), "--instance", "0",
                          "--json", str(out)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    fit = json.loads(out.read_text())["tcal"][0]
    assert fit["significant"], fit
    for sensor, name in (("acc", "ACC"), ("gyr", "GYR")):
        got = np.asarray(fit[sensor]["c1_c2_c3_xyz"])
        sigma = np.asarray(fit[sensor]["sigma"])
        want = np.array([[injected[f"SIM_IMUT1_{name}{k}_{a}"] for a in "XYZ"]
                         for k in (1, 2, 3)])
        off = np.abs(got - want) / sigma
        assert off.max() < 3, (sensor, got.round(2).tolist(), want.tolist(), off.round(1))
