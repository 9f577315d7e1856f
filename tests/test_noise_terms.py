"""Noise structure of still periods (apmcal.diagnosis.noise.allan, .noise_terms, .bias_track): wavelet
variance, Allan deviation, GMWM noise terms, the fixed-slope baseline and the Kalman/RTS
random-walk check."""
from __future__ import annotations

from types import SimpleNamespace

import allantools
import numpy as np
import pytest

from apmcal.diagnosis.noise import allan, bias_track
from apmcal.diagnosis.noise import terms as noise_terms
from apmcal.sensor_model.imu import ImuErrorModel
from apmcal.sensor_model.truth import Truth

# the three modules under one prefix, the one the tests used before noise.py was split
nz = SimpleNamespace(
    haar_wavelet_variance=allan.haar_wavelet_variance, allan_deviation=allan.allan_deviation,
    fit_noise_terms=noise_terms.fit_noise_terms,
    noise_terms_allan_lines=noise_terms.noise_terms_allan_lines,
    random_walk_bias=bias_track.random_walk_bias, random_walk_loglik=bias_track.random_walk_loglik,
    fit_random_walk_ml=bias_track.fit_random_walk_ml, _walk_filter=bias_track._walk_filter)

FS = 100.0
N_SITL = 8.7e-5          # rad/s/√Hz, one-sided: σ per sample = N·√(fs/2)
Q = 2e-5                 # rad/s/√s


def sitl_gyro(seed: int, seconds: float, effects=("gyro_noise", "gyro_bias_random_walk"),
              noise: float = N_SITL, q: float = Q) -> np.ndarray:
    """(n, 3) still gyro record [rad/s] from sitl's error model with only ``effects`` on."""
    truth = Truth.random(seed).with_effects(disable=["all"], enable=list(effects))
    truth.gyro_noise, truth.gyro_bias_random_walk = noise, q
    model = ImuErrorModel(truth, fs=FS, seed=seed)
    n = int(seconds * FS)
    z = np.zeros((n, 3))
    return model.gyro(np.arange(n) / FS, z, z)


# ---- Haar wavelet variance -------------------------------------------------------------------
def test_haar_wavelet_variance_of_white_noise_is_sigma2_over_2m_at_every_scale():
    sigma = 2.0
    x = np.random.default_rng(1).standard_normal(2 ** 16) * sigma
    wv = nz.haar_wavelet_variance([x], FS, ci=0.99)
    theory = sigma ** 2 / (2 * wv.m)
    assert len(wv.m) == 16 and np.allclose(wv.tau, wv.m / FS)
    assert np.all((wv.ci_low <= theory) & (theory <= wv.ci_high))
    # the interval is informative: ±2 % at the finest scale, and the estimate is close there
    assert wv.ci_high[0] / wv.ci_low[0] < 1.05
    assert abs(2 * wv.m[0] * wv.wv[0] / sigma ** 2 - 1) < 0.01
    assert np.array_equal(wv.n_coeff, len(x) - 2 * wv.m + 1)


def test_haar_wavelet_variance_of_random_walk_matches_theory():
    gamma = 0.5                                   # increment σ per sample
    rng = np.random.default_rng(2)
    pieces = [np.cumsum(rng.standard_normal(4096)) * gamma for _ in range(40)]
    wv = nz.haar_wavelet_variance(pieces, FS, ci=0.99)
    theory = gamma ** 2 * (2 * wv.m ** 2 + 1) / (12 * wv.m)
    assert np.all((wv.ci_low <= theory) & (theory <= wv.ci_high))
    fine = wv.m <= 64                             # many coefficients: a tight check
    assert np.all(np.abs(wv.wv[fine] / theory[fine] - 1) < 0.1)
    assert wv.m[-1] == 2048                       # a 4096-sample piece reaches m = n/2


def test_pooling_never_differences_across_a_gap():
    rng = np.random.default_rng(3)
    a, b = rng.standard_normal(3000), rng.standard_normal(5000)
    jumped = [a, b + 1000.0]                      # a huge jump between the two holds
    w0, w1 = nz.haar_wavelet_variance([a, b], FS), nz.haar_wavelet_variance(jumped, FS)
    assert np.allclose(w0.wv, w1.wv, rtol=1e-9)
    assert np.array_equal(w0.n_coeff, w1.n_coeff)
    assert np.array_equal(w0.n_coeff, (3000 - 2 * w0.m + 1).clip(0) + (5000 - 2 * w0.m + 1).clip(0))
    ad0, ad1 = nz.allan_deviation([a, b], FS), nz.allan_deviation(jumped, FS)
    assert np.allclose(ad0.adev, ad1.adev, rtol=1e-9)
    # what differencing across the gap would do: the concatenated record sees the jump
    cat = nz.haar_wavelet_variance([np.concatenate(jumped)], FS)
    assert cat.wv[0] > 10 * w1.wv[0] or cat.wv[5] > 10 * w1.wv[5]


def test_short_pieces_are_ignored_and_nan_is_refused():
    rng = np.random.default_rng(4)
    x = rng.standard_normal(1000)
    w = nz.haar_wavelet_variance([x, rng.standard_normal(63) * 1e3], FS)
    assert np.allclose(w.wv, nz.haar_wavelet_variance([x], FS).wv)
    with pytest.raises(ValueError):
        nz.haar_wavelet_variance([np.r_[x, np.nan]], FS)
    with pytest.raises(ValueError):
        nz.haar_wavelet_variance([x[:10]], FS)


# ---- Allan deviation --------------------------------------------------------------------------
def test_allan_deviation_matches_allantools_on_one_piece():
    x = np.random.default_rng(5).standard_normal(5000) * 0.1 + 3.0
    taus = np.array([0.01, 0.02, 0.05, 0.1, 0.3, 1.0, 5.0, 20.0])
    ours = nz.allan_deviation([x], FS, taus=taus)
    t, ad, ade, n = allantools.oadev(x, rate=FS, data_type="freq", taus=taus)
    assert np.array_equal(ours.tau, t) and np.array_equal(ours.n, n)
    # the same numbers up to the rounding of the pooling √(n·σ²/n)
    assert np.allclose(ours.adev, ad, rtol=1e-13, atol=0)
    assert np.allclose(ours.err, ade, rtol=1e-13, atol=0)


@pytest.mark.parametrize("kind", ["white", "random_walk", "white_plus_walk"])
def test_allan_deviation_in_numpy_equals_allantools_oadev(kind):
    """apmcal's own overlapping Allan deviation against allantools (kept as a test extra only)
    on white noise (σ_A ∝ τ^-1/2), a random walk of the rate (∝ τ^+1/2) and their sum, octave
    and log10 grids: the same values to 1e-10 relative, term counts equal."""
    rng = np.random.default_rng({"white": 1, "random_walk": 2, "white_plus_walk": 3}[kind])
    n = 20000
    white = rng.standard_normal(n) * 0.05
    walk = np.cumsum(rng.standard_normal(n)) * 1e-3
    x = {"white": white, "random_walk": walk, "white_plus_walk": white + walk}[kind] + 0.7
    for grid in ("octave", "log10"):
        ours = nz.allan_deviation([x], FS, taus=grid)
        t, ad, _, cnt = allantools.oadev(x, rate=FS, data_type="freq", taus=ours.tau)
        assert np.array_equal(ours.tau, t) and np.array_equal(ours.n, cnt)
        assert np.allclose(ours.adev, ad, rtol=1e-10, atol=0)
    # the slopes the noise types predict, so the comparison is on meaningful numbers
    ours = nz.allan_deviation([x], FS, taus=np.array([0.1, 1.0]))
    slope = np.log10(ours.adev[1] / ours.adev[0])
    if kind == "white":
        assert abs(slope + 0.5) < 0.05
    elif kind == "random_walk":
        assert abs(slope - 0.5) < 0.15


def test_pooled_allan_deviation_equals_allantools_pooled_by_hand():
    """Pieces of different lengths: each piece's allantools value, pooled as √(Σnσ²/Σn)."""
    rng = np.random.default_rng(8)
    pieces = [rng.standard_normal(k) * 0.02 + np.cumsum(rng.standard_normal(k)) * 1e-4
              for k in (900, 4000, 2500)]
    ours = nz.allan_deviation(pieces, FS, taus="octave")
    num, den = np.zeros(len(ours.tau)), np.zeros(len(ours.tau))
    for x in pieces:
        t, ad, _, cnt = allantools.oadev(x, rate=FS, data_type="freq", taus=ours.tau)
        i = np.searchsorted(ours.tau, t)
        num[i] += cnt * ad ** 2
        den[i] += cnt
    assert np.array_equal(ours.n, den)
    assert np.allclose(ours.adev, np.sqrt(num / den), rtol=1e-10, atol=0)


def test_pooled_overlapping_allan_variance_is_twice_the_haar_wavelet_variance():
    rng = np.random.default_rng(6)
    pieces = [np.cumsum(rng.standard_normal(k)) * 0.01 + rng.standard_normal(k)
              for k in (3000, 7000, 1500)]
    wv = nz.haar_wavelet_variance(pieces, FS)
    ad = nz.allan_deviation(pieces, FS, taus="octave")
    j = len(ad.tau)                               # allantools needs 2 terms: one scale fewer
    assert np.allclose(ad.tau, wv.tau[:j])
    assert np.allclose(ad.adev ** 2, 2 * wv.wv[:j], rtol=1e-9)
    assert np.array_equal(ad.n, wv.n_coeff[:j])


# ---- GMWM noise terms -------------------------------------------------------------------------
def _z(term, truth):
    return (term.value - truth) / term.sigma


def test_fit_noise_terms_recovers_white_density_and_random_walk_from_sitl():
    w = sitl_gyro(seed=11, seconds=600)
    for axis in range(3):
        r = nz.fit_noise_terms([w[:, axis]], FS, unit="rad/s")
        assert "white" in r.selected and "random_walk" in r.selected
        n, k = r.white_density_sitl, r.random_walk
        assert abs(_z(n, N_SITL)) < 4 and abs(_z(k, Q)) < 4
        # the reported uncertainties are informative, and the unit conventions agree
        assert n.sigma / n.value < 0.01 and k.sigma / k.value < 0.25
        assert np.isclose(r.white_density.value * np.sqrt(2), n.value)
        assert np.isclose(r.white_sigma.value, n.value * np.sqrt(FS / 2))
        assert k.unit == "rad/s/√s"


def test_fit_noise_terms_on_holds_with_gaps():
    w = sitl_gyro(seed=12, seconds=1200)[:, 1]
    holds = [w[i * 8000:i * 8000 + 6000] for i in range(15)]    # 60-s holds, 20-s moves
    r = nz.fit_noise_terms(holds, FS, components=("white", "random_walk"))
    assert r.selected == ("white", "random_walk")
    assert abs(_z(r.white_density_sitl, N_SITL)) < 4 and abs(_z(r.random_walk, Q)) < 4
    assert r.wavelet.tau[-1] == pytest.approx(2048 / FS)        # nothing longer than a hold


def test_fit_noise_terms_selects_white_only_on_white_noise():
    picks = []
    for seed in range(10):
        w = sitl_gyro(seed=100 + seed, seconds=300, effects=("gyro_noise",))
        r = nz.fit_noise_terms([w[:, 0]], FS)
        picks.append(r.selected)
        assert set(r.criterion) >= {("white",)}
        assert abs(_z(r.white_density_sitl, N_SITL)) < 4
    assert sum(p == ("white",) for p in picks) >= 9, picks


def test_min_tau_leaves_out_the_scales_shaped_by_a_low_pass_filter():
    w = sitl_gyro(seed=14, seconds=600, effects=("gyro_noise", "lowpass_filter"))[:, 0]
    wv = nz.haar_wavelet_variance([w], FS)
    assert 2 * wv.wv[0] < 0.2 * (N_SITL * np.sqrt(FS / 2)) ** 2   # 20 Hz Butterworth at 100 Hz
    r = nz.fit_noise_terms([w], FS, min_tau=0.2)
    assert r.selected == ("white",)
    assert abs(_z(r.white_density_sitl, N_SITL)) < 4
    assert len(r.model_wv) == len(wv.wv)


def test_fit_noise_terms_finds_bias_instability_in_flicker_noise():
    rng = np.random.default_rng(7)
    n, b, sigma = 2 ** 19, 1.0, 10.0
    f = np.fft.rfftfreq(n)
    amp = np.zeros_like(f)
    amp[1:] = np.sqrt(b ** 2 / (2 * np.pi * f[1:]) * n / 2)     # two-sided S = B²/(2π|f|)
    x = np.fft.irfft((rng.standard_normal(len(f)) + 1j * rng.standard_normal(len(f))) * amp, n)
    pieces = [x[i * 2 ** 15:(i + 1) * 2 ** 15] + rng.standard_normal(2 ** 15) * sigma
              for i in range(8)]
    r = nz.fit_noise_terms(pieces, 1.0)
    assert r.selected == ("white", "bias_instability")
    assert abs(_z(r.bias_instability, b)) < 4 and r.bias_instability.sigma < 0.1
    assert abs(_z(r.white_sigma, sigma)) < 4


def test_allan_lines_baseline_reads_the_textbook_values_on_a_long_record():
    w = sitl_gyro(seed=13, seconds=1800)[:, 2]
    lines = nz.noise_terms_allan_lines([w], FS)
    assert lines.white_density * np.sqrt(2) == pytest.approx(N_SITL, rel=0.1)
    assert lines.random_walk == pytest.approx(Q, rel=0.5)
    assert lines.bias_instability > 0


# ---- Kalman filter / RTS smoother -------------------------------------------------------------
@pytest.fixture(scope="module")
def walk_record():
    """10 min of white noise + bias random walk, and the walk alone (same seed → same walk)."""
    x = sitl_gyro(seed=21, seconds=600)[:, 0]
    walk = sitl_gyro(seed=21, seconds=600, effects=("gyro_bias_random_walk",))[:, 0]
    return x, walk


def test_rts_track_follows_the_random_walk(walk_record):
    x, walk = walk_record
    sigma = N_SITL * np.sqrt(FS / 2)
    tr = nz.random_walk_bias([x], FS, sigma, Q)
    k = len(tr.bias)
    assert tr.block == 60 and k == 1000
    truth = walk[:k * tr.block].reshape(k, tr.block).mean(axis=1)
    err = tr.bias - truth
    assert np.mean(np.abs(err) <= 2 * tr.sigma) >= 0.9
    # smoothing beats the raw block means by far, and the band is not trivially wide
    rms = np.sqrt(np.mean(err ** 2))
    assert rms < 0.5 * np.sqrt(np.mean((tr.measured - truth) ** 2))
    assert rms < 0.3 * np.std(truth) and np.mean(tr.sigma) < 1.5 * rms
    assert np.isfinite(tr.loglik)


def test_rts_track_restarts_at_each_piece(walk_record):
    x, _ = walk_record
    sigma = N_SITL * np.sqrt(FS / 2)
    a, b = x[:30000], x[30000:]
    tr0 = nz.random_walk_bias([a, b], FS, sigma, Q, block=60)
    tr1 = nz.random_walk_bias([a, b + 0.5], FS, sigma, Q, block=60)
    assert np.allclose(tr1.bias[tr1.piece == 1] - 0.5, tr0.bias[tr0.piece == 1], atol=1e-12)
    assert np.allclose(tr1.bias[tr1.piece == 0], tr0.bias[tr0.piece == 0])
    assert tr1.loglik == pytest.approx(tr0.loglik, rel=1e-9)
    assert tr0.t[tr0.piece == 1][0] == pytest.approx(0.3)


def test_ml_random_walk_agrees_with_truth_and_with_gmwm(walk_record):
    x, _ = walk_record
    gm = nz.fit_noise_terms([x], FS, components=("white", "random_walk"))
    ml = nz.fit_random_walk_ml([x], FS, gm.white_sigma.value, block=120)    # 500 steps
    assert not ml.at_bound
    assert abs(np.log(ml.q / Q)) < 3 * ml.log_q_sigma
    assert ml.log_q_sigma < 0.3
    z = (ml.q - gm.random_walk.value) / np.hypot(ml.q_sigma, gm.random_walk.sigma)
    assert abs(z) < 3
    # the likelihood prefers the ML value to a q off by a factor 3
    ll = nz.random_walk_loglik([x], FS, gm.white_sigma.value, 3 * ml.q, block=120)
    assert ll < ml.loglik - 2


def test_diffuse_start_equals_a_very_wide_prior(walk_record):
    x, _ = walk_record
    sigma, block = N_SITL * np.sqrt(FS / 2), 60
    y = x[:12000].reshape(-1, block).mean(axis=1)
    tr = nz.random_walk_bias([x[:12000]], FS, sigma, Q, block=block)
    kf = nz._walk_filter(FS, sigma, Q, block)     # same model, textbook start: x₀ ~ N(ȳ, κ)
    kappa = 1e4 * np.var(y)
    kf.x, kf.P = np.full((2, 1), y.mean()), np.eye(2) * kappa
    mu, cov, mu_p, cov_p = kf.batch_filter(y.reshape(-1, 1, 1))
    xs, ps, _, _ = kf.rts_smoother(mu, cov)
    assert np.allclose(tr.bias, xs[:, 1, 0], rtol=0, atol=1e-4 * sigma / np.sqrt(block))
    assert np.allclose(tr.sigma, np.sqrt(ps[:, 1, 1]), rtol=1e-4)
    s = cov_p[1:, 1, 1] + kf.R[0, 0]
    v = y[1:] - mu_p[1:, 1, 0]
    assert tr.loglik == pytest.approx(-0.5 * np.sum(np.log(2 * np.pi * s) + v * v / s), rel=1e-6)
