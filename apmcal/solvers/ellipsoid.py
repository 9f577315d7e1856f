"""Ellipsoid calibration (seed 000, Niespodziany) and its robust successor: one entry point.

The estimators live in :mod:`apmcal.solvers.ellipsoid_paper` (the paper's analytical and
numerical fits, gyro offset, relative MSE) and :mod:`apmcal.solvers.ellipsoid_robust` (robust
geometric fit, coverage, verdict); this module re-exports them and wraps a fit into a
:class:`~apmcal.solvers.result.Calibration` with a report.
"""
from __future__ import annotations

import numpy as np

from apmcal.errors import ApmcalError
from apmcal.solvers.ellipsoid_paper import (
    fit_ellipsoid_analytical,
    fit_ellipsoid_numerical,
    gyro_offset,
    relative_mse,
    sphere_fit,
)
from apmcal.solvers.ellipsoid_robust import (
    algebraic_ellipsoid,
    direction_coverage,
    fit_ellipsoid_robust,
    verdict,
)
from apmcal.solvers.result import Calibration

__all__ = ["fit_ellipsoid_analytical", "fit_ellipsoid_numerical", "fit_ellipsoid_robust",
           "gyro_offset", "relative_mse", "sphere_fit", "algebraic_ellipsoid",
           "direction_coverage", "verdict", "ellipsoid_calibration"]

FITS = {"analytical": fit_ellipsoid_analytical, "numerical": fit_ellipsoid_numerical,
        "robust": fit_ellipsoid_robust}


MIN_RESIDUAL_DOF = 10     # below this the residual-based sigma is itself uncertain by > 20 %


def few_residuals_line(sensor: str, n_samples: int, n_params: int | None) -> list[str]:
    """A warning when the sigmas rest on few residuals (e.g. 7 hold means, 6 parameters).

    A sigma estimated from k residual degrees of freedom is itself uncertain by about 1/√(2k).
    """
    if n_params is None:
        return []
    dof = n_samples - n_params
    if dof >= MIN_RESIDUAL_DOF:
        return []
    if dof <= 0:
        return [f"{sensor}: {n_samples} samples for {n_params} parameters: no residual is left "
                "to estimate the uncertainty; the sigmas are not meaningful (add holds)"]
    return [f"{sensor}: only {dof} residual degree(s) of freedom ({n_samples} samples, "
            f"{n_params} parameters): the sigmas are themselves uncertain by about "
            f"{100 / np.sqrt(2 * dof):.0f}% (add holds)"]


def ellipsoid_calibration(samples: dict, radius: dict, *, method: str = "robust",
                          diagonal_only: dict | None = None, holdout: float = 0.0,
                          rng=None) -> Calibration:
    """Calibrate several sensors by ellipsoid fits into one Calibration (method "ellipsoid").

    Parameters
    ----------
    samples : dict
        sensor name ("acc", "mag") → (n, 3) samples; "gyr" → (n, 3) samples at rest (offset only,
        seed 000 §VIII).
    radius : dict
        sensor name → field magnitude in the samples' units (acc: local g [m/s²]; mag: WMM total
        intensity [mGauss]). Not needed for "gyr".
    method : {"robust", "analytical", "numerical"}
    diagonal_only : dict, optional
        sensor → bool, for the paper's fits (seed 000 §VII.A); the robust fit decides itself.
    holdout : float
        Fraction (0..0.5) of samples, taken at random, kept out of the fit to score the paper's
        relative MSE raw vs calibrated (seed 000 §VI.B). 0 scores on the fitting samples.
    """
    if method not in FITS:
        raise ApmcalError(f"unknown ellipsoid method {method!r} (robust, analytical, numerical)")
    rng = np.random.default_rng(rng)
    diagonal_only = diagonal_only or {}
    cal = Calibration(method="ellipsoid", report={"lines": [], "ellipsoid_method": method})
    for name, data in samples.items():
        if name == "gyr":
            cal.sensors["gyr"] = gyro_offset(data)
            cal.report["lines"].append("gyr: offset only (mean at rest, seed 000 §VIII); "
                                       "scale and cross-axis need known rotations")
            continue
        if name not in radius:
            raise ApmcalError(f"ellipsoid fit of {name}: radius (field magnitude) missing")
        data = np.asarray(data, dtype=float)
        idx = rng.permutation(len(data))
        n_test = int(round(holdout * len(data)))
        train, test = data[idx[n_test:]], data[idx[:n_test]] if n_test else data
        info: dict = {}
        kw = {"info": info}
        if method != "robust":
            kw["diagonal_only"] = bool(diagonal_only.get(name, False))
        sc = FITS[method](train, radius[name], **kw)
        cal.sensors[name] = sc
        mse_raw = relative_mse(test, None, radius[name])
        mse_cal = relative_mse(test, sc, radius[name])
        cal.report[name] = {k: v for k, v in info.items() if k not in ("cov", "inliers", "prior")}
        cal.report[name].update({"relative_mse_raw": mse_raw, "relative_mse_calibrated": mse_cal,
                                 "scored_on": "held-out" if n_test else "fitting"})
        cal.report["lines"] += verdict(train, sc, radius[name], sensor=name, info=info)
        cal.report["lines"] += few_residuals_line(name, len(train), info.get("n_params"))
        cal.report["lines"].append(f"{name}: relative MSE of |calibrated| (seed 000) raw "
                                   f"{mse_raw:.3g} → {mse_cal:.3g} on "
                                   f"{cal.report[name]['scored_on']} samples")
    return cal
