"""Machinery of benchmarks/accuracy_ferraris.py: simulator truth, CRLB against an independent
finite-difference Fisher matrix, and a small (20-run) Monte-Carlo. Not timed."""
from __future__ import annotations

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from apmcal.preprocessing.ferraris_regions import ferraris_regions
from apmcal.solvers.ferraris import ferraris_calibration

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "accuracy_ferraris.py"
_spec = importlib.util.spec_from_file_location("accuracy_ferraris", _PATH)
bench = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("accuracy_ferraris", bench)   # dataclasses look their module up
_spec.loader.exec_module(bench)

# a shorter session than the benchmark's default keeps the file fast
DESIGN = bench.Design(fs=50.0, t_hold=10.0, t_step=1.0, t_pause=2.0)
TRUTH = bench.Truth()
RUNS = 20


@pytest.fixture(scope="module")
def errors():
    return bench.monte_carlo(DESIGN, TRUTH, RUNS, np.random.default_rng(11))


# ----------------------------------------------------------------------------- simulator truth
def test_noise_free_session_gives_the_truth_exactly():
    """With no noise the drift variant must return the injected parameters (rectangle rule exact)."""
    t, acc, gyr, sections = bench.simulate(DESIGN, TRUTH)
    est = bench.estimators(DESIGN)["drift"](t, acc, gyr, sections)
    np.testing.assert_allclose(est, bench.truth_vector(TRUTH), rtol=0, atol=1e-9)
    no_drift = replace(TRUTH, b1=np.zeros(3))
    t, acc, gyr, sections = bench.simulate(DESIGN, no_drift)
    est = bench.estimators(DESIGN)["known g"](t, acc, gyr, sections)
    np.testing.assert_allclose(est, bench.truth_vector(no_drift), rtol=0, atol=1e-9)


def test_reference_time_is_the_one_ferraris_uses():
    t, acc, gyr, sections = bench.simulate(DESIGN, TRUTH, np.random.default_rng(0))
    cal = ferraris_calibration(t, acc, gyr, ferraris_regions(t, acc, gyr, sections=sections),
                               gravity=bench.G, lat_deg=90.0)
    assert cal.sensors["gyr"].t_ref == pytest.approx(bench.t_ref(DESIGN), abs=1e-9)


# ----------------------------------------------------------------------------- CRLB
def _params_to_truth(p: np.ndarray) -> "bench.Truth":
    """Parameters in the reported form (b_a, F⁻¹, c, b1, K, E⁻¹) → Truth."""
    return bench.Truth(b_a=p[0:3], F=np.linalg.inv(p[3:12].reshape(3, 3)), c=p[12:15],
                       b1=p[15:18], K=p[18:27].reshape(3, 3),
                       E=np.linalg.inv(p[27:36].reshape(3, 3)))


def _whitened_data(d, tr) -> np.ndarray:
    """Noise-free data the bound is about, each entry divided by its noise sigma."""
    t, acc, gyr, sections = bench.simulate(d, tr)
    parts = []
    for name, (i0, i1) in sections.items():
        if name in bench.POSES:
            parts += [acc[i0:i1].ravel() / d.sigma_a, gyr[i0:i1].ravel() / d.sigma_g]
        else:   # rotation integral Σ ω Δt, noise σ_g·√n/fs
            n = i1 - i0
            parts.append(gyr[i0:i1].sum(axis=0) / d.fs / (d.sigma_g * np.sqrt(n) / d.fs))
    return np.concatenate(parts)


def test_crlb_matches_finite_difference_fisher():
    """Fisher = JᵀJ of the whitened simulator output, J by central differences in the reported
    parameterisation (so the delta method for F⁻¹, E⁻¹ is checked too)."""
    tr = TRUTH
    p0 = np.concatenate([tr.b_a, np.linalg.inv(tr.F).ravel(), tr.c, tr.b1, tr.K.ravel(),
                         np.linalg.inv(tr.E).ravel()])
    cols = []
    for i in range(p0.size):
        h = 1e-6 * max(abs(p0[i]), 1e-2)
        pp, pm = p0.copy(), p0.copy()
        pp[i] += h
        pm[i] -= h
        cols.append((_whitened_data(DESIGN, _params_to_truth(pp))
                     - _whitened_data(DESIGN, _params_to_truth(pm))) / (2 * h))
    jac = np.column_stack(cols)
    scale = 1.0 / np.linalg.norm(jac, axis=0)          # Jacobi scaling before inverting
    cov = np.linalg.inv((jac * scale).T @ (jac * scale)) * np.outer(scale, scale)
    fd = np.sqrt(np.diag(cov))
    keep = np.r_[0:18, 27:36]                          # K is a nuisance, not reported
    np.testing.assert_allclose(bench.crlb(DESIGN, tr), fd[keep], rtol=1e-4)


def test_crlb_by_hand_for_accel_offset_and_one_hold():
    """Accel offset: 6 holds, regressor (1, ±g e_j) → var = σ²/(6n). One hold: σ/√n."""
    n = int(DESIGN.t_hold * DESIGN.fs)
    b = bench.crlb(DESIGN, TRUTH)
    np.testing.assert_allclose(b[:3], DESIGN.sigma_a / np.sqrt(6 * n), rtol=1e-12)
    assert bench.crlb_one_hold(DESIGN) == pytest.approx(DESIGN.sigma_g / np.sqrt(n), rel=1e-12)


# ----------------------------------------------------------------------------- Monte-Carlo
def test_drift_variant_is_unbiased(errors):
    e = errors["drift"]
    se = e.std(axis=0, ddof=1) / np.sqrt(RUNS)
    assert np.all(np.abs(e.mean(axis=0)) < 4 * se)


def test_known_g_accel_and_gyro_offset_are_unbiased(errors):
    e = errors["known g"][:, :15]          # accel offset + matrix, gyro offset (bias at t_ref)
    se = e.std(axis=0, ddof=1) / np.sqrt(RUNS)
    assert np.all(np.abs(e.mean(axis=0)) < 4 * se)


def test_efficiencies_where_theory_fixes_them(errors):
    bound = bench.crlb(DESIGN, TRUTH)
    eff = {k: bench.efficiency(e, bound) for k, e in errors.items()}
    # eq. 3 uses 2 of 6 holds per axis: variance σ²/(2n) vs the bound σ²/(6n) → 1/3
    assert 0.2 < np.mean(eff["known g"][:3]) < 0.5
    # ML parts: accel matrix with known g, drift variant gyro (pooled over 9-12 parameters)
    assert 0.7 < np.mean(eff["known g"][3:12]) < 1.4
    assert 0.7 < np.mean(eff["drift"][12:27]) < 1.4


def test_known_inefficiencies_are_detected(errors):
    bound = bench.crlb(DESIGN, TRUTH)
    # Q scaling: the diagonal of the accel matrix is off by ≈ (Q/g − 1), far above the bound
    q_diag = [3, 7, 11]
    assert np.all(bench.significant_bias(errors["paper(Q)"])[q_diag])
    assert np.all(bench.efficiency(errors["paper(Q)"], bound)[q_diag] < 0.01)
    # drift ignored: every gyro matrix entry biased
    assert np.all(bench.significant_bias(errors["known g"])[18:27])
    # one hold: g-sensitivity, drift and Earth rate stay in the bias
    assert np.all(bench.significant_bias(errors["1-pos"])[12:15])


def test_benchmark_main_prints_summary(capsys):
    bench.main(["--runs", "3", "--hold", "8", "--fs", "50"])
    out = capsys.readouterr().out
    assert "CRLB σ" in out and out.strip().splitlines()[-1].startswith("summary:")
