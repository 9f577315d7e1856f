"""Ellipsoid calibration ([Niespodziany]) and its robust successor: one entry point.

The estimators live in :mod:`apmcal.solvers.ellipsoid.paper` (the paper's analytical and
numerical fits, gyro offset, relative MSE) and :mod:`apmcal.solvers.ellipsoid.robust` (robust
geometric fit, coverage, the numbers it is judged by); this module re-exports them and wraps a
fit into a :class:`~apmcal.solvers.result.Calibration` with a report.
"""
from __future__ import annotations

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.solvers.coverage import direction_coverage
from apmcal.solvers.ellipsoid.paper import (
    fit_ellipsoid_analytical,
    fit_ellipsoid_numerical,
    gyro_offset,
    relative_mse,
    sphere_fit,
)
from apmcal.solvers.ellipsoid.robust import algebraic_ellipsoid, fit_ellipsoid_robust, fit_report
from apmcal.solvers.report_types import CalibrationReport, MseScore
from apmcal.solvers.result import Calibration

__all__ = ["fit_ellipsoid_analytical", "fit_ellipsoid_numerical", "fit_ellipsoid_robust",
           "gyro_offset", "relative_mse", "sphere_fit", "algebraic_ellipsoid",
           "direction_coverage", "fit_report", "ellipsoid_calibration"]

FITS = {"analytical": fit_ellipsoid_analytical, "numerical": fit_ellipsoid_numerical,
        "robust": fit_ellipsoid_robust}


def ellipsoid_calibration(samples: dict, radius: dict, *, method: str = "robust",
                          diagonal_only: dict | None = None, holdout: float = 0.0,
                          rng=None) -> Calibration:
    """Calibrate several sensors by ellipsoid fits into one Calibration (method "ellipsoid").

    Parameters
    ----------
    samples : dict
        sensor name ("acc", "mag") → (n, 3) samples; "gyr" → (n, 3) samples at rest (offset only,
        [Niespodziany] §VIII).
    radius : dict
        sensor name → field magnitude in the samples' units (acc: local g [m/s²]; mag: WMM total
        intensity [mGauss]). Not needed for "gyr".
    method : {"robust", "analytical", "numerical"}
    diagonal_only : dict, optional
        sensor → bool, for the paper's fits ([Niespodziany] §VII.A); the robust fit decides itself.
    holdout : float
        Fraction (0..0.5) of samples, taken at random, kept out of the fit to score the paper's
        relative MSE raw vs calibrated ([Niespodziany] §VI.B). 0 scores on the fitting samples.
    rng : int or numpy.random.Generator, optional
        Seed or generator of the hold-out draw.

    Returns
    -------
    Calibration
        Method "ellipsoid": one SensorCalibration per sensor of ``samples``, and a report with an
        EllipsoidFit (including the relative-MSE score) per fitted sensor.

    Raises
    ------
    ApmcalError
        When ``method`` is unknown or a sensor other than "gyr" has no ``radius``.
    """
    if method not in FITS:
        raise ApmcalError(f"unknown ellipsoid method {method!r} (robust, analytical, numerical)")
    rng = np.random.default_rng(rng)
    diagonal_only = diagonal_only or {}
    cal = Calibration(method="ellipsoid", report=CalibrationReport())
    for name, data in samples.items():
        if name == "gyr":
            cal.sensors["gyr"] = gyro_offset(data)
            cal.report.gyro_offset_only = True
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
        fit = fit_report(train, sc, radius[name], info, method)
        fit.score = MseScore(relative_mse(test, None, radius[name]),
                             relative_mse(test, sc, radius[name]),
                             "held-out" if n_test else "fitting")
        cal.report.ellipsoids[name] = fit
    return cal
