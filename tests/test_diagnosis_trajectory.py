"""The twin's motion: attitude integration, instantaneous rates, corrected moves."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from apmcal.diagnosis.session.trajectory import (
    attitude,
    body_rates,
    corrected_move,
    integrate_attitude,
    prefix_products,
)

RNG = np.random.default_rng(3)


def test_prefix_products_equal_sequential_products():
    q = Rotation.from_rotvec(RNG.standard_normal((777, 3)) * 0.1).as_quat()
    got = Rotation.from_quat(prefix_products(q))
    current = Rotation.identity()
    for i, step in enumerate(Rotation.from_quat(q)):
        current = current * step
        if i in (0, 5, 400, 776):
            assert (got[i].inv() * current).magnitude() < 1e-12


def test_integration_of_a_constant_rate_is_exact():
    r0 = Rotation.from_rotvec([0.2, -0.1, 0.3]).as_matrix()
    rate = np.tile([0.0, 0.0, 1.5], (200, 1))
    dt = np.full(200, 0.01)
    end = integrate_attitude(r0, rate, dt)[-1]
    np.testing.assert_allclose(end, r0 @ Rotation.from_rotvec([0, 0, 3.0]).as_matrix(),
                               atol=1e-12)


def test_body_rates_are_instantaneous():
    """A rate ramp sampled like a gyro: the central estimate has no half-sample lag."""
    t = np.arange(300) / 100.0
    angle = 0.5 * t ** 2                          # rate = t about z
    rot = Rotation.from_rotvec(np.outer(angle, [0, 0, 1])).as_matrix()
    w = body_rates(rot, t)
    np.testing.assert_allclose(w[1:-1, 2], t[1:-1], atol=1e-9)


def test_corrected_move_starts_follows_and_ends_where_asked():
    r0 = np.eye(3)
    target = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()
    rate = np.tile([0.0, 0.0, np.pi / 2 * 1.02 / 3.0], (300, 1))    # a 2 % scale error
    path, error = corrected_move(r0, target, rate, np.full(300, 0.01))
    np.testing.assert_allclose(path[0], r0, atol=1e-12)
    np.testing.assert_allclose(path[-1], target, atol=1e-12)
    np.testing.assert_allclose(error, [0, 0, -0.02 * np.pi / 2], atol=1e-12)   # 2 % too far


def test_attitude_puts_up_and_north_where_asked():
    up = np.array([0.1, -0.2, 0.97])
    north = np.array([1.0, 0.3, 0.0])
    r = attitude(up, north)
    np.testing.assert_allclose(r @ (up / np.linalg.norm(up)), [0, 0, -1], atol=1e-12)
    n_ned = r @ north
    assert n_ned[0] > 0 and abs(n_ned[1]) < 1e-12
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
