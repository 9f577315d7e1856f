"""Haar wavelet variance and Allan deviation of still-period residuals, pooled over pieces.

Every function takes ``pieces``: a list of 1-D float arrays, the residual samples of separate still
periods ("holds") at one sample rate ``fs`` [Hz], in one unit ``u`` (rad/s for a gyroscope, m/s²
for an accelerometer, ...). Pieces shorter than :data:`MIN_PIECE` samples are ignored. Nothing is
ever differenced or averaged across the gap between two pieces: each statistic is computed within
each piece and pooled by its number of terms. The same piece handling serves
:mod:`apmcal.diagnosis.noise.terms` and :mod:`apmcal.diagnosis.noise.bias_track`.

Conventions
-----------
Scale j = 1, 2, ... has block length ``m = 2**(j-1)`` samples and averaging time ``τ = m / fs``
[s]. The Haar (MODWT, all shifts) wavelet coefficient at scale j is half the difference of the
means of two adjacent blocks of m samples, ``W = (mean(x[t:t+m]) - mean(x[t+m:t+2m])) / 2``, so a
piece of n samples has ``n - 2m + 1`` coefficients at that scale. The Haar wavelet variance
ν²(τ) = E[W²] is half the Allan variance: ``σ²_A(τ) = 2 ν²(τ)``, and the pooled overlapping Allan
variance at τ = m/fs is exactly twice the pooled Haar wavelet variance (Percival & Walden 2000,
Wavelet Methods for Time Series Analysis, §8.6; Allan variance as in IEEE Std 952-1997, Annex C).
Confidence intervals use Percival & Walden's model-free equivalent degrees of freedom η₃ (§8.4).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincinv

MIN_PIECE = 64


# ---------------------------------------------------------------------------------------------
# pieces
# ---------------------------------------------------------------------------------------------
def _indexed_pieces(pieces) -> list[tuple[int, np.ndarray]]:
    """(index, piece as a 1-D float array) for the pieces of MIN_PIECE samples or more."""
    out = [(i, np.asarray(p, dtype=float).ravel()) for i, p in enumerate(pieces)]
    out = [(i, x) for i, x in out if len(x) >= MIN_PIECE]
    if not out:
        raise ValueError(f"no piece has {MIN_PIECE} samples or more")
    return out


def _raw_pieces(pieces) -> list[np.ndarray]:
    """Pieces as 1-D float arrays, mean kept, dropping those shorter than MIN_PIECE."""
    return [x for _, x in _indexed_pieces(pieces)]


def _finite_pieces(pieces) -> list[np.ndarray]:
    """:func:`_raw_pieces`, refusing NaN/inf in the pieces kept."""
    xs = _raw_pieces(pieces)
    if not all(np.all(np.isfinite(x)) for x in xs):
        raise ValueError("pieces must be finite (cut NaN/inf out into separate pieces)")
    return xs


def _clean_pieces(pieces) -> list[np.ndarray]:
    """Pieces as float arrays minus their mean, dropping those shorter than MIN_PIECE."""
    return [x - x.mean() for x in _finite_pieces(pieces)]


# ---------------------------------------------------------------------------------------------
# the empirical Haar wavelet variance
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class WaveletVariance:
    """Pooled Haar wavelet variance per octave scale (see the module docstring for conventions).

    Attributes
    ----------
    m : (J,) int array
        Block length [samples], ``2**(j-1)``.
    tau : (J,) array
        Averaging time ``m / fs`` [s].
    wv : (J,) array
        Pooled Haar wavelet variance ν² [u²] (the Allan variance is ``2 * wv``).
    n_coeff : (J,) int array
        Number of wavelet coefficients behind each value (all pieces).
    n_coeff_piece : (P, J) int array
        The same per kept piece (pieces of 64 samples or more, in order; 0 where a piece is
        too short for the scale).
    edf : (J,) array
        Equivalent degrees of freedom: Percival & Walden's model-free η₃ = max(M/2m, 1) per
        piece, combined over pieces by Satterthwaite's rule (conservative for white noise,
        whose true η is about three times larger at coarse scales).
    ci_low, ci_high : (J,) arrays
        Chi-square confidence interval of ``wv`` at level ``ci`` [u²].
    fs : float
        Sample rate [Hz].
    """

    m: np.ndarray
    tau: np.ndarray
    wv: np.ndarray
    n_coeff: np.ndarray
    n_coeff_piece: np.ndarray
    edf: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    fs: float

    @property
    def adev(self) -> np.ndarray:
        """Allan deviation √(2ν²) [u], shape (J,)."""
        return np.sqrt(2.0 * self.wv)


def _piece_haar_sums(x: np.ndarray, ms: np.ndarray, min_span: float):
    """Sum of squared Haar coefficients and their count for one piece at block lengths ``ms``.

    With c the cumulative sum (c[0] = 0), 2m·W_t = c[t+2m] − 2c[t+m] + c[t] (block sums'
    difference), computed in one reused buffer; no BLAS call (a threaded dot product is slower
    than this on a busy machine).
    """
    c = np.concatenate(([0.0], np.cumsum(x)))
    n = len(x)
    buf = np.empty(n)
    ss = np.zeros(len(ms))
    cnt = np.zeros(len(ms), dtype=int)
    for i, m in enumerate(ms):
        if n < min_span * 2 * m or n < 2 * m:
            break
        k = n - 2 * m + 1
        d = buf[:k]
        np.subtract(c[2 * m:], c[m:n + 1 - m], out=d)
        d -= c[m:n + 1 - m]
        d += c[:k]
        ss[i], cnt[i] = np.sum(np.square(d, out=d)) / (4.0 * m * m), k
    return ss, cnt


def haar_wavelet_variance(pieces, fs: float, ci: float = 0.95,
                          min_span: float = 1.0) -> WaveletVariance:
    """Pooled overlapping Haar wavelet variance at octave scales τ = 2**(j-1)/fs.

    Parameters
    ----------
    pieces : list of 1-D arrays
        Residual samples of separate still periods [u]; each piece's mean is removed (the Haar
        filter ignores it anyway) and coefficients never straddle two pieces.
    fs : float
        Sample rate [Hz].
    ci : float
        Level of the chi-square confidence interval (0.95: 95 %).
    min_span : float
        A piece contributes to a scale only if it is at least ``min_span`` Haar filter lengths
        (2m samples) long; 1 keeps every scale with at least one coefficient.

    Returns
    -------
    WaveletVariance
        Scales up to the largest one any piece contributes to.
    """
    xs = _clean_pieces(pieces)
    n_max = max(len(x) for x in xs)
    j_max = int(np.floor(np.log2(n_max / (2.0 * max(min_span, 1.0))))) + 1
    ms = 2 ** np.arange(max(j_max, 1))
    sums = [_piece_haar_sums(x, ms, min_span) for x in xs]
    ss = np.sum([s for s, _ in sums], axis=0)
    cnt_p = np.array([c for _, c in sums])
    cnt = cnt_p.sum(axis=0)
    keep = cnt > 0
    ms, ss, cnt, cnt_p = ms[keep], ss[keep], cnt[keep], cnt_p[:, keep]
    wv = ss / cnt
    edf = _edf_eta3(cnt_p, ms)
    lo, hi = _chi2_interval(wv, edf, ci)
    return WaveletVariance(m=ms, tau=ms / fs, wv=wv, n_coeff=cnt, n_coeff_piece=cnt_p, edf=edf,
                           ci_low=lo, ci_high=hi, fs=float(fs))


def _edf_eta3(cnt_p: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """η₃ = max(M_p/2m, 1) per piece (Percival & Walden 2000, eq. 314c), Satterthwaite-pooled."""
    eta_p = np.where(cnt_p > 0, np.maximum(cnt_p / (2.0 * ms), 1.0), np.inf)
    share = cnt_p / cnt_p.sum(axis=0)
    return 1.0 / np.sum(share ** 2 / eta_p, axis=0)


def _chi2_interval(v: np.ndarray, edf: np.ndarray, ci: float):
    """Two-sided chi-square interval of a variance estimate v with edf degrees of freedom."""
    a = (1.0 - ci) / 2.0
    return edf * v / _chi2_ppf(1.0 - a, edf), edf * v / _chi2_ppf(a, edf)


def _chi2_ppf(q: float, edf: np.ndarray) -> np.ndarray:
    """χ² quantile, value for value as scipy.stats.chi2.ppf (2·P⁻¹(ν/2, q), the same special
    function), without importing scipy.stats (0.6 s) at the start of every ``apmcal gap``."""
    return 2.0 * gammaincinv(np.asarray(edf) / 2.0, q)


# ---------------------------------------------------------------------------------------------
# Allan deviation (overlapping, [IEEE952] Annex C, [NIST1065] eq. 11)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AllanDeviation:
    """Pooled overlapping Allan deviation.

    Attributes
    ----------
    tau : (K,) array
        Averaging times [s] (multiples of 1/fs).
    adev : (K,) array
        Overlapping Allan deviation [u], pooled as √(Σ n_p σ²_p / Σ n_p).
    err : (K,) array
        One-sigma error bar [u]: the simple ``adev/√n`` with the pooled n (allantools' too).
    n : (K,) int array
        Number of terms (second differences) behind each value, all pieces.
    """

    tau: np.ndarray
    adev: np.ndarray
    err: np.ndarray
    n: np.ndarray


def _tau_grid(n_max: int, fs: float, taus) -> np.ndarray:
    """Averaging factors m for 'log10' (~10 per decade), 'octave' or explicit taus [s]."""
    m_top = max(1, (n_max - 1) // 2)
    if isinstance(taus, str) and taus == "log10":
        m = np.logspace(0, np.log10(m_top), max(2, int(10 * np.log10(m_top)) + 1))
    elif isinstance(taus, str) and taus == "octave":
        m = 2.0 ** np.arange(int(np.log2(m_top)) + 1)
    elif isinstance(taus, str):
        raise ValueError(f"taus must be 'log10', 'octave' or an array of seconds, not {taus!r}")
    else:
        m = np.asarray(taus, dtype=float) * fs
    m = np.unique(np.round(m))
    return m[(m >= 1) & (m <= m_top)].astype(int)


def _oadev(x: np.ndarray, fs: float, ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(overlapping Allan deviation [u], number of terms) of rate samples ``x`` at the
    averaging factors ``ms`` (each with at least one term), [NIST1065] eq. (11).

    The rate is integrated to phase (mean removed first, a zero prepended: N + 1 phase points
    x_k), and σ²(mτ₀) = Σ (x_{k+2m} - 2x_{k+m} + x_k)² / (2 (mτ₀)² (N + 1 - 2m)). Hand-written
    (allantools' ``oadev`` computes the same; its package would pull pytest, sphinx and
    numpydoc into every install): the steps and their order are allantools' own, so the values
    are the same floats (tests/test_noise_terms.py compares them).
    """
    phase = np.insert(np.cumsum(x - np.nanmean(x)) * (1.0 / float(fs)), 0, 0)
    dev, n = np.zeros(len(ms)), np.zeros(len(ms))
    for i, m in enumerate(ms):
        m = int(m)
        k = len(phase) - 2 * m
        v = phase[2 * m:] - 2 * phase[m:m + k] + phase[:k]
        dev[i] = np.sqrt(np.sum(v * v) / (2.0 * k)) / m * float(fs)
        n[i] = k
    return dev, n


def allan_deviation(pieces, fs: float, taus="log10") -> AllanDeviation:
    """Overlapping Allan deviation ([IEEE952] Annex C, [NIST1065] eq. 11) of each piece,
    pooled over pieces.

    Parameters
    ----------
    pieces : list of 1-D arrays
        Residual samples of separate still periods [u] (rate-like data, integrated to phase).
    fs : float
        Sample rate [Hz].
    taus : "log10", "octave" or array of float
        Averaging times [s]: about 10 per decade or octaves from 1/fs up to half the longest
        piece, or explicit values (rounded to whole samples).

    Returns
    -------
    AllanDeviation
        Values at the taus that at least one piece supports with two or more terms.
    """
    xs = _finite_pieces(pieces)                  # mean kept: _oadev removes it
    ms = _tau_grid(max(len(x) for x in xs), fs, taus)
    num, cnt = np.zeros(len(ms)), np.zeros(len(ms))
    for x in xs:
        ok = np.flatnonzero(len(x) - 2 * ms + 1 > 1)    # two terms or more
        if len(ok) == 0:
            continue
        ad, n = _oadev(x, fs, ms[ok])
        num[ok] += n * ad ** 2
        cnt[ok] += n
    keep = cnt > 0
    adev = np.sqrt(num[keep] / cnt[keep])
    return AllanDeviation(tau=ms[keep] / fs, adev=adev, err=adev / np.sqrt(cnt[keep]),
                          n=cnt[keep].astype(int))
