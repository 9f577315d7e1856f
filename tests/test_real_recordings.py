"""Every method through `apmcal log` on the real recordings in ../shared/data.

Each case says what the data allow (see ../shared/data/README.md): a method either calibrates,
or refuses with the one-line reason a user needs. A refusal that turned into a result (or the
reverse) is a change in behaviour this test must catch.
"""
import json

import numpy as np
import pytest

from apmcal.cli import main

WORKS, REFUSES = "works", "refuses"
CASES = [
    # file, method, outcome, what the output or the refusal must contain
    ("imucal/example_ferraris_session.csv", "auto", WORKS, "ferraris"),
    ("imucal/example_ferraris_session.csv", "ferraris", WORKS, "ferraris"),
    ("imucal/example_ferraris_session.csv", "ellipsoid", WORKS, "ellipsoid"),
    ("imucal/example_ferraris_session.csv", "static", WORKS, "static"),       # z_a hold is level
    ("mpu6050/example_data_calibration.csv", "auto", WORKS, "ellipsoid"),
    ("mpu6050/example_data_calibration.csv", "ferraris", REFUSES, "z_a"),     # 1.5 s z_a hold
    ("imu_tk/xsens_acc.mat", "auto", WORKS, "ellipsoid"),                     # 38 holds, counts
    ("imu_tk/xsens_acc.mat", "static", REFUSES, "no level still period"),
    ("ardupilot/pxf_copter_static_51.BIN", "auto", WORKS, "static"),          # level on a desk
    ("ardupilot/pxf_copter_static_51.BIN", "ellipsoid", REFUSES, "1 orientation"),
    ("ardupilot/pxf_copter_static_51.BIN", "ferraris", REFUSES, "needs all six holds"),
    ("ardupilot/pxf_copter_mag.BIN", "auto", WORKS, "static"),
    ("ardupilot/pixhawk1_copter368.bin", "auto", WORKS, "static"),
    ("ardupilot/pixhawk_3imu_log171.bin", "static", WORKS, "static"),         # board PITCH_180
    ("ardupilot/ardusub_small.tlog", "static", WORKS, "static"),              # board ROLL_90
    ("ardupilot/sitl_vtol.tlog", "auto", WORKS, "static"),                    # time jumps back
    ("ardupilot/copter311_nan.log", "static", REFUSES, "too short"),          # 4 s still
    ("ardupilot/ardusub_small.tlog", "ellipsoid", REFUSES, "orientation"),
]


@pytest.mark.parametrize("name,method,outcome,needle", CASES,
                         ids=[f"{c[0].split('/')[-1]}-{c[1]}" for c in CASES])
def test_method_on_real_recording(shared_data, tmp_path, capsys, name, method, outcome, needle):
    out = tmp_path / "result.json"
    status = main(["log", str(shared_data / name), "--method", method, "--quiet",
                   "--json", str(out)])
    err = capsys.readouterr().err
    if outcome == WORKS:
        assert status in (0, 1), err        # 1: computed, but a value is out of the firmware's limits
        result = json.loads(out.read_text())
        assert result["method"] == needle
        assert {"offset", "matrix", "sigma"} <= set(result["acc"])
    else:
        assert status == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0], err


def test_mpu6050_ellipsoid_agrees_with_the_reference_tool(shared_data, tmp_path):
    """`apmcal log` on tomisuarez2's MPU-6050 run against that repo's own result (Tedaldi
    method, a = T·K·(counts + b), K in m/s² per count): an independent tool, other holds, other
    model, so agreement is to its few-mm/s² and 0.1 % level, not to our sigma alone."""
    out = tmp_path / "mpu.json"
    assert main(["log", str(shared_data / "mpu6050/example_data_calibration.csv"),
                 "--min-still", "1", "--quiet", "--json", str(out)]) == 0
    acc = json.loads(out.read_text())["acc"]
    ref = np.loadtxt(shared_data / "mpu6050/ref_params_acc.csv")
    counts_to_si = 9.80665 / 16384.0                      # the reader's ±2 g conversion
    np.testing.assert_allclose(acc["offset"], -ref[6:9] * counts_to_si, atol=0.015)
    np.testing.assert_allclose(np.diag(acc["matrix"]), ref[3:6] / counts_to_si, atol=0.002)
