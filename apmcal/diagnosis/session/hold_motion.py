"""The motion inside the holds — hand tremor and sway — as the gyro measured it and the
accelerometer confirms it, for the twin.

A hand-held board is never quite still: it sways (0.1-0.5 Hz) and trembles (4-9 Hz), and the
gyro sees that motion above its white noise. When ``motion_contamination`` is modelled the twin
does not invent a tremor of its own (a different draw would not line up with the real one):
it takes the real one. The gyro's hold residual is filtered by magnitude spectral subtraction
(Boll 1979): each frequency bin of power P is kept in the proportion 1 − √(N/P), N the white
noise floor read off the spectrum above the motion bands, where P is clearly (sixteen times)
above the noise and between 0.05 Hz (a slower change inside a still hold is the sensor
drifting, which other effects model) and 15 Hz. Unlike the least-squares (Wiener) gain
1 − N/P, this gain leaves the real residual exactly the noise power N in those bins — what the
twin's residual has there — so the comparison of the two is not biased by the extraction.

The gyro alone cannot tell a motion from a bump in its own noise spectrum, and taking such a
bump as motion would remove it from the real gyro and put it into the twin: evidence for an
effect that is not there. A turn of the board tilts gravity, so the accelerometer decides: each
band of the estimate (sway up to 1.5 Hz, tremor above) is kept only when its predicted tilt,
f × θ(t), shows in the accelerometer's hold samples of the training pieces: the least-squares
factor κ with which it appears there must be clearly (four standard errors) above zero and at
least one half (1 for a real motion, 0 for a gyro artefact; the noise left in the estimate
biases κ a little below 1, which is why the band is then kept whole rather than scaled by κ).
The estimate's tilt, in the bands sitl's own motion contamination uses, gives the amplitudes
written to a standalone twin.
"""
from __future__ import annotations

import numpy as np

TREMOR_BAND_HZ = (4.0, 9.0)   # the bands of sitl's motion contamination (apmcal.sensor_model.truth defaults)
SWAY_BAND_HZ = (0.1, 0.5)
SEGMENT_S = 10.0        # Welch segment of the pooled hold spectrum [s] (sway down to 0.1 Hz)
CLEAR_ABOVE_NOISE = 16.0  # a frequency bin is motion where its power is this many times noise
                          # (pure noise exceeds it in one bin in e^16 ≈ 9 million)
FASTEST_MOTION_HZ = 15.0  # hand tremor stays below this (sitl's 4-9 Hz; physiological 8-12 Hz)
NOISE_FROM_HZ = 16.0      # the noise floor is read above this frequency
BAND_SPLIT_HZ = 1.5       # sway below, tremor above (each confirmed on its own)
CONFIRM_SIGMAS = 4.0      # a band counts as motion when the accelerometer shows it this clearly
CONFIRM_SHARE = 0.5       # ... and at least this share of it


def _hold_runs(session) -> list[tuple[int, int]]:
    return [(h.i0, h.i1) for h in session.holds if h.i1 - h.i0 >= 16]


def pooled_spectrum(x: np.ndarray, runs, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD (f, P (f, 3)) of ``x`` pooled over the hold runs (each detrended: a slow
    sensor drift is not motion), weighted by length.

    Parameters
    ----------
    x : (n, 3) array
        Samples at every session sample (e.g. a rate [rad/s]).
    runs : list of (int, int)
        Half-open sample ranges of the holds; those shorter than one Welch segment are left
        out.
    fs : float
        Sample rate [Hz].

    Returns
    -------
    f : (k,) array
        Frequencies [Hz].
    power : (k, 3) array
        PSD per axis [(unit of x)²/Hz].
    """
    from scipy.signal import detrend, welch  # here: only motion contamination needs it

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
    fast, and a low-pass filter's roll-off near Nyquist is left out by the quartile.

    Parameters
    ----------
    f : (k,) array
        Frequencies [Hz], ascending.
    power : (k, 3) array
        One-sided PSD per axis (:func:`pooled_spectrum`).

    Returns
    -------
    (3,) array
        Noise density per axis, in the unit of ``power``.
    """
    fast = f >= min(NOISE_FROM_HZ, 0.6 * f[-1])
    return np.percentile(power[fast], 75, axis=0)


def extract_motion(residual: np.ndarray, session) -> tuple[np.ndarray, np.ndarray]:
    """Estimated rate of motion [rad/s] inside the holds (zero elsewhere) from the gyro
    residual [rad/s] (module docstring), as two (n, 3) parts: sway (up to ``BAND_SPLIT_HZ``)
    and tremor (above).

    The noise floor comes from the holds' pooled spectrum; the gain is then set bin by bin on
    each hold's own spectrum (a pooled gain smeared over another frequency grid leaves a few
    per cent of a strong tremor behind, still far above the noise).

    Parameters
    ----------
    residual : (n, 3) array
        Gyro hold residual at every session sample [rad/s].
    session : Session

    Returns
    -------
    sway, tremor : (n, 3) arrays
        Rate of motion [rad/s] up to and above ``BAND_SPLIT_HZ``.
    """
    fs, runs = session.fs, _hold_runs(session)
    slow, fast = np.zeros_like(residual), np.zeros_like(residual)
    if not runs:
        return slow, fast
    f, power = pooled_spectrum(residual, runs, fs)
    noise = noise_floor(f, power)
    for a, b in runs:
        x = residual[a:b] - residual[a:b].mean(axis=0)
        # the hold mirrored onto its end is periodic without a jump: a plain FFT would spread a
        # strong tremor over every frequency through the jump between the hold's two ends
        mirrored = np.concatenate([x, x[::-1]])
        m = len(mirrored)
        spectrum = np.fft.rfft(mirrored, axis=0)
        freq = np.fft.rfftfreq(m, 1.0 / fs)
        periodogram = 2.0 * np.abs(spectrum) ** 2 / (fs * m)     # one-sided PSD
        clear = (periodogram > CLEAR_ABOVE_NOISE * noise) & \
            ((freq > 0) & (freq <= FASTEST_MOTION_HZ))[:, None]
        gain = np.where(clear, 1.0 - np.sqrt(noise / np.maximum(periodogram, 1e-300)), 0.0)
        low = (freq <= BAND_SPLIT_HZ)[:, None]
        slow[a:b] = np.fft.irfft(spectrum * gain * low, n=m, axis=0)[:b - a]
        fast[a:b] = np.fft.irfft(spectrum * gain * ~low, n=m, axis=0)[:b - a]
    return slow, fast


def hold_angles(session, rate: np.ndarray) -> np.ndarray:
    """θ(t) (n, 3) [rad]: the integral of ``rate`` [rad/s] through each hold, its mean over the
    hold removed (the hold's fitted orientation is its mean attitude); zero outside the holds.

    Parameters
    ----------
    session : Session
    rate : (n, 3) array
        Rate of motion at every session sample [rad/s].

    Returns
    -------
    (n, 3) array
        Rotation vector θ [rad].
    """
    theta = np.zeros_like(rate)
    for h in session.holds:
        a, b = h.i0, h.i1
        if b - a < 2 or not np.any(rate[a:b]):
            continue
        dt = np.diff(session.t[a:b])
        turn = np.vstack([np.zeros(3), np.cumsum(0.5 * (rate[a:b - 1] + rate[a + 1:b])
                                                 * dt[:, None], axis=0)])
        theta[a:b] = turn - turn.mean(axis=0)
    return theta


def confirmed_by_accelerometer(session, rate: np.ndarray, hold_f: np.ndarray,
                               pieces: np.ndarray) -> float:
    """κ ∈ [0, 1]: how much of the tilt the motion ``rate`` predicts, f × θ(t) for small turns
    θ of a hold whose specific force is f [m/s²] (R(θ)ᵀ·f ≈ f − θ × f), the accelerometer
    shows in the hold ``pieces`` — least squares, each piece's mean and slope removed; 0 unless
    the fit is ``CONFIRM_SIGMAS`` standard errors above zero (a tilt far below the
    accelerometer's noise confirms nothing). See :func:`confirmed` for the decision.

    Parameters
    ----------
    session : Session
    rate : (n, 3) array
        Rate of the motion (one band) at every session sample [rad/s].
    hold_f : (n_holds, 3) array
        Specific force of each hold [m/s²].
    pieces : (k,) int array
        Session-wide ids of the hold pieces to look in (pieces under 16 samples are skipped).

    Returns
    -------
    float
        κ (dimensionless, 1 for a real motion).
    """
    from scipy.signal import detrend

    theta = hold_angles(session, rate)
    num = den = power = 0.0
    count = 0
    pc = session.pieces
    for p in pieces:
        a, b = pc.i0[p], pc.i1[p]
        hold = session.hold_of_piece(p)
        if b - a < 16 or hold is None:
            continue
        tilt = detrend(np.cross(hold_f[hold], theta[a:b]), axis=0)
        acc = detrend(session.acc[a:b], axis=0)
        num, den = num + float(np.sum(tilt * acc)), den + float(np.sum(tilt * tilt))
        power, count = power + float(np.sum(acc * acc)), count + acc.size
    if den <= 0 or count == 0:
        return 0.0
    kappa = num / den
    standard_error = np.sqrt(power / count / den)     # σ of κ for white residuals of that size
    return float(np.clip(kappa, 0.0, 1.0)) if kappa > CONFIRM_SIGMAS * standard_error else 0.0


def confirmed(kappa: float) -> bool:
    """Whether a band with accelerometer share ``kappa`` is motion (module docstring)."""
    return kappa >= CONFIRM_SHARE


def hold_rotations(session, rate: np.ndarray) -> np.ndarray:
    """Exp(θ(t)) (n, 3, 3) at every sample (θ of :func:`hold_angles`); identity outside the
    holds.

    Parameters
    ----------
    session : Session
    rate : (n, 3) array
        Rate of motion at every session sample [rad/s].

    Returns
    -------
    (n, 3, 3) array
        Rotation matrices.
    """
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(hold_angles(session, rate)).as_matrix()


def band_amplitude_deg(rate: np.ndarray, session, band: tuple[float, float]) -> float:
    """sitl's amplitude parameter [deg] of the tilt in a band: its components are sinusoids of
    amplitude a/√count, so the tilt's RMS per axis is a/√2 (apmcal_sim.motion.Tremor).

    Parameters
    ----------
    rate : (n, 3) array
        Rate of motion at every session sample [rad/s].
    session : Session
    band : (float, float)
        Frequency band [Hz].

    Returns
    -------
    float
        Amplitude a [deg] (0 without holds to measure in).
    """
    runs = _hold_runs(session)
    if not runs:
        return 0.0
    f, power = pooled_spectrum(rate, runs, session.fs)
    inside = (f >= band[0]) & (f <= band[1]) & (f > 0)
    tilt_var = np.trapezoid(power[inside] / (2 * np.pi * f[inside, None]) ** 2, f[inside], axis=0)
    return float(np.degrees(np.sqrt(2.0 * np.mean(tilt_var))))


def amplitudes(rate: np.ndarray, session) -> tuple[float, float]:
    """(tremor, sway) amplitudes [deg] of the estimated hold motion.

    Parameters
    ----------
    rate : (n, 3) array
        Rate of motion at every session sample [rad/s].
    session : Session

    Returns
    -------
    tremor_deg, sway_deg : float
        sitl's amplitudes [deg] in ``TREMOR_BAND_HZ`` and ``SWAY_BAND_HZ``.
    """
    return (band_amplitude_deg(rate, session, TREMOR_BAND_HZ),
            band_amplitude_deg(rate, session, SWAY_BAND_HZ))
