"""The joint method ([Chow]) on a hand-held-like session recorded from ArduPilot's own firmware
(SITL, ../shared/ardupilot-sitl): the ``calibration`` model turned by hand-like spins (90-180°
about random axes at 35-90 °/s) between uneven holds, with accelerometer, gyro and compass
errors injected through SIM_*; ``apmcal log --method joint`` on its dataflash log must propose
the exact calibration the firmware's README gives for them.

The firmware's gravity is 9.80665 m/s² while apmcal scales the accelerometer to the normal
gravity at --lat (9.7967 at the default home): INS_ACCSCAL = SIM_ACC1_SCAL × 9.7967 / 9.80665.
Its compass field comes from ArduPilot's own tables (579.3 mGauss there) while apmcal scales the
compass to the WMM's magnitude at the site: COMPASS_DIA/ODI = SIM_MAG1_DIA/ODI × F_WMM / 579.3.
The firmware's calibration model adds no sensor noise and logs the compass in whole mGauss at
10 Hz: the joint fit runs on white-noise floors there (apmcal/solvers/joint/residuals.py).
"""
from __future__ import annotations

import json
import math
import random

import numpy as np
import pytest
from firmware_sessions import known_failure

from apmcal.ardupilot.paramfile import read_param_file
from apmcal.cli import main
from apmcal.core.constants import normal_gravity

pytestmark = pytest.mark.ardupilot_sitl

HOME = (-35.363262, 149.165237)          # the firmware's default home
INJECTED = {"SIM_ACC1_BIAS_X": 0.3, "SIM_ACC1_BIAS_Y": -0.2, "SIM_ACC1_BIAS_Z": 0.25,
            "SIM_ACC1_SCAL_X": 1.02, "SIM_ACC1_SCAL_Y": 0.98, "SIM_ACC1_SCAL_Z": 1.01,
            "SIM_GYR1_BIAS_X": 0.02, "SIM_GYR1_BIAS_Y": -0.015, "SIM_GYR1_BIAS_Z": 0.01,
            "SIM_MAG1_OFS_X": 100.0, "SIM_MAG1_OFS_Y": -50.0, "SIM_MAG1_OFS_Z": 80.0,
            "SIM_MAG1_DIA_X": 1.05, "SIM_MAG1_DIA_Y": 0.97, "SIM_MAG1_DIA_Z": 1.02,
            "SIM_MAG1_ODI_X": 0.02, "SIM_MAG1_ODI_Y": -0.01, "SIM_MAG1_ODI_Z": 0.03}
# the dataflash log from boot; no gyro drift (a triangle wave no calibration undoes)
BOOT = {"LOG_DISARMED": 1, "SIM_DRIFT_SPEED": 0, **INJECTED}
FIRMWARE_FIELD_MGAUSS = 579.3            # the firmware's table field at HOME (its README)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The session (about 140 simulated seconds) and apmcal's JSON result and proposal."""
    from ardupilot_sitl import ArduPilotSitl, unavailable_reason

    if unavailable_reason():
        pytest.skip(unavailable_reason())
    tmp = tmp_path_factory.mktemp("joint-sitl")
    rng = random.Random(3)
    with ArduPilotSitl(tmp / "sitl", speedup=400, boot_params=BOOT) as sitl:
        sitl.run_for(4.0)
        for _ in range(14):
            axis = [rng.gauss(0, 1) for _ in range(3)]
            rate = rng.uniform(0.6, 1.6)                       # rad/s
            sitl.spin(rate, axis)
            sitl.run_for(math.radians(rng.uniform(90, 180)) / rate)
            sitl.halt()                                        # a damped stop, then held
            sitl.run_for(rng.uniform(5.0, 8.0))
        log = sitl.dataflash_logs()[-1]
    out, params = tmp / "joint.json", tmp / "joint.param"
    status = main(["log", str(log), "--method", "joint", "--lat", str(HOME[0]), "--lon",
                   str(HOME[1]), "--json", str(out), "--param-file", str(params), "--quiet"])
    return {"status": status, "est": json.loads(out.read_text()),
            "params": read_param_file(params)}


def expected(field_mgauss: float) -> dict[str, float]:
    """The exact calibration of the README's table, in apmcal's gravity and field (the WMM
    magnitude ``field_mgauss`` the result was scaled to)."""
    scale = normal_gravity(HOME[0]) / 9.80665
    ratio = field_mgauss / FIRMWARE_FIELD_MGAUSS
    out = {}
    for axis in "XYZ":
        out[f"INS_ACCOFFS_{axis}"] = INJECTED[f"SIM_ACC1_BIAS_{axis}"]
        out[f"INS_ACCSCAL_{axis}"] = INJECTED[f"SIM_ACC1_SCAL_{axis}"] * scale
        out[f"INS_GYROFFS_{axis}"] = INJECTED[f"SIM_GYR1_BIAS_{axis}"]
        out[f"COMPASS_OFS_{axis}"] = INJECTED[f"SIM_MAG1_OFS_{axis}"]
        out[f"COMPASS_DIA_{axis}"] = INJECTED[f"SIM_MAG1_DIA_{axis}"] * ratio
        out[f"COMPASS_ODI_{axis}"] = INJECTED[f"SIM_MAG1_ODI_{axis}"] * ratio
    return out


# tolerances: what the log carries (floats for the IMU, whole mGauss for the compass at 10 Hz)
TOLERANCE = {"INS_ACCOFFS": 0.003, "INS_ACCSCAL": 0.001, "INS_GYROFFS": 2e-4,
             "COMPASS_OFS": 1.0, "COMPASS_DIA": 0.005, "COMPASS_ODI": 0.005}


def test_the_joint_fit_converges_on_the_firmware_session(recorded):
    joint = recorded["est"]["report"]["joint"]
    assert recorded["status"] == 0
    assert joint["converged"] and not joint["fallback"]
    assert recorded["est"]["method"] == "joint"


def test_it_proposes_the_exact_calibration(recorded):
    got = recorded["params"]
    for name, want in expected(recorded["est"]["report"]["magnetic_field"]["mgauss"]).items():
        assert got[name] == pytest.approx(want, abs=TOLERANCE[name[:-2]]), name


def test_the_firmware_gyro_has_no_scale_error_and_the_fit_finds_none(recorded):
    """SITL's gyro is its rate plus SIM_GYR1_BIAS: the diagonal of the joint's gyro matrix (its
    scale) must be 1 (largest error 1.1e-3 over 10 recordings; docs/joint-validation.md)."""
    gyr = np.array(recorded["est"]["gyr"]["matrix"])
    assert np.abs(np.diag(gyr) - 1).max() < 2e-3


@known_failure("8 of 10", "a cross-axis term of ±2.2e-3 kept on the others, 4.3σ on one (the σ "
                         "of the gyro matrix is too small on the firmware's 25 Hz IMU log; "
                         "docs/joint-validation.md)")
def test_the_firmware_gyro_has_no_cross_axis_terms_and_the_fit_finds_none(recorded):
    """Its cross-axis terms are zero too, and the accelerometer frame the joint's gyro matrix
    is taken in has no rotation here (SIM_ACC1 has only bias and scale)."""
    gyr = np.array(recorded["est"]["gyr"]["matrix"])
    assert np.abs(gyr - np.diag(np.diag(gyr))).max() < 2e-3
