"""Monte-Carlo accuracy of the ellipsoid estimators against the Cramér-Rao lower bound.

Simulates sessions with known truth ([Niespodziany] model S_p = W·S + V0, symmetric W; calibration
``M = W⁻¹``, ``o = V0``): a fixed design of field directions, isotropic Gaussian noise σ on each
measured vector, many noise realisations. For each parameter (offset 3, symmetric matrix 6) it
prints the RMSE of [Niespodziany]'s analytical and numerical fits, of the robust fit, and of the robust
fit with its second-order bias removed (apmcal.solvers.ellipsoid.debias), next to the CRLB of the
same design, and the efficiency CRLB/MSE (1 = as good as any unbiased estimator).

CRLB: the geometric model ``|M(s − o)| = r`` with the unknown directions as nuisance parameters;
to first order only the radial noise component ``nᵀM·ε`` (variance σ²·|Mᵀn|²) informs θ, so
``I(θ) = Σ Jᵢᵀ Jᵢ / (σ² |Mᵀnᵢ|²)`` with Jᵢ = ∂rᵢ/∂θ at the truth, CRLB = diag(I⁻¹).

Run: ``.venv/bin/python benchmarks/accuracy.py [--runs 200]`` (about 3 minutes).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in (".", "sitl")]

from apmcal.solvers.ellipsoid.debias import (
    debiased,  # noqa: E402
    warm_refit,  # noqa: E402
)
from apmcal.solvers.ellipsoid.paper import (  # noqa: E402
    DIAGONAL_ENTRIES,
    SYMMETRIC_ENTRIES,
    fit_ellipsoid_analytical,
    fit_ellipsoid_numerical,
    geometric_residual,
    matrix_to_params,
)
from apmcal.solvers.ellipsoid.robust import fit_ellipsoid_robust  # noqa: E402

NAMES = ["o_x", "o_y", "o_z", "M_xx", "M_yy", "M_zz", "M_xy", "M_xz", "M_yz"]
RADIUS = 500.0          # e.g. mGauss
SIGMA = 3.0             # per-axis noise, same units


def make_truth(rng, diagonal: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Random symmetric W near I (±4 % scale, ±3 % cross terms) and offset V0."""
    A = rng.normal(scale=0.03, size=(3, 3))
    W = np.eye(3) + np.diag(rng.normal(scale=0.04, size=3))
    if not diagonal:
        W += 0.5 * (A + A.T)
    return W, rng.normal(scale=0.4 * RADIUS, size=3)


def design(kind: str, rng, n: int = 200) -> np.ndarray:
    """Unit field directions: full sphere, upper half (partial coverage), or six faces."""
    if kind == "six-faces":
        return np.repeat(np.vstack([np.eye(3), -np.eye(3)]), n // 6, axis=0)
    d = rng.normal(size=(4 * n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if kind == "half-sphere":
        d = d[d[:, 2] > 0]
    return d[:n]


def theta(offset, M, entries) -> np.ndarray:
    return np.concatenate([offset, matrix_to_params(M, entries)])


def crlb(W, V0, dirs, entries) -> np.ndarray:
    """One-sigma CRLB of θ = [o, m] for this design (see module docstring)."""
    M = np.linalg.inv(W)
    s = (RADIUS * dirs) @ W.T + V0                       # noise-free measurements
    _, J = geometric_residual(theta(V0, M, entries), s, RADIUS, entries, jac=True)
    n = (s - V0) @ M.T
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    var_r = SIGMA ** 2 * np.sum((n @ M) ** 2, axis=1)    # σ²|Mᵀn|²
    info = (J / var_r[:, None]).T @ J
    return np.sqrt(np.diag(np.linalg.inv(info)))


def fits(diagonal: bool) -> dict:
    """The estimators; diagonal variants when the design cannot carry cross terms. "debiased"
    is the robust fit with its second-order bias removed, as apmcal runs it on magnetometers."""
    def robust(s, info=None):
        return fit_ellipsoid_robust(s, RADIUS, info=info,
                                    parameterisation="diagonal" if diagonal else "symmetric")

    def robust_debiased(s):
        info: dict = {}
        cal = robust(s, info)
        return debiased(warm_refit(cal, RADIUS, info), s[info["inliers"]], cal, RADIUS)[0]

    return {
        "analytical": lambda s: fit_ellipsoid_analytical(s, RADIUS, diagonal_only=diagonal),
        "numerical": lambda s: fit_ellipsoid_numerical(s, RADIUS, diagonal_only=diagonal),
        "robust": robust,
        "debiased": robust_debiased,
    }


def run(kind: str, runs: int, rng, outliers: float = 0.0, n: int = 200,
        only: list[str] | None = None) -> dict:
    """Monte-Carlo of one design of ``n`` samples; prints the table, returns per-estimator
    efficiencies (of the estimators in ``only``, default all)."""
    diagonal = kind == "six-faces"   # axis-only directions: cross terms are second order, no info
    entries = DIAGONAL_ENTRIES if diagonal else SYMMETRIC_ENTRIES
    names = NAMES[:6] if diagonal else NAMES
    W, V0 = make_truth(rng, diagonal)
    dirs = design(kind, rng, n)
    truth = theta(V0, np.linalg.inv(W), entries)
    bound = crlb(W, V0, dirs, entries)
    estimators = {k: f for k, f in fits(diagonal).items() if not only or k in only}
    err = {k: [] for k in estimators}
    fails = {k: 0 for k in estimators}
    for _ in range(runs):
        s = (RADIUS * dirs) @ W.T + V0 + rng.normal(scale=SIGMA, size=dirs.shape)
        if outliers:
            k = int(outliers * len(s))
            s[:k] += rng.normal(scale=30 * SIGMA, size=(k, 3))
        for name, fit in estimators.items():
            try:
                c = fit(s)
                err[name].append(theta(c.offset, c.matrix, entries) - truth)
            except Exception:   # noqa: BLE001 — a failed fit is counted, not hidden
                fails[name] += 1
    title = f"{kind}, n={len(dirs)}, σ={SIGMA}, r={RADIUS}, {runs} runs"
    title += ", diagonal matrix" if diagonal else ", symmetric matrix"
    title += f", {100 * outliers:.0f}% outliers (CRLB is for Gaussian noise)" if outliers else ""
    print(f"\n== {title}")
    print(f"{'param':6} {'CRLB σ':>10} "
          + " ".join(f"{k + ' RMSE':>16} {'eff':>5}" for k in estimators))
    effs = {}
    for name in estimators:
        e = np.array(err[name]) if err[name] else np.full((1, len(names)), np.inf)
        effs[name] = bound ** 2 / np.mean(e ** 2, axis=0)
    for j, p in enumerate(names):
        row = f"{p:6} {bound[j]:10.4g} "
        for name in estimators:
            rmse = bound[j] / np.sqrt(effs[name][j])
            row += f"{rmse:16.4g} {effs[name][j]:5.2f} "
        print(row)
    for name in estimators:
        print(f"  {name:10}: median efficiency {np.median(effs[name]):.2f}, "
              f"min {np.min(effs[name]):.2f}, failed fits {fails[name]}")
    return effs


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--n", type=int, default=200,
                    help="samples per session (a magnetometer logged at 400 Hz for 10 min has "
                         "250 000: --n 100000 --runs 40 --only robust,debiased exercises the "
                         "subsampled robust stage and bias removal)")
    ap.add_argument("--only", help="comma-separated estimators (analytical, numerical, robust, "
                                   "debiased)")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    only = a.only.split(",") if a.only else None
    t0 = time.time()
    for kind in ("full-sphere", "half-sphere", "six-faces"):
        run(kind, a.runs, rng, n=a.n, only=only)
    run("full-sphere", a.runs, rng, outliers=0.05, n=a.n, only=only)
    print(f"\n{time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()
