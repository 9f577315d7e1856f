"""The fitted parameters of each effect, with one-sigma uncertainties and units, for the report.

Each fold's fit gives values and σ — the least-squares ones of the fit (residual-scaled), NaN
where the fit gives none (grid searches, noise terms); the reported value is the mean of the
two folds' (two independent halves of the data), with σ = ½·√(σ₀² + σ₁²).
"""
from __future__ import annotations

import numpy as np

from apmcal.core.constants import EARTH_RATE


def _rows(names: list, theta: np.ndarray, sigma: np.ndarray, effect: str):
    rows = [i for i, n in enumerate(names) if n == effect]
    return theta[rows], sigma[rows]


def _value(v, s, unit: str) -> dict:
    """A parameter's value and one-sigma, the same shape (σ NaN where none is known)."""
    v = np.asarray(v, float)
    s = np.asarray(s, float)
    s = s.reshape(v.shape) if s.size == v.size else np.full(v.shape, np.nan)
    return {"value": np.round(v, 12).tolist(), "sigma": np.round(s, 12).tolist(), "unit": unit}


def _gyro_sigma(fit) -> np.ndarray:
    return np.asarray(fit.gyr.sigma.get("theta", np.zeros_like(fit.gyr.theta)))


def effect_params(name: str, fit, noise) -> dict:
    """{parameter: {"value", "sigma", "unit"}} of effect ``name`` in ``fit`` / ``noise``."""
    g = fit.gyr
    if name == "temperature_drift":
        out = {}
        v, s = _rows(fit.gyr_columns, g.theta, _gyro_sigma(fit), name)
        if len(v):
            out["gyro_coef"] = _value(v[0], s[0], "rad/s per K")
        if fit.acc.theta.shape[0]:
            sa = np.asarray(fit.acc.sigma.get("theta", np.full(3, np.nan))).reshape(-1, 3)
            out["acc_coef"] = _value(fit.acc.theta[0], sa[0], "m/s² per K")
        out["reference_c"] = _value(fit.refs.temp_c, np.nan, "°C")
        return out
    if name == "bias_drift":
        v, s = _rows(fit.gyr_columns, g.theta, _gyro_sigma(fit), name)
        return {"gyro_drift": _value(v[0], s[0], "rad/s per s")} if len(v) else {}
    if name == "g_sensitivity":
        v, s = _rows(fit.gyr_columns, g.theta, _gyro_sigma(fit), name)
        return {"matrix": _value(v.T, s.T, "rad/s per m/s²")} if len(v) else {}
    if name in ("earth_rate", "triangle_drift"):
        return _vector_params(name, fit)
    if name in ("cross_axis", "scale_nonlinearity"):
        key = {"cross_axis": "alpha", "scale_nonlinearity": "k2"}[name]
        unit = {"alpha": "rad (α_yz, α_zy, α_zx)", "k2": "1/(m/s²)"}[key]
        return {key: _value(fit.acc.params.get(key, [np.nan] * 3),
                            fit.acc.sigma.get(key, [np.nan] * 3), unit)}
    if name == "local_gravity":
        return {"gravity": _value(fit.gravity, np.nan, "m/s²")}
    if name == "gyro_scale":
        d = fit.dynamics
        return {"scale": _value(d.gyro_scale, _dyn_sigma(d, "gyro_scale"), "1"),
                "misalignment": _value(d.gyro_gamma, _dyn_sigma(d, "gyro_gamma"),
                                       "rad (γ yz, zy, zx, xz, xy, yx)")}
    if name == "time_offset":
        return {"delay": _value(fit.dynamics.time_offset_s, _dyn_sigma(fit.dynamics,
                                                                        "time_offset"),
                                "s (accelerometer after gyro)")}
    if name == "mag_interference" and fit.mag is not None and fit.mag.theta.shape[0]:
        sm = np.asarray(fit.mag.sigma.get("theta", np.full(3, np.nan))).reshape(-1, 3)
        return {"per_amp": _value(fit.mag.theta[0], sm[0], "mGauss per A")}
    return _noise_params(name, noise)


def _dyn_sigma(dyn, name: str) -> np.ndarray:
    """One-sigma of the move-fit parameters of block ``name`` (NaN when not fitted)."""
    names = dyn.sigma.get("names", [])
    values = np.asarray(dyn.sigma.get("params", []), float)
    picked = [v for n, v in zip(names, values) if n == name]
    return np.asarray(picked) if picked else np.full(1, np.nan)


def _vector_params(name: str, fit) -> dict:
    g = fit.gyr
    coef = dict(zip(fit.gyr_vectors, g.vector_coef))
    sig = dict(zip(fit.gyr_vectors, g.sigma.get("vector_coef", np.full(len(coef), np.nan))))
    if name == "triangle_drift":
        if "triangle_drift" not in coef:
            return {}
        return {"speed": _value(np.degrees(coef[name]), np.degrees(sig[name]), "°/s per min"),
                "drift_time": _value(fit.refs.drift_time_min, np.nan, "min")}
    up, north = coef.get("earth_rate_up", np.nan), coef.get("earth_rate_north", np.nan)
    out = {"vertical": _value(up * EARTH_RATE, sig.get("earth_rate_up", np.nan) * EARTH_RATE,
                              "rad/s (Ω sin φ expected)")}
    if np.isfinite(north):
        out["horizontal"] = _value(north * EARTH_RATE,
                                   sig.get("earth_rate_north", np.nan) * EARTH_RATE,
                                   "rad/s (Ω cos φ expected)")
        out["latitude"] = _value(np.degrees(np.arctan2(up, north)), np.nan, "deg (implied)")
    return out


def _noise_params(name: str, noise) -> dict:
    sensors = [s for s in ("acc", "gyr", "mag") if s in noise]
    if name == "bias_random_walk":
        q = noise["gyr"].rw_q
        return {"gyro_q": _value(q, np.full(3, np.nan), "rad/s/√s")} if q is not None else {}
    if name == "lowpass_filter":
        return {f"{s}_cutoff": _value(noise[s].cutoff_hz if noise[s].cutoff_hz else np.nan,
                                      np.nan, "Hz (NaN: none)") for s in ("acc", "gyr")}
    if name == "quantization":
        return {f"{s}_step": _value(noise[s].step, np.full(3, np.nan), "sensor unit")
                for s in sensors if noise[s].step is not None}
    if name == "motion_contamination":
        n = noise["gyr"]
        return {"tremor": _value(n.tremor_deg, np.nan, "deg (4-9 Hz)"),
                "sway": _value(n.sway_deg, np.nan, "deg (0.1-0.5 Hz)"),
                "confirmed": _value(n.motion_confirmed or (np.nan, np.nan), np.full(2, np.nan),
                                    "share of the gyro's sway, tremor seen by the "
                                    "accelerometer")}
    return {}


def white_noise(noise) -> dict:
    """Per-sample white noise of each sensor (the nominal model's only noise term)."""
    units = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}
    return {s: _value(noise[s].sigma, np.full(3, np.nan), units[s] + " per sample")
            for s in ("acc", "gyr", "mag") if s in noise}


def mean_of_folds(parts: list[dict]) -> dict:
    """One effect's parameters from the fits of the folds: mean values, σ of the mean."""
    out = {}
    for key, first in parts[0].items():
        values = np.array([p[key]["value"] for p in parts], float)
        sigmas = np.array([p[key]["sigma"] for p in parts], float)
        sigma = np.sqrt(np.sum(sigmas ** 2, axis=0)) / len(parts)
        out[key] = _value(values.mean(axis=0), sigma, first["unit"])
    return out


def white_noise_of_folds(noises: list) -> dict:
    """The white noise of each fold's noise model, averaged (see :func:`white_noise`)."""
    return mean_of_folds([white_noise(n) for n in noises])
