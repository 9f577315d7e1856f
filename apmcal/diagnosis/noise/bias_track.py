"""Random-walk bias of still periods by a Kalman filter / RTS smoother on block means (filterpy).

An independent check of the rate random walk that :mod:`apmcal.diagnosis.noise.terms` fits to
the Haar wavelet variance (Guerrier et al. 2013): the samples of each still piece are modelled
as a bias that is a random walk plus white noise, averaged over blocks of samples, filtered and
smoothed with filterpy's ``KalmanFilter`` and restarted at each piece with a diffuse prior, so
pieces are independent and a jump between two holds costs nothing. :func:`random_walk_bias`
tracks the bias, :func:`random_walk_loglik` scores a rate random walk by the innovations
log-likelihood and :func:`fit_random_walk_ml` maximises it. ``pieces``, ``fs`` and the unit
``u`` are as in :mod:`apmcal.diagnosis.noise.allan`; white noise σ per sample and the rate random
walk q [u/√s] (increments of variance q²·dt, IEEE Std 952-1997's K, sitl's q) as in
:mod:`apmcal.diagnosis.noise.terms`. The default white noise of the ML fit comes from the
finest Haar scale (Percival & Walden 2000, §8.6), σ² = 2ν²(m = 1), the white-noise wavelet
variance ν² = σ²/(2m) at m = 1.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from apmcal.diagnosis.noise.allan import _indexed_pieces, _raw_pieces, haar_wavelet_variance


@dataclass(frozen=True)
class BiasTrack:
    """RTS-smoothed bias on block means, all pieces one after the other.

    Attributes
    ----------
    piece : (K,) int array
        Index (in the ``pieces`` passed) of the piece each block belongs to; pieces shorter
        than 64 samples or than one block are left out.
    t : (K,) array
        Time of the block centre from the start of its piece [s].
    measured : (K,) array
        Block means of the samples [u] (each piece's own mean is not removed).
    bias : (K,) array
        Smoothed bias averaged over the block [u].
    sigma : (K,) array
        Its one-sigma uncertainty [u].
    loglik : float
        Log-likelihood from the innovations (each piece's first block, the diffuse start,
        excluded).
    block : int
        Block length [samples].
    """

    piece: np.ndarray
    t: np.ndarray
    measured: np.ndarray
    bias: np.ndarray
    sigma: np.ndarray
    loglik: float
    block: int


def default_block(lengths, target_steps: int = 1000, min_blocks: int = 50) -> int:
    """Block length [samples]: about ``target_steps`` blocks in all, and at least
    ``min_blocks`` blocks in the median piece (never below one sample).

    Parameters
    ----------
    lengths : (P,) int array
        Lengths of the pieces [samples].
    target_steps : int
        Number of blocks aimed at over all pieces.
    min_blocks : int
        Blocks the median piece holds at least.

    Returns
    -------
    int
        Block length [samples], ≥ 1.
    """
    lengths = np.asarray(lengths)
    return int(max(1, min(lengths.sum() // target_steps, np.median(lengths) // min_blocks)))


def _block_means(x: np.ndarray, block: int) -> np.ndarray:
    k = len(x) // block
    return x[:k * block].reshape(k, block).mean(axis=1)


def _walk_filter(fs: float, sigma_white: float, q: float, block: int):
    """filterpy KalmanFilter for block means of bias + white noise, bias a random walk.

    State (x, b): x the walk at the end of the block, b its mean over the block. With L =
    block, γ² = q²/fs per sample: b_k = x_{k-1} + u_k, x_k = x_{k-1} + Δ_k, var Δ = γ²L,
    cov(Δ, u) = γ²(L+1)/2, var u = γ²(L+1)(2L+1)/(6L) (exact for a sampled walk); the
    measurement is b_k plus white noise of variance σ²/L.
    """
    from filterpy.kalman import KalmanFilter

    lb, g2 = float(block), q * q / fs
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.F = np.array([[1.0, 0.0], [1.0, 0.0]])
    kf.H = np.array([[0.0, 1.0]])
    kf.Q = g2 * np.array([[lb, (lb + 1) / 2], [(lb + 1) / 2, (lb + 1) * (2 * lb + 1) / (6 * lb)]])
    kf.R = np.array([[sigma_white ** 2 / lb]])
    return kf


def _diffuse_start(kf, y0: float):
    """Posterior of (x, b) after the first block mean with a diffuse prior on the walk."""
    r = kf.R[0, 0]
    q = kf.Q
    v = q[0, 0] - 2 * q[0, 1] + q[1, 1]          # var(Δ - u): x_1 = b_1 + Δ_1 - u_1
    return np.array([[y0], [y0]]), np.array([[r + v, r], [r, r]])


def _filter_piece(kf, y: np.ndarray, smooth: bool):
    """Filter (and RTS-smooth) one piece's block means; returns (mean, sd, loglik)."""
    x0, p0 = _diffuse_start(kf, y[0])
    if len(y) == 1:
        return y[:1], np.sqrt(p0[1:, 1]), 0.0
    kf.x, kf.P = x0, p0
    mu, cov, mu_p, cov_p = kf.batch_filter(y[1:].reshape(-1, 1, 1))
    s = cov_p[:, 1, 1] + kf.R[0, 0]
    v = y[1:] - mu_p[:, 1, 0]
    loglik = -0.5 * float(np.sum(np.log(2 * np.pi * s) + v * v / s))
    if not smooth:
        return None, None, loglik
    xs, ps, _, _ = kf.rts_smoother(np.concatenate([x0[None], mu]), np.concatenate([p0[None], cov]))
    return xs[:, 1, 0], np.sqrt(ps[:, 1, 1]), loglik


def _walk_setup(pieces, fs, sigma_white, q, block):
    """Checked arguments: the (index, piece) pairs, the block length and the filter."""
    for k, v in dict(fs=fs, sigma_white=sigma_white, q=q).items():
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{k} must be positive and finite, got {v}")
    xs = _indexed_pieces(pieces)
    block = block or default_block([len(x) for _, x in xs])
    return xs, block, _walk_filter(fs, sigma_white, q, block)


def random_walk_bias(pieces, fs: float, sigma_white: float, q: float,
                     block: int | None = None) -> BiasTrack:
    """Kalman filter + RTS smoother of a random-walk bias on block means of each piece.

    Local-level model (filterpy ``KalmanFilter.batch_filter`` and ``rts_smoother``): the bias
    is a random walk of rate random walk ``q``, each sample is bias + white noise of σ
    ``sigma_white``; the filter runs on block means (state in :func:`_walk_filter`) and restarts
    at each piece with a diffuse prior, so pieces are independent (a jump between holds is free).

    Parameters
    ----------
    pieces : list of 1-D arrays
        Samples of separate still periods [u] (means not removed; ≥ 64 samples each).
    fs : float
        Sample rate [Hz].
    sigma_white : float
        White noise σ per sample [u] (e.g. ``NoiseTerms.white_sigma.value``).
    q : float
        Rate random walk [u/√s] (increments of variance q²·dt).
    block : int, optional
        Block length [samples]; default :func:`default_block` (~1000 blocks in all, ≥ 50 per
        median piece). Samples after the last whole block of a piece are not used.

    Returns
    -------
    BiasTrack
    """
    xs, block, kf = _walk_setup(pieces, fs, sigma_white, q, block)
    parts, loglik = [], 0.0
    for i, x in xs:
        y = _block_means(x, block)
        if len(y) == 0:
            continue
        b, sd, ll = _filter_piece(kf, y, smooth=True)
        t = (np.arange(len(y)) + 0.5) * block / fs
        parts.append((np.full(len(y), i), t, y, b, sd))
        loglik += ll
    if not parts:
        raise ValueError(f"no piece holds a block of {block} samples")
    cat = [np.concatenate(c) for c in zip(*parts)]
    return BiasTrack(piece=cat[0], t=cat[1], measured=cat[2], bias=cat[3], sigma=cat[4],
                     loglik=loglik, block=block)


def random_walk_loglik(pieces, fs: float, sigma_white: float, q: float,
                       block: int | None = None) -> float:
    """Innovations log-likelihood of the block means under rate random walk q [u/√s].

    Parameters and model as in :func:`random_walk_bias`; pieces without a whole block add
    nothing.

    Returns
    -------
    float
        Sum over the pieces of the innovations log-likelihood (each piece's first block, the
        diffuse start, excluded).
    """
    xs, block, kf = _walk_setup(pieces, fs, sigma_white, q, block)
    ys = [_block_means(x, block) for _, x in xs]
    return sum(_filter_piece(kf, y, smooth=False)[2] for y in ys if len(y))


@dataclass(frozen=True)
class RandomWalkFit:
    """Maximum-likelihood rate random walk.

    Attributes
    ----------
    q : float
        ML rate random walk [u/√s].
    q_sigma : float
        One-sigma uncertainty [u/√s] from the curvature of the log-likelihood in log q.
    log_q_sigma : float
        The same as an uncertainty of ln q (a factor exp(±log_q_sigma)).
    loglik : float
        Maximum log-likelihood.
    at_bound : bool
        True when the maximum is at the edge of the search range (q then is only a bound).
    sigma_white : float
        White σ per sample used [u].
    block : int
        Block length [samples].
    """

    q: float
    q_sigma: float
    log_q_sigma: float
    loglik: float
    at_bound: bool
    sigma_white: float
    block: int


def _q_bounds(xs, fs, sigma_white, block) -> tuple[float, float]:
    """Search range for ln q: walk/white crossover τ_c = √3·N/q from block/10 to 1000×record."""
    n_allan = sigma_white / np.sqrt(fs)
    t_rec = sum(len(x) for x in xs) / fs
    return (np.log(np.sqrt(3) * n_allan / (1000 * t_rec)),
            np.log(np.sqrt(3) * n_allan / (0.1 * block / fs)))


def fit_random_walk_ml(pieces, fs: float, sigma_white: float | None = None,
                       block: int | None = None, bounds: tuple[float, float] | None = None
                       ) -> RandomWalkFit:
    """Maximum-likelihood rate random walk q from the Kalman innovations (pieces independent).

    A bounded 1-D search on ln q of :func:`random_walk_loglik`; the uncertainty comes from the
    numerical second derivative of the log-likelihood in ln q at the maximum.

    Parameters
    ----------
    pieces : list of 1-D arrays
        Samples of separate still periods [u].
    fs : float
        Sample rate [Hz].
    sigma_white : float, optional
        White noise σ per sample [u]; default from the finest Haar scale, σ² = 2ν²(m=1).
    block : int, optional
        Block length [samples] (default :func:`default_block`).
    bounds : (float, float), optional
        Search range of q [u/√s]; default: crossover time between a tenth of a block and
        1000 times the total record.

    Returns
    -------
    RandomWalkFit
    """
    xs = _raw_pieces(pieces)
    if sigma_white is None:
        sigma_white = float(np.sqrt(2 * haar_wavelet_variance(xs, fs).wv[0]))
    block = block or default_block([len(x) for x in xs])
    lo, hi = np.log(bounds) if bounds is not None else _q_bounds(xs, fs, sigma_white, block)

    def nll(lq):
        return -random_walk_loglik(xs, fs, sigma_white, float(np.exp(lq)), block)

    res = minimize_scalar(nll, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    lq, h = float(res.x), 0.05
    curv = (nll(lq + h) - 2 * res.fun + nll(lq - h)) / h ** 2
    sd = 1.0 / np.sqrt(curv) if curv > 0 else np.inf
    q = float(np.exp(lq))
    return RandomWalkFit(q=q, q_sigma=float(q * sd), log_q_sigma=float(sd), loglik=-float(res.fun),
                         at_bound=bool(min(lq - lo, hi - lq) < 0.01 * (hi - lo)),
                         sigma_white=float(sigma_white), block=int(block))
