"""The motion inside the holds — hand tremor and sway — as the gyro measured it, for the twin.

A hand-held board is never quite still: it sways (0.1-0.5 Hz) and trembles (4-9 Hz), and the
gyro sees that motion above its white noise. When ``motion_contamination`` is modelled the twin
does not invent a tremor of its own (a different draw would not line up with the real one):
it takes the real one. The gyro's hold residual is Wiener-filtered — each frequency kept in the
proportion S/(S + N) of motion power S to noise power N, the least-squares estimate of the
motion (Wiener 1949) — with N the fitted white noise and S what the holds' pooled spectrum
holds above it, where that is clearly (four times) above the noise. The estimate's tilt, in the bands sitl's own motion contamination uses, gives
the amplitudes written to a standalone twin.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import welch

from apmcal.diagnosis.noise_fit import SWAY_BAND_HZ, TREMOR_BAND_HZ

SEGMENT_S = 10.0        # Welch segment of the pooled hold spectrum [s] (sway down to 0.1 Hz)
CLEAR_ABOVE_NOISE = 4.0 # a frequency counts as motion where its power is this many times noise


def _hold_runs(session) -> list[tuple[int, int]]:
    return [(h.i0, h.i1) for h in session.holds if h.i1 - h.i0 >= 16]


def pooled_spectrum(x: np.ndarray, runs, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD (f, P (f, 3)) of ``x`` pooled over the hold runs, weighted by length."""
    nper = int(min(SEGMENT_S * fs, max(b - a for a, b in runs)))
    total, weight, f = 0.0, 0.0, None
    for a, b in runs:
        if b - a < nper:
            continue
        f, p = welch(x[a:b] - x[a:b].mean(axis=0), fs=fs, nperseg=nper, axis=0)
        total, weight = total + p * (b - a), weight + (b - a)
    return f, total / weight


def wiener_motion(residual: np.ndarray, session, sigma: np.ndarray) -> np.ndarray:
    """Estimated rate of motion (n, 3) [rad/s] inside the holds (zero elsewhere) from the gyro
    residual [rad/s] and its white noise per sample ``sigma`` (3,)."""
    fs, runs = session.fs, _hold_runs(session)
    out = np.zeros_like(residual)
    if not runs:
        return out
    f, power = pooled_spectrum(residual, runs, fs)
    noise = 2.0 * np.asarray(sigma) ** 2 / fs              # one-sided white density
    # only where the motion clearly stands out of the noise: a pooled Welch estimate of pure
    # noise strays above its level by chance, and a twin that copied those strays would copy
    # the real data's own noise into itself
    gain = np.where(power > CLEAR_ABOVE_NOISE * noise,
                    (power - noise) / np.maximum(power, 1e-300), 0.0)
    for a, b in runs:
        x = residual[a:b] - residual[a:b].mean(axis=0)
        spectrum = np.fft.rfft(x, axis=0)
        g = np.column_stack([np.interp(np.fft.rfftfreq(b - a, 1.0 / fs), f, gain[:, k])
                             for k in range(3)])
        out[a:b] = np.fft.irfft(spectrum * g, n=b - a, axis=0)
    return out


def band_amplitude_deg(rate: np.ndarray, session, band: tuple[float, float]) -> float:
    """sitl's amplitude parameter [deg] of the tilt in a band: its components are sinusoids of
    amplitude a/√count, so the tilt's RMS per axis is a/√2 (sitl.motion.Tremor)."""
    runs = _hold_runs(session)
    if not runs:
        return 0.0
    f, power = pooled_spectrum(rate, runs, session.fs)
    inside = (f >= band[0]) & (f <= band[1]) & (f > 0)
    tilt_var = np.trapezoid(power[inside] / (2 * np.pi * f[inside, None]) ** 2, f[inside], axis=0)
    return float(np.degrees(np.sqrt(2.0 * np.mean(tilt_var))))


def amplitudes(rate: np.ndarray, session) -> tuple[float, float]:
    """(tremor, sway) amplitudes [deg] of the estimated hold motion."""
    return (band_amplitude_deg(rate, session, TREMOR_BAND_HZ),
            band_amplitude_deg(rate, session, SWAY_BAND_HZ))
