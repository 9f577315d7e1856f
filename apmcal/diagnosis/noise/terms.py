"""White noise, bias instability and rate random walk of still-period residuals (GMWM-style fit).

``pieces``, ``fs``, the unit ``u`` and the Haar wavelet variance ν² = σ²_A/2 at block length
m = τ·fs are as in :mod:`apmcal.diagnosis.noise.allan`. Noise terms and units (IEEE Std 952-1997,
Annex C; σ per sample = standard deviation of one sample of the white part):

================  =====================  ==========================================================
term              unit                   Allan variance / Haar wavelet variance (m = τ·fs)
================  =====================  ==========================================================
white noise N     u/√Hz (= u·√s)         σ²_A = N²/τ; N = σ/√fs; sitl's one-sided density
                                         N_sitl = σ/√(fs/2) = √2·N
bias instab. B    u                      flicker floor σ²_A = (2 ln2/π)·B², i.e. σ_A ≈ 0.664·B
rate r. walk K    u/√s (= u/s/√Hz)       σ²_A = K²τ/3; K = sitl's q (increments of variance K²·dt)
================  =====================  ==========================================================

Exact discrete-time Haar wavelet variances (Guerrier, Skaloud, Stebler & Victoria-Feser 2013,
"Wavelet-variance-based estimation for composite stochastic processes", JASA 108:1021-1030,
with their scale 2^j = 2m): white noise of variance σ² per sample, ν² = σ²/(2m); random walk
with increments of variance γ² = K²/fs per sample, ν² = γ²(2m² + 1)/(12m). Bias instability is
modelled as flicker noise, two-sided spectral density B²/(2π|f|) (IEEE 952's 1/f term): its
wavelet variance is the constant ln2·B²/π for large m (exactly the IEEE 952 plateau), computed
numerically for m ≤ 128 where the sampling matters. Why flicker and not a first-order
Gauss-Markov process: B is *defined* by IEEE 952 as the level of the flat floor, the flicker
model keeps the whole fit linear in (σ², B², γ²) — a non-negative least-squares problem with a
unique minimum and no starting values, where a Gauss-Markov term adds a correlation time that
makes the GMWM objective non-convex — and records of minutes rarely resolve a correlation time.
A Gauss-Markov bump in real data shows up as a misfit of the model wavelet variance.

The fit (:func:`fit_noise_terms`) is GMWM with a diagonal weight matrix: weighted non-negative
least squares of the model wavelet variance against the empirical one, weights the inverse
variance of each empirical wavelet variance, iterated so that the variances come from the fitted
model rather than from the noisy estimates (the fixed point solves the χ²/Gamma quasi-likelihood
equations, so weights that follow the noise of the estimate do not bias the fit). The variances
and the covariances between scales are the large-sample Gaussian ones, (2/M)·∫|H_j|²|H_k|²S² df
(Percival & Walden 2000, Wavelet Methods for Time Series Analysis, §8.3), integrated numerically
over the sampled spectra for m ≤ 128 and through the scale invariance of power-law spectra above
(checked against Monte Carlo: standard deviations and neighbour correlations within a few per
cent). Uncertainties of the terms use the full covariance (a sandwich), so the correlation
between neighbouring scales is not ignored. Components are chosen among all subsets of the
candidates by the smallest prediction-error criterion, the kind GMWM uses (its WIC): here
Mallows' Cp for this weighted fit, the weighted residual sum of squares plus twice the trace of
the weighted covariance between fitted and empirical wavelet variances, with one common weight
matrix (from the fit of all candidates) so that the values can be compared. Like AIC it errs on
the side of keeping a component: on pure white noise it keeps white alone in about 97 % of
records.

Real sensor data are low-passed (the MPU-6000 DLPF): the finest scales then fall below the
white-noise line and must be left out with ``min_tau`` (a few filter time constants, e.g.
0.2 s for 20 Hz), or the fit explains the deficit with the wrong components.

The baseline to beat is :func:`noise_terms_allan_lines` (the fixed-slope line reading of
Kalibr's allan tools and allan_variance_ros). :mod:`apmcal.diagnosis.noise.bias_track` checks the
random walk independently with a Kalman filter / RTS smoother.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.optimize import nnls

from apmcal.diagnosis.noise.allan import (
    AllanDeviation,
    WaveletVariance,
    _raw_pieces,
    allan_deviation,
    haar_wavelet_variance,
)

COMPONENTS = ("white", "bias_instability", "random_walk")
B_FACTOR = float(np.sqrt(2.0 * np.log(2.0) / np.pi))       # σ_A floor = 0.664·B (IEEE 952)
_DISCRETE_MAX_M = 128          # up to this block length spectral integrals use the sampled H
_GRID = 2 ** 15                # frequency grid (midpoints of (0, 1/2), cycles/sample) for them
_D_MAX = 6                     # scale pairs further apart than 2**6 are taken as uncorrelated


# ---------------------------------------------------------------------------------------------
# theoretical wavelet variances and their covariance (unit parameters, per sample)
# ---------------------------------------------------------------------------------------------
def _haar_gain(m: int, f: np.ndarray) -> np.ndarray:
    """|H_m(f)|² of the Haar MODWT filter with block length m (f in cycles/sample)."""
    return np.sin(np.pi * f * m) ** 4 / (m * np.sin(np.pi * f)) ** 2


@lru_cache(maxsize=1)
def _grid_spectra():
    """Midpoint frequency grid on (0, 1/2) and the unit spectra (white, flicker, walk)."""
    f = (np.arange(_GRID) + 0.5) / (2 * _GRID)
    s = np.array([np.ones_like(f), 1.0 / (2 * np.pi * f), 1.0 / (4 * np.sin(np.pi * f) ** 2)])
    return f, s, 1.0 / (2 * _GRID)


# (A, β) of the unit spectra at low frequency, S(f) ≈ A|f|^β (white, flicker, random walk)
_POWER_LAW = ((1.0, 0), (1.0 / (2 * np.pi), -1), (1.0 / (4 * np.pi ** 2), -2))


@lru_cache(maxsize=1)
def _scale_free_integrals() -> np.ndarray:
    """I[β, d] = ∫ P(u)·P(2^d u)·|u|^(-β) du over the real line, P(u) = sin⁴(πu)/(πu)².

    Row index b = -β for β = 0..-4, column d = 0.._D_MAX. With these, for m_k = 2^d m_j,
    ∫|H_j|²|H_k|² A|f|^β df = A · m_j^(-1-β) · I[-β, d] (continuous-time limit).
    """
    du = 2.0 ** -(_D_MAX + 5)
    u = (np.arange(int(64 / du)) + 0.5) * du
    p = np.sin(np.pi * u) ** 4 / (np.pi * u) ** 2
    out = np.zeros((5, _D_MAX + 1))
    for d in range(_D_MAX + 1):
        v = 2.0 ** d * u
        pp = p * np.sin(np.pi * v) ** 4 / (np.pi * v) ** 2
        for b in range(5):
            out[b, d] = 2.0 * np.sum(pp * u ** (-b)) * du
    return out


def prepare() -> None:
    """Compute the fits' fixed integrals now (0.15 s, kept for the life of the process), so
    that the workers forked later inherit them instead of each computing its own."""
    _grid_spectra()
    _scale_free_integrals()


@lru_cache(maxsize=8)
def _unit_wv(n_scales: int) -> np.ndarray:
    """(J, 3) Haar wavelet variance of unit white, flicker and random-walk components.

    Columns: σ² = 1 → 1/(2m); B = 1 → ln2/π (numeric for m ≤ 128); γ² = 1 → (2m²+1)/(12m).
    """
    f, s, df = _grid_spectra()
    ms = 2.0 ** np.arange(n_scales)
    flick = np.array([2 * np.sum(_haar_gain(int(m), f) * s[1]) * df if m <= _DISCRETE_MAX_M
                      else np.log(2) / np.pi for m in ms])
    return np.column_stack([1 / (2 * ms), flick, (2 * ms ** 2 + 1) / (12 * ms)])


@lru_cache(maxsize=8)
def _unit_kernels(n_scales: int) -> np.ndarray:
    """(3, 3, J, J) integrals ∫_{-1/2}^{1/2} |H_j|²|H_k|² S_a S_b df of the unit spectra."""
    f, s, df = _grid_spectra()
    ms = 2 ** np.arange(n_scales)
    small = int(np.sum(ms <= _DISCRETE_MAX_M))
    h = np.array([_haar_gain(int(m), f) for m in ms[:small]])
    integ = _scale_free_integrals()
    k = np.zeros((3, 3, n_scales, n_scales))
    for a, b in itertools.product(range(3), repeat=2):
        k[a, b, :small, :small] = 2 * (h * (s[a] * s[b] * df)) @ h.T
        amp = _POWER_LAW[a][0] * _POWER_LAW[b][0]
        beta = _POWER_LAW[a][1] + _POWER_LAW[b][1]
        for i, j in itertools.product(range(n_scales), repeat=2):
            d = abs(i - j)
            if max(i, j) >= small and d <= _D_MAX:
                k[a, b, i, j] = amp * float(ms[min(i, j)]) ** (-1 - beta) * integ[-beta, d]
    return k


def _overlap(cnt_p: np.ndarray) -> np.ndarray:
    """(J, J) Σ_p min(M_pj, M_pk) / (M_j M_k): how pooled coefficient sums share pieces."""
    tot = cnt_p.sum(axis=0).astype(float)
    both = np.minimum(cnt_p[:, :, None], cnt_p[:, None, :]).sum(axis=0)
    return both / np.outer(tot, tot)


def _wv_covariance(theta: np.ndarray, kern: np.ndarray, overlap: np.ndarray) -> np.ndarray:
    """(J, J) covariance of the pooled empirical wavelet variances under parameters theta."""
    return 2.0 * overlap * np.einsum("a,b,abjk->jk", theta, theta, kern)


# ---------------------------------------------------------------------------------------------
# GMWM fit
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NoiseTerm:
    """A noise term's value and one-sigma uncertainty, in ``unit``."""

    value: float
    sigma: float
    unit: str


@dataclass
class NoiseTerms:
    """Noise terms fitted to the Haar wavelet variance (units: u = the pieces' unit).

    Attributes
    ----------
    selected : tuple of str
        Components in the chosen model (a subset of :data:`COMPONENTS`).
    white_sigma : NoiseTerm or None
        White noise σ per sample [u].
    white_density : NoiseTerm or None
        Allan white density N [u/√Hz], σ²_A(τ) = N²/τ (angle/velocity random walk).
    white_density_sitl : NoiseTerm or None
        sitl's one-sided density [u/√Hz], σ per sample = N_sitl·√(fs/2), i.e. √2·N.
    bias_instability : NoiseTerm or None
        IEEE 952 bias instability B [u] (flicker floor σ_A = 0.664·B).
    random_walk : NoiseTerm or None
        Rate random walk K [u/√s], σ²_A(τ) = K²τ/3 (sitl's q).
    criterion : dict
        Prediction-error criterion (WIC/Cp, smaller is better) of each candidate subset, keyed by
        the tuple of component names that stayed non-zero.
    theta : (3,) array
        Per-sample parameters (σ² [u²], B² [u²], γ² = K²/fs [u²]) of the chosen model.
    theta_cov : (3, 3) array
        Their covariance (sandwich with the full covariance of the wavelet variances).
    wavelet : WaveletVariance
        The empirical wavelet variance that was fitted.
    model_wv : (J,) array
        Model wavelet variance at the fitted parameters [u²].
    fs : float
        Sample rate [Hz].
    component_wv : (J, 3) array
        Model wavelet variance of each component (white, bias instability, random walk) [u²].
    """

    selected: tuple
    white_sigma: NoiseTerm | None
    white_density: NoiseTerm | None
    white_density_sitl: NoiseTerm | None
    bias_instability: NoiseTerm | None
    random_walk: NoiseTerm | None
    criterion: dict
    theta: np.ndarray
    theta_cov: np.ndarray
    wavelet: WaveletVariance
    model_wv: np.ndarray
    fs: float
    component_wv: np.ndarray = field(repr=False, default=None)


def _wnnls(g: np.ndarray, nu: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted non-negative least squares min Σ w (nu - g θ)², θ ≥ 0 (columns rescaled)."""
    a = g * np.sqrt(w)[:, None]
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    theta, _ = nnls(a / scale, nu * np.sqrt(w), maxiter=50 * g.shape[1])
    return theta / scale


def _fit_cols(nu, g, w, cols) -> np.ndarray:
    """θ (3,) with only ``cols`` free, by weighted NNLS with fixed weights w."""
    theta = np.zeros(3)
    theta[list(cols)] = _wnnls(g[:, list(cols)], nu, w)
    return theta


def _model_var(theta, kern, overlap, floor) -> np.ndarray:
    """Model variance of each empirical wavelet variance, at least ``floor``."""
    return np.maximum(np.diag(_wv_covariance(theta, kern, overlap)), floor)


def _irls(nu, g, w0, kern, overlap, cols, max_iter=30, rtol=1e-7):
    """Iteratively re-weighted NNLS: weights 1/var(ν̂_j) from the current model.

    Returns θ (3,) and the final weights (J,).
    """
    floor = 1e-12 * np.max(nu ** 2) + 1e-300
    w = w0
    theta = _fit_cols(nu, g, w, cols)
    for _ in range(max_iter):
        w = 1.0 / _model_var(theta, kern, overlap, floor)
        new = _fit_cols(nu, g, w, cols)
        done = np.allclose(new, theta, rtol=rtol, atol=1e-30)
        theta = new
        if done:
            break
    return theta, w


def _hat_terms(g, w, active):
    """(G_A, B = (G_AᵀWG_A)⁻¹) for the active columns."""
    ga = g[:, active]
    return ga, np.linalg.pinv(ga.T @ (w[:, None] * ga))


def _criterion(nu, g, theta, w, sigma) -> float:
    """WIC/Cp: weighted RSS + 2·tr(W·cov(fitted, empirical)) for the non-zero components."""
    active = np.flatnonzero(theta > 0)
    r = nu - g @ theta
    rss = float(np.sum(w * r ** 2))
    if len(active) == 0:
        return rss
    ga, b = _hat_terms(g, w, active)
    hat = ga @ b @ (ga.T * w)                    # fitted = hat @ nu
    return rss + 2.0 * float(np.trace((w[:, None] * hat) @ sigma))


def _theta_cov(g, w, sigma, theta) -> np.ndarray:
    """Sandwich covariance of θ̂ over its non-zero components (zeros elsewhere)."""
    cov = np.zeros((3, 3))
    active = np.flatnonzero(theta > 0)
    if len(active):
        ga, b = _hat_terms(g, w, active)
        gw = ga.T * w
        cov[np.ix_(active, active)] = b @ gw @ sigma @ gw.T @ b
    return cov


def _sqrt_term(var, var_sd, factor, unit) -> NoiseTerm | None:
    """Term factor·√var with its delta-method sigma; None when var is 0 (not in the model)."""
    if var <= 0:
        return None
    v = factor * np.sqrt(var)
    return NoiseTerm(float(v), float(factor * var_sd / (2 * np.sqrt(var))), unit)


def _select(nu, g, w, sigma, cand) -> tuple[tuple[int, ...], dict]:
    """Criterion for every non-empty subset of ``cand``; returns the best active set and all."""
    crit = {}
    for r in range(1, len(cand) + 1):
        for cols in itertools.combinations(cand, r):
            theta = _fit_cols(nu, g, w, cols)
            active = tuple(int(i) for i in np.flatnonzero(theta > 0))
            if active and active not in crit:
                crit[active] = _criterion(nu, g, theta, w, sigma)
    best = min(crit, key=lambda a: (crit[a], len(a)))
    return best, crit


def _problem(wv: WaveletVariance, use: np.ndarray):
    """Model matrix (all scales), and for the fitted scales ``use``: ν̂, model matrix, unit
    covariance kernels, piece overlap and first-pass weights η/(2ν̂²)."""
    take = np.log2(wv.m).astype(int)
    j = int(take[-1]) + 1
    g_all = _unit_wv(j)[take]
    kern = _unit_kernels(j)[:, :, take[use]][:, :, :, take[use]]
    nu = wv.wv[use]
    w0 = wv.edf[use] / (2.0 * np.maximum(nu, 1e-300) ** 2)
    return g_all, nu, g_all[use], kern, _overlap(wv.n_coeff_piece[:, use]), w0


def _terms(theta, cov, fs, unit) -> dict:
    """The NoiseTerm fields from per-sample parameters θ = (σ², B², γ²) and their covariance."""
    sd = np.sqrt(np.diag(cov))
    return dict(white_sigma=_sqrt_term(theta[0], sd[0], 1.0, unit),
                white_density=_sqrt_term(theta[0], sd[0], 1 / np.sqrt(fs), f"{unit}/√Hz"),
                white_density_sitl=_sqrt_term(theta[0], sd[0], np.sqrt(2 / fs), f"{unit}/√Hz"),
                bias_instability=_sqrt_term(theta[1], sd[1], 1.0, unit),
                random_walk=_sqrt_term(theta[2], sd[2], np.sqrt(fs), f"{unit}/√s"))


def fit_noise_terms(pieces, fs: float, components=COMPONENTS, *, select: bool = True,
                    min_tau: float = 0.0, min_span: float = 1.0, unit: str = "u") -> NoiseTerms:
    """White noise, bias instability and rate random walk by GMWM on the Haar wavelet variance.

    Parameters
    ----------
    pieces : list of 1-D arrays
        Residual samples of separate still periods [u] (each ≥ 64 samples, else ignored).
    fs : float
        Sample rate [Hz].
    components : sequence of str
        Candidates among "white", "bias_instability", "random_walk".
    select : bool
        True: fit every subset and keep the one with the smallest criterion; False: fit all
        candidates together (non-negative, so a component can still come out as zero).
    min_tau : float
        Scales with τ below this [s] are left out of the fit (e.g. those shaped by a sensor's
        low-pass filter, which the white-noise model does not describe); they stay in
        ``wavelet`` and ``model_wv``.
    min_span : float
        Passed to :func:`~apmcal.diagnosis.noise.allan.haar_wavelet_variance` (scales a piece
        contributes to).
    unit : str
        Name of u for the NoiseTerm units (e.g. "rad/s").

    Returns
    -------
    NoiseTerms
        Values with one-sigma uncertainties; terms not in the chosen model are None.
    """
    names = list(components)
    if set(names) - set(COMPONENTS) or not names:
        raise ValueError(f"components must be a non-empty subset of {COMPONENTS}, got {names}")
    cand = tuple(sorted(COMPONENTS.index(c) for c in names))
    wv = haar_wavelet_variance(pieces, fs, min_span=min_span)
    use = wv.tau >= min_tau
    if np.sum(use) < len(cand) or not np.any(wv.wv[use] > 0):
        raise ValueError("too few scales with any noise to fit (pieces constant or too short)")
    g_all, nu, g, kern, overlap, w0 = _problem(wv, use)

    theta, w = _irls(nu, g, w0, kern, overlap, cand)
    crit = {}
    if select and len(cand) > 1:
        cols, crit = _select(nu, g, w, _wv_covariance(theta, kern, overlap), cand)
        theta, w = _irls(nu, g, w0, kern, overlap, cols)
    cov = _theta_cov(g, w, _wv_covariance(theta, kern, overlap), theta)
    return NoiseTerms(
        selected=tuple(COMPONENTS[i] for i in np.flatnonzero(theta > 0)),
        **_terms(theta, cov, fs, unit),
        criterion={tuple(COMPONENTS[i] for i in a): v for a, v in crit.items()},
        theta=theta, theta_cov=cov, wavelet=wv, model_wv=g_all @ theta, fs=float(fs),
        component_wv=g_all * theta)


# ---------------------------------------------------------------------------------------------
# baseline: Kalibr / allan_variance_ros fixed-slope lines
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AllanLineTerms:
    """Noise terms read off fixed-slope lines on the Allan deviation (the baseline).

    Attributes
    ----------
    white_density : float
        N [u/√Hz]: the −½-slope line at τ = 1 s.
    random_walk : float
        K [u/√s]: the +½-slope line at τ = 3 s.
    bias_instability : float
        B [u]: the minimum Allan deviation / 0.664.
    allan : AllanDeviation
        The curve the lines were read from.
    """

    white_density: float
    random_walk: float
    bias_instability: float
    allan: AllanDeviation


def _line_intercept(logt, logs, slope, target, tol) -> float:
    """Intercept of a line of fixed ``target`` slope through the points whose local slope is
    within ``tol`` of it (least squares in log-log); the single closest point if none is."""
    near = np.abs(slope - target) <= tol
    if not np.any(near):
        near = np.abs(slope - target) == np.min(np.abs(slope - target))
    return float(np.mean(logs[near] - target * logt[near]))


def noise_terms_allan_lines(pieces, fs: float, slope_tol: float = 0.1) -> AllanLineTerms:
    """The Kalibr / allan_variance_ros reading: fixed-slope lines on the Allan deviation.

    The pooled overlapping Allan deviation (:func:`~apmcal.diagnosis.noise.allan.allan_deviation`,
    ~10 τ per decade, kept up to a quarter of the longest piece, Stable32's stop ratio for it)
    is differentiated in log-log; N is the −½-slope line through the points whose local slope
    is within ``slope_tol`` of −½ (or through the closest point, as in the MathWorks /
    kalibr_allan recipe), read at τ = 1 s; K the +½-slope line likewise among the points beyond
    the minimum (all points when the minimum is the last one), read at τ = 3 s;
    B = min σ_A / 0.664 (IEEE Std 952-1997, Annex C).

    Parameters
    ----------
    pieces : list of 1-D arrays
        Residual samples of separate still periods [u].
    fs : float
        Sample rate [Hz].
    slope_tol : float
        Tolerance on the local log-log slope.

    Returns
    -------
    AllanLineTerms
    """
    ad = allan_deviation(pieces, fs)
    keep = np.round(ad.tau * fs) <= max(len(x) for x in _raw_pieces(pieces)) / 4
    keep[:2] = True
    ad = AllanDeviation(tau=ad.tau[keep], adev=ad.adev[keep], err=ad.err[keep], n=ad.n[keep])
    logt, logs = np.log10(ad.tau), np.log10(ad.adev)
    slope = np.gradient(logs, logt)
    n_db = 10 ** _line_intercept(logt, logs, slope, -0.5, slope_tol)
    i_min = int(np.argmin(ad.adev))
    rest = slice(i_min + 1, None) if i_min < len(logt) - 1 else slice(None)
    b = _line_intercept(logt[rest], logs[rest], slope[rest], 0.5, slope_tol)
    k = 10 ** (b + 0.5 * np.log10(3.0))
    return AllanLineTerms(white_density=float(n_db), random_walk=float(k),
                          bias_instability=float(ad.adev[i_min] / B_FACTOR), allan=ad)
