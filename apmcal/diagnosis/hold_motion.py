"""The motion inside the holds — hand tremor and sway — as the gyro measured it, for the twin.

A hand-held board is never quite still: it sways (0.1-0.5 Hz) and trembles (4-9 Hz), and the
gyro sees that motion above its white noise. When ``motion_contamination`` is modelled the twin
does not invent a tremor of its own (a different draw would not line up with the real one):
it takes the real one. The gyro's hold residual is Wiener-filtered — each frequency kept in the
proportion S/(S + N) of motion power S to noise power N, the least-squares estimate of the
motion (Wiener 1949) — with N the white noise floor read off the spectrum above the motion
bands and S what each hold's spectrum holds above it, where that is clearly (sixteen times) above
the noise and between 0.05 Hz (a slower change inside a still hold is the sensor drifting,
which other effects model) and 15 Hz. The estimate's tilt, in the bands sitl's own motion contamination uses, gives
the amplitudes written to a standalone twin.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import detrend, welch


TREMOR_BAND_HZ = (4.0, 9.0)   # the bands of sitl's motion contamination (sitl.truth defaults)
SWAY_BAND_HZ = (0.1, 0.5)
SEGMENT_S = 10.0        # Welch segment of the pooled hold spectrum [s] (sway down to 0.1 Hz)
CLEAR_ABOVE_NOISE = 16.0  # a frequency bin is motion where its power is this many times noise
                          # (pure noise exceeds it in one bin in e^16 ≈ 9 million)
SLOWEST_MOTION_HZ = 0.05  # slower changes of a still hold are drifts of the sensor, not motion
FASTEST_MOTION_HZ = 15.0  # hand tremor stays below this (sitl's 4-9 Hz; physiological 8-12 Hz)
NOISE_FROM_HZ = 16.0      # the noise floor is read above this frequency


def _hold_runs(session) -> list[tuple[int, int]]:
    return [(h.i0, h.i1) for h in session.holds if h.i1 - h.i0 >= 16]


def pooled_spectrum(x: np.ndarray, runs, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD (f, P (f, 3)) of ``x`` pooled over the hold runs (each detrended: a slow
    sensor drift is not motion), weighted by length."""
    nper = int(min(SEGMENT_S * fs, max(b - a for a, b in runs)))
    total, weight, f = 0.0, 0.0, None
    for a, b in runs:
        if b - a < nper:
            continue
        f, p = welch(detrend(x[a:b], axis=0), fs=fs, nperseg=nper, axis=0)
        total, weight = total + p * (b - a), weight + (b - a)
    return f, total / weight


def noise_floor(f: np.ndarray, power: np.ndarray) -> np.ndarray:
    """The white-noise density per axis: the upper quartile of the spectrum above the motion
    bands (16 Hz up, or the top 40 % of the band at slow rates) — a hand does not shake that
    fast, and a low-pass filter's roll-off near Nyquist is left out by the quartile."""
    fast = f >= min(NOISE_FROM_HZ, 0.6 * f[-1])
    return np.percentile(power[fast], 75, axis=0)


def wiener_motion(residual: np.ndarray, session) -> np.ndarray:
    """Estimated rate of motion (n, 3) [rad/s] inside the holds (zero elsewhere) from the gyro
    residual [rad/s] (module docstring).

    The noise floor comes from the holds' pooled spectrum; the gain is then set bin by bin on
    each hold's own spectrum (a pooled gain smeared over another frequency grid leaves a few
    per cent of a strong tremor behind, still far above the noise).
    """
    fs, runs = session.fs, _hold_runs(session)
    out = np.zeros_like(residual)
    if not runs:
        return out
    f, power = pooled_spectrum(residual, runs, fs)
    noise = noise_floor(f, power)
    for a, b in runs:
        x = detrend(residual[a:b], axis=0)     # a drift inside a hold is not motion
        # the hold mirrored onto its end is periodic without a jump: a plain FFT would spread a
        # strong tremor over every frequency through the jump between the hold's two ends
        mirrored = np.concatenate([x, x[::-1]])
        m = len(mirrored)
        spectrum = np.fft.rfft(mirrored, axis=0)
        freq = np.fft.rfftfreq(m, 1.0 / fs)
        periodogram = 2.0 * np.abs(spectrum) ** 2 / (fs * m)     # one-sided PSD
        clear = (periodogram > CLEAR_ABOVE_NOISE * noise) & \
            ((freq >= SLOWEST_MOTION_HZ) & (freq <= FASTEST_MOTION_HZ))[:, None]
        gain = np.where(clear, 1.0 - noise / np.maximum(periodogram, 1e-300), 0.0)
        out[a:b] = np.fft.irfft(spectrum * gain, n=m, axis=0)[:b - a]
    return out


def hold_rotations(session, rate: np.ndarray) -> np.ndarray:
    """Exp(θ(t)) (n, 3, 3) at every sample: θ the integral of ``rate`` [rad/s] through each
    hold, its mean over the hold removed (the hold's fitted orientation is its mean attitude);
    identity outside the holds."""
    from scipy.spatial.transform import Rotation

    rot = np.broadcast_to(np.eye(3), (len(rate), 3, 3)).copy()
    for h in session.holds:
        a, b = h.i0, h.i1
        if b - a < 2 or not np.any(rate[a:b]):
            continue
        dt = np.diff(session.t[a:b])
        theta = np.vstack([np.zeros(3), np.cumsum(0.5 * (rate[a:b - 1] + rate[a + 1:b])
                                                  * dt[:, None], axis=0)])
        rot[a:b] = Rotation.from_rotvec(theta - theta.mean(axis=0)).as_matrix()
    return rot


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
