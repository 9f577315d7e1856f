"""The joint method out of sample on every real recording with turns between still poses
(../shared/data; skipped when absent): fitted on the first still poses, the calibrated gyro
carries gravity across the turns after them (or across a separate recording of the same sensor)
and is compared with the gravity measured there ([Chow] §5). The joint fit must never be worse
than the ellipsoid + static calibration beyond the check's own noise
(:func:`apmcal.calibration.validation.check_noise_deg`: what the sensors' white noise alone
gives). ``python benchmarks/joint_validation.py`` prints the whole table (docs/joint-validation.md).

Truth here is the recording itself: the measured gravity direction at poses no fit saw.
"""
from __future__ import annotations

import numpy as np
import pytest
from conftest import SKIP_REASON, shared_data_path

from apmcal.calibration.validation import REAL_RECORDINGS, out_of_sample
from apmcal.solvers.joint.residuals import at_range_limit

NOISE_MARGIN = 2.0      # "beyond noise": the check's own noise, twice


@pytest.fixture(scope="module", params=REAL_RECORDINGS, ids=lambda r: r.file.split("/")[0]
                + ("-" + r.check_file.split("/")[-1] if r.check_file else "-later-poses"))
def scores(request):
    data = shared_data_path()
    if data is None:
        pytest.skip(SKIP_REASON)
    return request.param, out_of_sample(request.param, data, ("raw", "ellipsoid", "joint"))


def test_joint_is_never_worse_than_the_ellipsoid_beyond_noise(scores):
    rec, s = scores
    joint, ellipsoid = s["joint"], s["ellipsoid"]
    assert joint.pairs >= 1 and joint.note == ""           # the fit itself, no fallback
    assert joint.rms_deg <= ellipsoid.rms_deg + NOISE_MARGIN * joint.noise_deg, (
        rec.name, joint, ellipsoid)


def test_joint_beats_the_raw_sensor(scores):
    """The check can tell a calibration from none: raw samples are worse by far."""
    _, s = scores
    assert s["joint"].rms_deg < 0.5 * s["raw"].rms_deg


def test_a_gyro_at_its_range_limit_is_found_on_the_real_mpu6050(shared_data):
    """The MPU-6050 run was turned faster than its ±250 °/s: three turns read a flat 250.1 °/s.
    They are left out of the fit and of the check (the turn read is not the turn made)."""
    from apmcal.calibration.validation import session

    raw = session(shared_data / "mpu6050" / "example_data_calibration.csv", "mpu6050")[2]
    limit = at_range_limit(raw.xyz("gyr"))
    assert np.degrees(np.abs(raw.xyz("gyr")[limit]).max()) == pytest.approx(250.1, abs=0.1)
    starts = np.flatnonzero(np.diff(np.append(0, limit.astype(int))) == 1)
    assert len({int(raw.t[k]) // 5 for k in starts}) == 3            # three turns
    assert not at_range_limit(session(shared_data / "mpu6050" / "imu_90_x_rot.csv",
                                      "mpu6050")[2].xyz("gyr")).any()
