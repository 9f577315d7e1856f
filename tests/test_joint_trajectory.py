"""The joint solver's batched parts (apmcal.solvers.joint.trajectory, and the design matrix,
interval noise and whitening built on it) against their definitions, computed the slow way:
window by window, step by step, by finite differences. A small synthetic session: still
poses at 200 Hz with hand turns between them, no simulator needed."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from apmcal.preprocessing.static import make_segment
from apmcal.solvers.joint import covariance as jc
from apmcal.solvers.joint import model as jm
from apmcal.solvers.joint.jacobian import jacobian
from apmcal.solvers.joint.residuals import layout, misclosures
from apmcal.solvers.joint.solve import _Compressed, _families
from apmcal.solvers.joint.trajectory import Trajectory, frames
from apmcal.solvers.strapdown import hat, midpoint, so3_exp

FS = 200.0
GRAVITY = 9.80665
FIELD = np.array([300.0, 0.0, -400.0])        # mGauss, NED-like, magnitude 500


def _products(steps: np.ndarray) -> np.ndarray:
    """S_k = E_0·…·E_k of (K, 3, 3) step matrices, one at a time (the reference)."""
    out = np.empty_like(steps)
    acc = np.eye(3)
    for k, e in enumerate(steps):
        acc = acc @ e
        out[k] = acc
    return out


@pytest.fixture(scope="module")
def session():
    """5 still poses of 2 s and 4 turns of 1.5 s (≈ 70-110° each, about changing axes) at
    200 Hz: raw samples with small sensor errors and white noise, the holds by hand."""
    rng = np.random.default_rng(7)
    hold, turn = int(2 * FS), int(1.5 * FS)
    axes = [np.array(a, float) / np.linalg.norm(a) for a in
            ((1, 0, 0), (0, 1, 0.3), (0.2, 0.3, 1), (1, -1, 0))]
    rate, spans = [], []
    for k, axis in enumerate(axes + [None]):
        spans.append((len(rate), len(rate) + hold))
        rate += [np.zeros(3)] * hold
        if axis is not None:
            tau = np.arange(turn) / turn
            rate += list(axis[None] * (1.6 * np.sin(np.pi * tau) ** 2)[:, None] * (1 + 0.2 * k))
    w = np.array(rate)
    t = np.arange(len(w)) / FS
    att = np.empty((len(w), 3, 3))
    att[0] = np.eye(3)
    for k in range(1, len(w)):
        att[k] = att[k - 1] @ so3_exp(0.5 * (w[k - 1] + w[k]) / FS)
    acc = np.einsum("nji,j->ni", att, [0.0, 0.0, -GRAVITY])     # specific force, body frame
    mag = np.einsum("nji,j->ni", att, FIELD)
    acc = acc @ np.diag([1.01, 0.99, 1.0]).T + [0.05, -0.03, 0.02]
    gyr = w @ np.diag([1.005, 1.0, 0.995]).T + [0.01, -0.005, 0.002]
    mag = mag @ np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.0]]).T + [40, -20,
                                                                                          10]
    acc += rng.normal(0, 0.02, acc.shape)
    gyr += rng.normal(0, 0.002, gyr.shape)
    mag += rng.normal(0, 1.0, mag.shape)
    holds = [make_segment(t, acc, gyr, i0, i1) for i0, i1 in spans]
    d = layout(t, acc, gyr, mag, holds, GRAVITY, float(np.linalg.norm(FIELD)))
    x = jm.NOMINAL.copy()
    x += np.random.default_rng(3).normal(0, 1e-3, x.size)
    return d, x


def test_frames_are_the_products_of_the_step_rotations():
    """Q_k from the quaternion running product against the step matrices multiplied one by
    one; any window's dR = Q_sᵀ·Q_e against the product of its own steps."""
    theta = np.random.default_rng(1).normal(0, 0.03, (3000, 3))
    q = frames(theta)
    ref = _products(so3_exp(theta))
    assert np.allclose(q[0], np.eye(3))
    assert np.abs(q[1:] - ref).max() < 1e-12
    s, e = 1234, 1891
    window = _products(so3_exp(theta[s:e]))[-1]
    assert np.abs(q[s].T @ q[e] - window).max() < 1e-12


def test_velocity_change_is_the_sum_over_the_window(session):
    """Δv of [Chow] eq. 11 from the running sums against Σ_k dR(s, k)·a_k·Δt_k step by step."""
    d, x = session
    tr = Trajectory(x, d)
    steps = so3_exp(midpoint(tr.w) * d.dt[:, None])
    for s, e in d.interval_index[:, 2:]:
        pk = np.concatenate([np.eye(3)[None], _products(steps[s:e - 1])])   # dR(s, k)
        ref = np.einsum("kij,kj->i", pk, tr.a[s:e] * d.dt[s:e, None])
        assert np.abs(tr.delta_v(np.array([s]), np.array([e]))[0] - ref).max() < 1e-10


def test_design_matrix_matches_finite_differences(session):
    """Every family's analytic ∂w/∂X against central differences of the misclosures. The
    analytic one takes each step's right Jacobian of Exp as the identity (|ω·Δt| ≤ 0.015 rad
    here), so a turn-dependent column may differ by about that fraction, never more."""
    d, x = session
    families = _families(d)
    free = np.ones(jm.N_PARAMS, bool)
    ana = jacobian(x, d, families, free)
    for i in range(jm.N_PARAMS):
        h = 1e-6 * max(1.0, abs(x[i]))
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        wu, wd = misclosures(up, d, families), misclosures(down, d, families)
        for f in families:
            num = (wu[f] - wd[f]) / (2 * h)
            scale = max(np.abs(num).max(), np.abs(ana[f][..., i]).max(), 1e-9)
            err = np.abs(ana[f][..., i] - num).max() / scale
            assert err < 0.02, (f, jm.NAMES[i], err)


def test_design_matrix_with_only_the_compass_free(session):
    """The t-test's refit may keep only magnetometer parameters (a real flight log did: it
    crashed on the empty accelerometer and gyro columns): the columns are those of the full
    matrix."""
    d, x = session
    families = _families(d)
    only = np.zeros(jm.N_PARAMS, bool)
    only[[30, 34, 40]] = True
    full = jacobian(x, d, families, np.ones(jm.N_PARAMS, bool))
    part = jacobian(x, d, families, only)
    for f in families:
        assert part[f].shape[-1] == 3
        assert np.abs(part[f] - full[f][..., only]).max() <= 1e-12 * max(
            np.abs(full[f]).max(), 1.0)


def test_interval_gyro_noise_is_the_sum_over_steps(session):
    """The levelling and ZUPT covariance from the gyro noise of an interval, closed form
    (S_k·S_kᵀ = I), against σ_ω²·Σ_k B_k·B_kᵀ with B_k = [−Eᵀ·dRᵀ·[û_i]×·S_k·Δt_k;
    −[C_k]×·S_k·Δt_k] built step by step."""
    d, x = session
    d.noise = dict(d.noise, acc=1e-12)          # the gyro's part alone
    tr = Trajectory(x, d)
    families = _families(d)
    cov, _ = jc.inertial_covariance(tr, d, families)
    nb, ni = len(d.blocks), len(d.intervals)
    a_blk = d.block_mean @ tr.a
    steps = so3_exp(midpoint(tr.w) * d.dt[:, None])
    for r, (bi, _bj, k0, k1) in enumerate(d.intervals):
        s = _products(steps[k0:k1])
        dt = d.dt[k0:k1]
        pk = np.concatenate([np.eye(3)[None], s[:-1]])
        pf = np.einsum("kij,kj->ki", pk, tr.a[k0:k1] * dt[:, None])
        c = np.cumsum(pf[::-1], axis=0)[::-1] - pf
        ui = a_blk[bi] / np.linalg.norm(a_blk[bi])
        b = np.concatenate([-d.level_basis[r].T @ s[-1].T @ hat(ui) @ s,
                            -hat(c) @ s], axis=1) * dt[:, None, None]          # (K, 5, 3)
        ref = d.noise["gyr"] ** 2 * np.einsum("kij,klj->il", b, b)
        rows = np.r_[nb + 2 * r:nb + 2 * r + 2, nb + 2 * ni + 3 * r:nb + 2 * ni + 3 * r + 3]
        got = cov[np.ix_(rows, rows)]
        assert np.abs(got - ref).max() < 1e-9 * np.abs(ref).max()


def test_inverse_cholesky_of_small_matrices():
    """L⁻¹ of many 1×1 to 3×3 covariances as numpy's cholesky then inv; an indefinite one is
    refused as numpy refuses it."""
    rng = np.random.default_rng(2)
    for k in (1, 2, 3):
        m = rng.normal(size=(200, k, k))
        a = m @ np.swapaxes(m, 1, 2) + 0.1 * np.eye(k)
        ref = np.linalg.inv(np.linalg.cholesky(a))
        assert np.abs(jc.inverse_cholesky(a) - ref).max() < 1e-12 * np.abs(ref).max()
    bad = np.array([[[1.0, 2.0], [2.0, 1.0]]])
    with pytest.raises(np.linalg.LinAlgError):
        jc.inverse_cholesky(bad)


def test_cholesky_with_a_diagonal_head(session):
    """The Schur-complement factor of the session's own inertial covariance (its static-norm
    head diagonal) against numpy's of the whole matrix; a matrix that is not positive definite
    is refused."""
    d, x = session
    cov, _ = jc.inertial_covariance(Trajectory(x, d), d, _families(d))
    k = len(d.blocks)
    assert not np.count_nonzero(cov[:k, :k] - np.diag(np.diag(cov[:k, :k])))
    ref = np.linalg.cholesky(cov)
    assert np.abs(jc.cholesky_diagonal_head(cov, k) - ref).max() < 1e-12 * np.abs(ref).max()
    bad = cov.copy()
    bad[-1, -1] = -1.0
    with pytest.raises(np.linalg.LinAlgError):
        jc.cholesky_diagonal_head(bad, k)


def test_compressed_problem_takes_the_same_steps():
    """least_squares (MINPACK LM, the design matrix held fixed) on the 43-row compressed
    problem against the same call on all rows: the same iterations, the same end point."""
    rng = np.random.default_rng(4)
    n, p = 400, 6
    a = rng.normal(size=(n, p)) * np.logspace(0, 3, p)
    truth = rng.normal(size=p) / np.logspace(0, 3, p)
    y = np.sin(a @ truth) + 0.01 * rng.normal(size=n)

    def fun(v):
        return np.sin(a @ v) - y

    x0 = np.zeros(p)
    j0 = np.cos(a @ x0)[:, None] * a
    kw = dict(x_scale="jac", method="lm", xtol=1e-8, ftol=1e-8, max_nfev=10)
    full = least_squares(fun, x0, jac=lambda v: j0, **kw)
    small = _Compressed(fun, j0)
    comp = least_squares(small, x0, jac=small.jacobian, **kw)
    assert comp.nfev == full.nfev
    assert np.abs(comp.x - full.x).max() < 1e-9 * np.abs(full.x).max()
    assert abs(comp.cost - full.cost) < 1e-9 * full.cost


def test_the_compass_datum_is_met_by_a_positive_scale_of_d_m(session):
    """The compass conditions do not see D_m's scale, its sign included: the fit holds the
    datum (the calibrated field's mean magnitude is F) and a positive determinant by scaling
    D_m, which leaves every compass misclosure as it was. A D_m turned negative (the
    calibrated field pointing the other way, equally consistent with the turns) comes back."""
    from apmcal.solvers.joint.solve import _on_datum

    d, x = session
    flipped = x.copy()
    flipped[jm.SLICES["D_m"]] *= -1.7
    fixed = _on_datum(flipped, d)
    mats = jm.matrices(fixed)
    assert np.linalg.det(mats["D_m"]) > 0
    assert np.linalg.norm(jm.correct_mag(d.mag, mats), axis=1).mean() == pytest.approx(d.field)
    for w in (misclosures(flipped, d, ("mag",))["mag"], misclosures(x, d, ("mag",))["mag"]):
        np.testing.assert_allclose(misclosures(fixed, d, ("mag",))["mag"], w, atol=1e-9)
