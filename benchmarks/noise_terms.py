"""Noise terms of still gyro records: GMWM fit (ours) against the fixed-slope Allan line reading.

Records come from sitl's error model with every effect off except white noise (gyro_noise, a
one-sided density N_sitl = 8.7e-5 rad/s/√Hz, σ per sample = N_sitl·√(fs/2)) and the bias
random walk (gyro_bias_random_walk, q = 2e-5 rad/s/√s), at fs = 100 Hz, three independent axes
per seed. Each seed's 40-minute record is cut into the cases:

- "2 min", "10 min", "30 min": the first minutes, one continuous piece;
- "10 x 60 s holds", "30 x 60 s holds": 60-s pieces separated by 20-s gaps (the vehicle being
  turned between holds), pooled without differencing across the gaps.

For each record both methods estimate N (reported in sitl's one-sided convention) and K (= q):

- ``gmwm``: :func:`apmcal.diagnosis.noise.terms.fit_noise_terms` with all three candidates
  (white, bias instability, random walk) and selection by the criterion; a term the criterion
  leaves out counts as an infinite error (and is counted in "missed");
- ``gmwm w+rw``: the same with candidates white and random walk only;
- ``lines``: :func:`apmcal.diagnosis.noise.terms.noise_terms_allan_lines` (Kalibr /
  allan_variance_ros: −½ line at τ = 1 s, +½ line at τ = 3 s); a missing +½ part counts as
  infinite.

Printed per case and term: median and 90th percentile of |log10(estimate/truth)|, the same
ratio ours/lines, the share of records with ours closer to the truth than lines, the coverage of
ours' ±2σ interval, and how often a term was missed. With ``--ml``, also the Kalman/RTS
maximum-likelihood q (:func:`fit_random_walk_ml`, σ white from the GMWM fit) on the x axis of
each seed for "10 min" (about 2 s per record).

Run: ``.venv/bin/python benchmarks/noise_terms.py [--seeds 30] [--ml]`` (about a minute on two
cores; ``--ml`` adds about one more).
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in (".", "sitl")]

from apmcal.diagnosis.noise.bias_track import fit_random_walk_ml  # noqa: E402
from apmcal.diagnosis.noise.terms import fit_noise_terms, noise_terms_allan_lines  # noqa: E402
from apmcal.sensor_model.imu import ImuErrorModel  # noqa: E402
from apmcal.sensor_model.truth import Truth  # noqa: E402

FS = 100.0
N_SITL = 8.7e-5          # rad/s/√Hz, one-sided (sitl convention)
Q = 2e-5                 # rad/s/√s
TOTAL_S = 2400.0
CASES = ("2 min", "10 min", "30 min", "10 x 60 s holds", "30 x 60 s holds")
METHODS = ("gmwm", "gmwm w+rw", "lines")


def simulate(seed: int) -> np.ndarray:
    """(n, 3) still gyro record [rad/s] with only white noise and the bias random walk."""
    truth = Truth.random(seed).with_effects(disable=["all"],
                                            enable=["gyro_noise", "gyro_bias_random_walk"])
    truth.gyro_noise, truth.gyro_bias_random_walk = N_SITL, Q
    model = ImuErrorModel(truth, fs=FS, seed=seed)
    n, chunk, out = int(TOTAL_S * FS), 60000, []
    for i0 in range(0, n, chunk):
        t = np.arange(i0, min(n, i0 + chunk)) / FS
        z = np.zeros((len(t), 3))
        out.append(model.gyro(t, z, z))
    return np.concatenate(out)


def cut(x: np.ndarray, case: str) -> list[np.ndarray]:
    """The pieces of one case from a 1-D record."""
    if case.endswith("min"):
        return [x[:int(float(case.split()[0]) * 60 * FS)]]
    k = int(case.split()[0])
    hold, step = int(60 * FS), int(80 * FS)
    return [x[i * step:i * step + hold] for i in range(k)]


def _ours(pieces, components):
    r = fit_noise_terms(pieces, FS, components=components)
    n = r.white_density_sitl
    k = r.random_walk
    return (n.value if n else 0.0, n.sigma if n else np.inf,
            k.value if k else 0.0, k.sigma if k else np.inf, r)


def run_seed(seed: int, with_ml: bool) -> list[dict]:
    """Estimates of every method for every case and axis of one seed."""
    w = simulate(seed)
    rows = []
    for case in CASES:
        for axis in range(3):
            pieces = cut(w[:, axis], case)
            row = {"case": case, "seed": seed, "axis": axis}
            for name, comps in (("gmwm", ("white", "bias_instability", "random_walk")),
                                ("gmwm w+rw", ("white", "random_walk"))):
                nv, ns, kv, ks, res = _ours(pieces, comps)
                row[name] = (nv, ns, kv, ks)
                if name == "gmwm":
                    fit = res
            lines = noise_terms_allan_lines(pieces, FS)
            row["lines"] = (lines.white_density * np.sqrt(2), np.nan, lines.random_walk, np.nan)
            if with_ml and case == "10 min" and axis == 0 and fit.white_sigma:
                ml = fit_random_walk_ml(pieces, FS, fit.white_sigma.value)
                row["ml"] = (ml.q, ml.q_sigma)
            rows.append(row)
    return rows


def _log_err(est, truth) -> np.ndarray:
    est = np.asarray(est, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.abs(np.log10(est / truth))
    return np.where(np.isfinite(e), e, np.inf)


def _stats(e: np.ndarray) -> tuple[float, float]:
    return float(np.median(e)), float(np.percentile(e, 90, method="higher"))


def _fmt(v: float) -> str:
    return "    inf" if not np.isfinite(v) else f"{v:7.4f}"


def report(rows: list[dict]) -> None:
    print(f"truth: N_sitl = {N_SITL:.2e} rad/s/√Hz, q = K = {Q:.1e} rad/s/√s, fs = {FS:.0f} Hz; "
          "errors are |log10(estimate/truth)| (0.01 ≈ 2.3 %, 0.1 ≈ 26 %, 0.3 ≈ ×2)")
    head = (f"{'case':17s} {'term':4s} {'n':>3s} | " + " | ".join(f"{m:^15s}" for m in METHODS)
            + " | ours/lines med  p90 | ours closer | ±2σ cover | missed g/g2/l")
    print(head)
    print(f"{'':17s} {'':4s} {'':>3s} | " + " | ".join(f"{'med':>7s} {'p90':>7s}" for _ in METHODS))
    for case in CASES:
        rs = [r for r in rows if r["case"] == case]
        for term, idx, truth in (("N", 0, N_SITL), ("K", 2, Q)):
            err = {m: _log_err([r[m][idx] for r in rs], truth) for m in METHODS}
            st = {m: _stats(err[m]) for m in METHODS}
            ratio = [st["gmwm"][i] / st["lines"][i] if st["lines"][i] > 0 else np.nan
                     for i in range(2)]
            closer = np.mean(err["gmwm"] < err["lines"])
            est = np.array([r["gmwm"][idx] for r in rs])
            sig = np.array([r["gmwm"][idx + 1] for r in rs])
            ok = est > 0
            cover = np.mean(np.abs(est[ok] - truth) < 2 * sig[ok]) if ok.any() else np.nan
            missed = "/".join(str(int(np.sum(~np.isfinite(err[m])))) for m in METHODS)
            print(f"{case:17s} {term:4s} {len(rs):3d} | "
                  + " | ".join(f"{_fmt(st[m][0])} {_fmt(st[m][1])}" for m in METHODS)
                  + f" | {ratio[0]:14.2f} {ratio[1]:4.2f} | {closer:11.0%} | {cover:9.0%}"
                  + f" | {missed}")
    ml = [r for r in rows if "ml" in r]
    if ml:
        q = np.array([r["ml"][0] for r in ml])
        qs = np.array([r["ml"][1] for r in ml])
        k = np.array([r["gmwm w+rw"][2] for r in ml])
        ks = np.array([r["gmwm w+rw"][3] for r in ml])
        e = _log_err(q, Q)
        z = (q - k) / np.hypot(qs, ks)
        print(f"Kalman ML q, 10 min, x axis, {len(ml)} seeds: |log10 err| median {np.median(e):.4f}"
              f" p90 {np.percentile(e, 90):.4f}; ±2σ cover {np.mean(np.abs(q - Q) < 2 * qs):.0%};"
              f" (q_ML − K_gmwm)/σ: median |z| {np.median(np.abs(z)):.2f}, max {np.max(np.abs(z)):.2f}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--ml", action="store_true", help="also the Kalman ML q on 10-min records")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as ex:
        rows = [r for rs in ex.map(run_seed, range(args.seeds), [args.ml] * args.seeds)
                for r in rs]
    report(rows)
    print(f"{args.seeds} seeds × 3 axes, {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
