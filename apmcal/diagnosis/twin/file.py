"""``apmcal gap --write-twin``: the selected model as a simulator configuration.

A file ending in ``.parm`` or ``.param`` gets the same twin as ArduPilot SITL parameters instead
(:mod:`apmcal.diagnosis.twin.sitl_params`); any other name the JSON below.

The file is sitl's own truth format (:meth:`apmcal.sensor_model.truth.Truth.save`) plus a ``"twin"`` block
saying where it came from, so ``python -m apmcal_sim --twin TWIN.json`` (or ``apmcal_sim.makelog --twin``)
runs a vehicle with the real board's fitted errors. Two things differ from the in-process twin:

- sitl makes its own temperature, a warm-up curve T_amb + ΔT(1 − e^(−t/τ)): the curve is fitted
  to the log's temperatures and the biases are moved to its start, where sitl's ΔT is zero;
- sitl samples its sensors at 1 kHz and reports every n-th sample without averaging, so the
  white-noise densities are set for that rate: the logged noise per sample then matches the
  real log's (with the fitted low-pass, if any, applied at 1 kHz before the reporting).
"""
from __future__ import annotations

import json

import numpy as np
from scipy.optimize import curve_fit
from scipy.signal import butter, freqz

from apmcal.core.errors import ApmcalError

SITL_SENSOR_RATE_HZ = 1000.0     # apmcal_sim.vehicle.SimVehicle's default fs


def warmup_curve(t: np.ndarray, temp: np.ndarray) -> tuple[float, float, float]:
    """(T_amb [°C], ΔT [K], τ [s]) of T = T_amb + ΔT·(1 − e^(−t/τ)) fitted to a log's
    temperatures; a flat curve when the fit fails or the temperature hardly changes.

    Parameters
    ----------
    t : (n,) array
        Time since the start of the log [s].
    temp : (n,) array
        Temperatures [°C].

    Returns
    -------
    ambient_c : float
        T_amb [°C].
    rise_k : float
        ΔT [K].
    tau_s : float
        τ [s].
    """
    mean = float(np.nanmean(temp))
    if np.nanmax(temp) - np.nanmin(temp) < 0.2:
        return mean, 0.0, 240.0
    pick = np.linspace(0, len(t) - 1, min(len(t), 2000)).astype(int)
    curve = lambda x, a, r, tau: a + r * (1 - np.exp(-x / tau))  # noqa: E731
    span = float(t[-1] - t[0]) or 1.0
    try:
        (a, r, tau), _ = curve_fit(curve, t[pick], temp[pick],
                                   p0=(float(temp[0]), float(temp[-1] - temp[0]), span / 3),
                                   bounds=([-60, -80, 1.0], [120, 80, 1e6]), maxfev=2000)
    except (RuntimeError, ValueError):
        return mean, 0.0, 240.0
    return float(a), float(r), float(tau)


def power_gain(fs: float, cutoff_hz: float | None) -> float:
    """Mean |H(f)|² over 0..fs/2 of sitl's 2nd-order Butterworth (1 without a filter).

    Parameters
    ----------
    fs : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Cut-off [Hz] (None, or at or above fs/2: no filter).

    Returns
    -------
    float
    """
    if cutoff_hz is None or cutoff_hz >= fs / 2:
        return 1.0
    b, a = butter(2, cutoff_hz / (fs / 2))
    _, h = freqz(b, a, worN=4096)
    return float(np.mean(np.abs(h) ** 2))


def sitl_density(sigma: np.ndarray, log_fs: float, cutoff_hz: float | None) -> np.ndarray:
    """sitl noise density [unit/√Hz] at 1 kHz giving the log's per-sample variance at its rate.

    Parameters
    ----------
    sigma : (3,) array
        White noise per sample before the low-pass [unit].
    log_fs : float
        The log's sample rate [Hz].
    cutoff_hz : float or None
        Low-pass cut-off [Hz].

    Returns
    -------
    (3,) array
        [unit/√Hz].
    """
    variance = np.asarray(sigma) ** 2 * power_gain(log_fs, cutoff_hz)
    unit = (SITL_SENSOR_RATE_HZ / 2) * power_gain(SITL_SENSOR_RATE_HZ, cutoff_hz)
    return np.sqrt(variance / unit)


def standalone_truth(diagnosis):
    """The selected model fitted on every piece, as a Truth sitl can run on its own."""
    from apmcal.diagnosis.twin.simulate import twin_truth

    ev, session = diagnosis.evaluator, diagnosis.evaluator.session
    selected = tuple(diagnosis.result.selected)
    fit, noise, _ = ev.fit(session, ev.reduced, selected, None)
    truth = twin_truth(fit, noise, session.fs)
    _temperature(truth, fit, session)
    for sensor, key in (("acc", "acc_noise"), ("gyr", "gyro_noise")):
        setattr(truth, key, sitl_density(noise[sensor].sigma, session.fs,
                                         noise[sensor].cutoff_hz).tolist())
    if session.lat_deg is not None:
        truth.site = dict(truth.site, lat=session.lat_deg,
                          lon=session.lon_deg if session.lon_deg is not None else 0.0)
    return truth


def _temperature(truth, fit, session) -> None:
    """sitl's warm-up curve from the log; biases moved from T_ref to the curve's start."""
    if session.temp is None:
        return
    ambient, rise, tau = warmup_curve(session.t - session.t[0], session.temp)
    shift = ambient - fit.refs.temp_c
    acc_coef = np.asarray(truth.temperature["acc_coef"])
    gyro_coef = np.asarray(truth.temperature["gyro_coef"])
    truth.acc_bias = (np.asarray(truth.acc_bias) + acc_coef * shift).tolist()
    truth.gyro_bias = (np.asarray(truth.gyro_bias) + gyro_coef * shift).tolist()
    truth.temperature = dict(truth.temperature, ambient_c=ambient, rise_k=rise, tau_s=tau)


SITL_SUFFIXES = (".parm", ".param")


def write_twin(diagnosis, path) -> None:
    """Write the twin file (see the module docstring): ArduPilot SITL parameters for a name
    ending in .parm or .param, else apmcal_sim's truth JSON.

    Raises
    ------
    ApmcalError
        When the file cannot be written.
    """
    truth = standalone_truth(diagnosis)
    result = diagnosis.result
    if str(path).lower().endswith(SITL_SUFFIXES):
        from apmcal.diagnosis.twin.sitl_params import write_sitl_params

        sigma = {s: np.asarray(v["value"], float) for s, v in result.white_noise.items()}
        # a compass whose geometry the session could not fit (too few orientations) has
        # nothing to write: zeros would claim a perfect compass
        geometry = np.any(truth.mag_hard_iron) or not np.allclose(truth.mag_soft_iron, np.eye(3))
        write_sitl_params(path, truth, compass=diagnosis.evaluator.session.mag is not None
                          and bool(geometry), sigma=sigma, source=result.source,
                          selected=result.selected)
        return
    extra = {"twin": {"source": result.source, "selected": result.selected,
                      "gap_nominal": {"total": result.gap["total"],
                                      "heldout": result.gap["heldout"]},
                      "gap_selected": {"total": result.after["total"],
                                       "heldout": result.after["heldout"]},
                      "log_rate_hz": diagnosis.evaluator.session.fs,
                      "sensor_rate_hz": SITL_SENSOR_RATE_HZ,
                      "written_by": "apmcal gap --write-twin"}}
    try:
        truth.save(path, extra=json.loads(json.dumps(extra, default=float)))
    except OSError as exc:
        raise ApmcalError(f"cannot write twin file ({exc.strerror or exc})", str(path)) \
            from None
