"""Identifiability of y = b + F·u from a set of poses (apmcal/solvers/identifiability.py)."""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.core.constants import MG_TO_MS2, MRAD_TO_RAD, STANDARD_GRAVITY, earth_rate_ned
from apmcal.core.errors import ApmcalError
from apmcal.solvers.identifiability import identifiability, jacobian, six_faces

G = STANDARD_GRAVITY
LEVEL = [[0.0, 0.0, -G]]          # ArduPilot level: acc reads (0, 0, −g) (ardupilot-facts.md)


def test_jacobian_matches_finite_differences_of_the_model():
    rng = np.random.default_rng(3)
    u = rng.normal(size=(4, 3))
    theta = rng.normal(size=12)

    def y(th):
        b, F = th[:3], th[3:].reshape(3, 3)
        return np.concatenate([b + F @ uk for uk in u])

    fd = np.column_stack([(y(theta + 1e-6 * e) - y(theta - 1e-6 * e)) / 2e-6 for e in np.eye(12)])
    np.testing.assert_allclose(jacobian(u, "full"), fd, atol=1e-8)


def test_one_pose_accelerometer_is_rank_3_of_12():
    r = identifiability("acc", LEVEL)
    assert (r.rank, r.n_params) == (3, 12)
    assert r.condition == float("inf")
    assert not any(r.determinable.values())
    text = "\n".join(r.lines)
    assert "b_x, F_xz cannot be separated" in text
    assert "b_x + (-9.807)·F_xz" in text
    assert "F_xx NOT determinable — no effect" in text


def test_six_faces_determine_bias_and_full_matrix():
    r = identifiability("acc", six_faces(G))
    assert (r.rank, r.n_params) == (12, 12)
    assert all(r.determinable.values())
    assert np.isfinite(r.condition) and r.condition < 10
    ru = identifiability("acc", six_faces(G), matrix="upper")     # [Oppong] F convention
    assert (ru.rank, ru.n_params) == (9, 9)


def test_level_and_upside_down_separate_z_only():
    r = identifiability("acc", [[0, 0, -G], [0, 0, G]])
    assert r.rank == 6
    assert r.determinable["b_x"] and r.determinable["F_xz"] and r.determinable["F_zz"]
    assert not r.determinable["F_xx"] and not r.determinable["F_yy"]


def test_gyro_at_rest_scale_terms_not_determinable_at_raw_imu_resolution():
    # Earth rate 0.073 mrad/s vs RAW_IMU's 1 mrad/s step (ardupilot-facts.md)
    r = identifiability("gyr", [earth_rate_ned(51.5)], matrix="upper", resolution=MRAD_TO_RAD)
    assert r.rank == 3
    for n in ("F_xx", "F_xz", "F_yz", "F_zz"):
        assert not r.resolvable[n]
        assert any(line.startswith(f"gyr: {n} not determinable at 0.001 rad/s") for line in r.lines)
    assert r.resolvable["b_x"]


def test_fast_rotations_make_gyro_matrix_resolvable():
    r = identifiability("gyr", six_faces(1.0), resolution=MRAD_TO_RAD)   # ±1 rad/s about each axis
    assert r.rank == 12 and all(r.resolvable.values())


def test_accelerometer_faces_resolvable_at_1_mg():
    r = identifiability("acc", six_faces(G), resolution=MG_TO_MS2)
    assert all(r.resolvable.values())


@pytest.mark.parametrize("kw", [{"model": "baro", "design": LEVEL},
                                {"model": "acc", "design": [[1.0, 2.0]]},
                                {"model": "acc", "design": [[np.nan, 0, 0]]},
                                {"model": "acc", "design": LEVEL, "matrix": "lower"}])
def test_bad_input_raises_apmcal_error(kw):
    with pytest.raises(ApmcalError):
        identifiability(**kw)
