"""Zero-phase Butterworth high-pass, the 0.5 Hz filter of [Oppong] §5.1-5.2 (step 3).

[Oppong] passes each axis of the one-minute static record through a high-pass with
f_c = 0.5 Hz before solving for the bias. It does not give the filter type or order; we use a
Butterworth (maximally flat pass band, so signal above f_c passes with unit gain) run forwards and
backwards (``scipy.signal.sosfiltfilt``) so it adds no phase shift or delay.

Order: 2 by default. Forward-backward filtering squares the magnitude response, so the effective
response is a 4th-order Butterworth magnitude with |H(f_c)|² = 0.5 (−6 dB at f_c). A low order
keeps the impulse response short (edge transients last about 1/f_c) which matters for records of
a minute or less; a higher order buys little since the signals of interest (noise, vibration) are
far above 0.5 Hz and DC is removed exactly by any order ≥ 1.

Edges: the record is extended by odd reflection over three cut-off periods (``padlen``) rather
than scipy's default of a few samples, so the start-up transient is absorbed in the padding.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import signal

from apmcal.core.errors import ApmcalError

DEFAULT_CUTOFF_HZ = 0.5     # [Oppong] §5.1
DEFAULT_ORDER = 2
MAX_JITTER = 0.05           # largest |Δt − median Δt| / median Δt accepted as "regular"
PAD_PERIODS = 3.0           # padding length in cut-off periods


def design(fs: float, cutoff: float = DEFAULT_CUTOFF_HZ, order: int = DEFAULT_ORDER) -> np.ndarray:
    """Second-order sections of a Butterworth high-pass (cutoff [Hz] at sampling rate fs [Hz]).

    Parameters
    ----------
    fs : float
        Sampling rate [Hz].
    cutoff : float, optional
        Cut-off frequency [Hz].
    order : int, optional
        Butterworth order of one pass.

    Returns
    -------
    numpy.ndarray, shape (n_sections, 6)
        ``scipy.signal`` second-order sections.

    Raises
    ------
    ApmcalError
        Non-positive rate, cutoff not inside (0, fs/2), or an order that is not a positive
        integer.
    """
    if not (fs > 0 and math.isfinite(fs)):
        raise ApmcalError(f"high-pass: sampling rate must be positive, got {fs}")
    if not 0 < cutoff < fs / 2:
        raise ApmcalError(f"high-pass: cutoff {cutoff} Hz must lie between 0 and the Nyquist "
                          f"frequency {fs / 2:g} Hz (sampling rate {fs:g} Hz)")
    if int(order) != order or order < 1:
        raise ApmcalError(f"high-pass: order must be a positive integer, got {order}")
    return signal.butter(int(order), cutoff, btype="highpass", fs=fs, output="sos")


def pad_length(fs: float, cutoff: float = DEFAULT_CUTOFF_HZ) -> int:
    """Samples of odd-reflection padding on each side: three cut-off periods.

    Parameters
    ----------
    fs : float
        Sampling rate [Hz].
    cutoff : float, optional
        Cut-off frequency [Hz].

    Returns
    -------
    int
    """
    return int(math.ceil(PAD_PERIODS * fs / cutoff))


def highpass(x, fs: float, cutoff: float = DEFAULT_CUTOFF_HZ, order: int = DEFAULT_ORDER) -> np.ndarray:
    """Zero-phase high-pass of regularly sampled ``x`` along axis 0.

    Parameters
    ----------
    x : (n,) or (n, k) array
        Samples, any unit (output in the same unit).
    fs : float
        Sampling rate [Hz].
    cutoff : float
        Cut-off frequency [Hz]; |H|² = 1/2 there after forward-backward filtering.
    order : int
        Butterworth order of one pass.

    Returns
    -------
    numpy.ndarray, shape of ``x``
        The filtered samples.

    Raises
    ------
    ApmcalError
        Cutoff not below Nyquist, or fewer samples than the padding needs (three cut-off periods).
    """
    x = np.asarray(x, dtype=float)
    sos = design(fs, cutoff, order)
    padlen = pad_length(fs, cutoff)
    n = x.shape[0] if x.ndim else 0
    if n <= padlen:
        raise ApmcalError(f"high-pass: {n} samples ({n / fs:.2f} s) too short for a {cutoff} Hz cut-off; "
                          f"need more than {padlen} samples ({padlen / fs:.1f} s)")
    if not np.all(np.isfinite(x)):
        raise ApmcalError("high-pass: samples contain NaN or inf")
    return signal.sosfiltfilt(sos, x, axis=0, padtype="odd", padlen=padlen)


def sampling_rate(t, max_jitter: float = MAX_JITTER) -> float:
    """Sampling rate [Hz] of times ``t`` [s], checking they are increasing and regular.

    Raises ApmcalError when a step differs from the median step by more than ``max_jitter``
    (relative): a digital filter designed for one rate is wrong on irregular samples (resample first).

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times [s].
    max_jitter : float, optional
        Largest accepted |Δt − median Δt| / median Δt.

    Returns
    -------
    float
        1 / median step [Hz].

    Raises
    ------
    ApmcalError
        Fewer than two times, times not strictly increasing, or irregular steps.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ApmcalError("high-pass: need at least two sample times")
    dt = np.diff(t)
    if not np.all(np.isfinite(dt)) or np.any(dt <= 0):
        k = int(np.argmax(~np.isfinite(dt) | (dt <= 0)))
        raise ApmcalError("high-pass: sample times not strictly increasing", where=f"sample {k + 1}")
    med = float(np.median(dt))
    jitter = np.abs(dt - med) / med
    if jitter.max() > max_jitter:
        k = int(np.argmax(jitter))
        raise ApmcalError(f"high-pass: irregular sampling (step {dt[k]:.4g} s vs median {med:.4g} s, "
                          f"{100 * jitter[k]:.0f} % > {100 * max_jitter:.0f} %); resample first",
                          where=f"sample {k + 1}")
    return 1.0 / med


def highpass_t(t, x, cutoff: float = DEFAULT_CUTOFF_HZ, order: int = DEFAULT_ORDER,
               max_jitter: float = MAX_JITTER) -> np.ndarray:
    """:func:`highpass` with the sampling rate taken from sample times ``t`` [s] (checked regular).

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times [s].
    x : array_like, shape (n,) or (n, k)
        Samples, any unit (output in the same unit).
    cutoff, order
        As for :func:`highpass`.
    max_jitter : float, optional
        As for :func:`sampling_rate`.

    Returns
    -------
    numpy.ndarray, shape of ``x``

    Raises
    ------
    ApmcalError
        From :func:`sampling_rate` and :func:`highpass`.
    """
    return highpass(x, sampling_rate(t, max_jitter), cutoff, order)
