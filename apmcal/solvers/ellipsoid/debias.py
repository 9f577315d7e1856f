"""The geometric ellipsoid fit's second-order bias, estimated and removed.

Why: every sample carries noise and its own unknown direction (a nuisance parameter per sample,
the Neyman-Scott setting), so the geometric fit of [Niespodziany] is biased by a term of order σ²/r
that does not shrink with more samples, while the spread does (~1/√n). On a full sphere the
terms nearly cancel; on partial coverage they do not: on a half sphere the bias of the offset
along the missing direction and of the diagonal is about half the Cramér-Rao bound at 200
samples and larger than it at 800 (``benchmarks/accuracy.py``), which is where the fit loses its
efficiency.

How (a parametric bootstrap, Efron & Tibshirani 1993 §10.6, with antithetic draws): each inlier
is projected onto the fitted ellipsoid along its calibrated direction, giving noise-free samples
of the fitted model; the model is refitted on those samples plus and minus the same Gaussian
noise draw (σ from the radial residuals). The pair's errors cancel to first order in the noise,
so their mean minus the fit is the second-order bias at the fitted parameters, with little
Monte-Carlo noise from a few pairs. The bias is subtracted; the reported sigmas are kept.

On many samples the refits use a random subset of ``MAX_SAMPLES``: the second-order bias is
set by the noise and the distribution of directions, not by their number (it does not shrink
with n), and a uniform subset keeps that distribution, while the Monte-Carlo scatter of the
antithetic mean, second order in σ/r, stays ~1/√(2·pairs·MAX_SAMPLES) of the bias itself,
far below the fit's own sigma. Below ``MAX_SAMPLES`` every sample is used, as before.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from apmcal.solvers.ellipsoid.lm import Problem, gradient
from apmcal.solvers.ellipsoid.paper import params_to_matrix
from apmcal.solvers.ellipsoid.robust import ENTRIES
from apmcal.solvers.report_types import Debias
from apmcal.solvers.result import SensorCalibration

DEFAULT_PAIRS = 4
MAX_SAMPLES = 50_000     # samples refitted at most (a random subset beyond)


def second_order_bias(fit: Callable[[np.ndarray], SensorCalibration], samples: np.ndarray,
                      cal: SensorCalibration, radius: float, pairs: int = DEFAULT_PAIRS,
                      rng=None) -> tuple[np.ndarray, np.ndarray]:
    """(offset bias, matrix bias) of ``fit`` at ``cal``, from ``pairs`` antithetic refits.

    Parameters
    ----------
    fit : callable
        The estimator to correct: (n, 3) samples → SensorCalibration, with the settings it was
        run with (radius, parameterisation). If it has a method ``at_design(clean)``, the fit
        it returns is used instead (given the (m, 3) noise-free samples every draw perturbs).
    samples : (n, 3) array
        The samples the fit used (outliers already left out); at most ``MAX_SAMPLES`` of them,
        drawn at random, are refitted.
    cal : SensorCalibration
        The fit's result on ``samples``.
    radius : float
        Field magnitude the fit scales to [sensor units].
    pairs : int
        Number of antithetic pairs of refits.
    rng : numpy.random.Generator, optional
        Source of the noise draws (and the subset); a generator seeded with 0 when None.

    Returns
    -------
    offset_bias : (3,) array
        Mean refit offset minus ``cal.offset`` [sensor units].
    matrix_bias : (3, 3) array
        Mean refit matrix minus ``cal.matrix``.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    if len(samples) > MAX_SAMPLES:
        samples = samples[np.sort(rng.choice(len(samples), MAX_SAMPLES, replace=False))]
    calibrated = cal.apply(samples)
    magnitude = np.linalg.norm(calibrated, axis=1, keepdims=True)
    # each sample moved onto the fitted ellipsoid along its own calibrated direction
    clean_calibrated = radius * calibrated / magnitude
    e = magnitude[:, 0] - radius                                  # radial residuals
    sigma = float(1.4826 * np.median(np.abs(e - np.median(e))))   # robust (MAD) σ
    # invert is affine: invert(c ± ε) = invert(c) ± M⁻¹ε, so the clean samples are mapped
    # back once and each draw by one 3×3 product (instead of a solve per refit)
    clean = cal.invert(clean_calibrated)
    if hasattr(fit, "at_design"):      # a refit that precomputes from the noise-free samples
        fit = fit.at_design(clean)
    to_measured = np.linalg.inv(cal.matrix).T
    offsets, matrices = [], []
    for _ in range(pairs):
        noise = rng.normal(scale=sigma, size=clean_calibrated.shape) @ to_measured
        for sign in (1.0, -1.0):
            refit = fit(clean + sign * noise)
            offsets.append(refit.offset)
            matrices.append(refit.matrix)
    return np.mean(offsets, axis=0) - cal.offset, np.mean(matrices, axis=0) - cal.matrix


def debiased(fit: Callable[[np.ndarray], SensorCalibration], samples: np.ndarray,
             cal: SensorCalibration, radius: float, pairs: int = DEFAULT_PAIRS,
             rng=None) -> tuple[SensorCalibration, Debias]:
    """``cal`` with its second-order bias subtracted, and by how much (for the report).

    Parameters
    ----------
    fit, samples, cal, radius, pairs, rng
        As for :func:`second_order_bias`.

    Returns
    -------
    SensorCalibration
        ``cal``'s offset (3,) and matrix (3, 3) minus their bias; drift, t_ref and sigmas kept.
    Debias
        The offset shift (3,) [sensor units], the largest matrix shift and the number of pairs.
    """
    d_offset, d_matrix = second_order_bias(fit, samples, cal, radius, pairs, rng)
    out = SensorCalibration(offset=cal.offset - d_offset, matrix=cal.matrix - d_matrix,
                            drift=cal.drift, t_ref=cal.t_ref, sigma=dict(cal.sigma))
    return out, Debias(offset_shift=-d_offset, matrix_shift_max=float(np.max(np.abs(d_matrix))),
                       pairs=pairs)


def warm_refit(cal: SensorCalibration, radius: float, info: dict, steps: int = 3):
    """The final least-squares stage of the fit that made ``cal`` (with ``info``), as a
    function of new samples, from ``cal``: for samples simulated from ``cal``'s model with
    Gaussian noise (the parametric bootstrap of :mod:`apmcal.solvers.ellipsoid.debias`).

    Same parameterisation and prior rows, plain least squares (on outlier-free Gaussian
    samples the Huber stage and the 4σ rejection leave the LS minimum where it is: the cut
    drops 6e-5 of them), no bounds. Started at the model the samples were drawn from, the
    refit is δ = O(σ) away: ``steps`` chord steps ``x ← x − A⁻¹Jᵀr`` with A = JᵀJ (+ prior)
    at the start contract the error by ~σ/r each (A is off by O(σ/r), as Gauss-Newton's own
    contraction), so three leave ~(σ/r)³·δ, far below the O(σ²/r) bias the bootstrap
    measures. A step needs only Jᵀr (:func:`apmcal.solvers.ellipsoid.lm.gradient`), and the
    setup a cold fit repeats (sphere fit, coverage, quadric start, Huber pass, covariance) is
    skipped. ``refit.at_design(clean)`` (m, 3): the same with A formed once, from the
    noise-free samples all draws perturb (as good a chord matrix: it too is O(σ/r) off).

    Parameters
    ----------
    cal : SensorCalibration
        The fit to start from (offset (3,) [sensor units], matrix (3, 3)).
    radius : float
        Field magnitude the fit scales to [sensor units].
    info : dict
        The fit's ``info`` (its ``parameterisation`` and ``prior``).
    steps : int
        Number of chord steps.

    Returns
    -------
    callable
        (m, 3) samples [sensor units] → SensorCalibration (no sigmas).
    """
    entries = ENTRIES[info["parameterisation"]]
    x0 = np.concatenate([cal.offset / radius, [cal.matrix[c[0]] for c in entries]])
    prior = info.get("prior")
    box = np.full(len(x0), np.inf)

    def chord_matrix(sT: np.ndarray) -> np.ndarray:
        """Cholesky factor of JᵀJ (+ prior) at the start, samples ``sT`` (3, m) / radius."""
        problem = Problem(sT, entries, np.ones(sT.shape[1]), "linear", 1.0, -box, box, prior)
        return np.linalg.cholesky(problem.normal_equations(x0)[0])

    def steps_from_start(sT: np.ndarray, chol: np.ndarray) -> SensorCalibration:
        x = x0.copy()
        for _ in range(steps):
            g = gradient(x, sT, entries)
            if prior is not None:
                g[3:] += prior[1] ** 2 * (x[3:] - prior[0])
            x = x - np.linalg.solve(chol.T, np.linalg.solve(chol, g))
        return SensorCalibration(offset=x[:3] * radius, matrix=params_to_matrix(x[3:], entries))

    def scaled(samples: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.asarray(samples, dtype=float).T / radius)

    def refit(samples: np.ndarray) -> SensorCalibration:
        sT = scaled(samples)
        return steps_from_start(sT, chord_matrix(sT))

    def at_design(clean: np.ndarray):
        chol = chord_matrix(scaled(clean))
        return lambda samples: steps_from_start(scaled(samples), chol)

    refit.at_design = at_design
    return refit
