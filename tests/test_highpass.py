"""The 0.5 Hz zero-phase high-pass of [Oppong] §5, checked against Butterworth theory."""
from __future__ import annotations

import numpy as np
import pytest

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.highpass import highpass, highpass_t, pad_length, sampling_rate

FS = 100.0


def _sine(f, seconds=40.0, fs=FS, phase=0.3, dc=0.0):
    t = np.arange(int(seconds * fs)) / fs
    return t, dc + np.sin(2 * np.pi * f * t + phase)


def _fit_sine(t, y, f):
    """Amplitude and phase of the f-Hz component by least squares."""
    a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
    (s, c, _), *_ = np.linalg.lstsq(a, y, rcond=None)
    return np.hypot(s, c), np.arctan2(c, s)


def _middle(n, frac=0.25):
    k = int(n * frac)
    return slice(k, n - k)


def test_sine_above_cutoff_passes_with_unit_gain_and_zero_phase():
    t, x = _sine(5.0, dc=3.0)
    y = highpass(x, FS)
    m = _middle(t.size)
    amp, ph = _fit_sine(t[m], y[m], 5.0)
    # |H|² of forward-backward order-2 Butterworth: 1 / (1 + (fc/f)^4) = 1 - 6e-6 at 5 Hz
    assert amp == pytest.approx(1 / (1 + (0.5 / 5.0) ** 4), abs=1e-4)
    assert ph == pytest.approx(0.3, abs=1e-4)          # zero phase: input phase kept
    assert abs(np.mean(y[m])) < 1e-3                    # DC of 3 removed


@pytest.mark.parametrize("f", [0.25, 0.5, 1.0])
def test_gain_follows_butterworth_magnitude_squared(f):
    """filtfilt squares |H|: gain = 1 / (1 + (fc/f)^(2N)) for order N, i.e. 1/2 at fc (−6 dB)."""
    t, x = _sine(f, seconds=200.0)
    y = highpass(x, FS, cutoff=0.5, order=2)
    m = _middle(t.size)
    amp, ph = _fit_sine(t[m], y[m], f)
    assert amp == pytest.approx(1 / (1 + (0.5 / f) ** 4), rel=2e-3)
    assert ph == pytest.approx(0.3, abs=2e-3)


def test_order_is_configurable():
    t, x = _sine(0.5, seconds=200.0)
    m = _middle(t.size)
    amp4, _ = _fit_sine(t[m], highpass(x, FS, order=4)[m], 0.5)
    amp, _ = _fit_sine(t[m], highpass(x, FS, order=4, cutoff=0.25)[m], 0.5)
    assert amp4 == pytest.approx(0.5, rel=2e-3)
    assert amp == pytest.approx(1 / (1 + 0.5 ** 8), rel=2e-3)


def test_multichannel_and_constant_input():
    x = np.column_stack([np.full(1000, 9.81), np.full(1000, -0.2), np.zeros(1000)])
    y = highpass(x, FS)
    assert y.shape == x.shape
    assert np.abs(y).max() < 1e-9       # odd padding: a constant maps to exactly zero


def test_telemetry_rate_2hz_allows_half_hertz():
    t = np.arange(240) / 2.0            # 2 Hz RAW_IMU stream, 2 min
    x = 5.0 + np.sin(2 * np.pi * 0.9 * t)
    y = highpass_t(t, x)
    assert abs(np.mean(y[60:-60])) < 0.05


def test_cutoff_at_or_above_nyquist_raises():
    with pytest.raises(ApmcalError, match="Nyquist"):
        highpass(np.zeros(1000), fs=1.0, cutoff=0.5)
    with pytest.raises(ApmcalError, match="Nyquist"):
        highpass(np.zeros(1000), fs=FS, cutoff=60.0)


def test_too_short_raises():
    n = pad_length(FS, 0.5)             # 600 samples = three cut-off periods
    assert n == 600
    with pytest.raises(ApmcalError, match="too short"):
        highpass(np.zeros(n), FS)
    assert highpass(np.zeros(n + 1), FS).shape == (n + 1,)


def test_irregular_time_raises_and_regular_jitter_passes():
    rng = np.random.default_rng(1)
    t = np.arange(2000) / FS
    jittered = t + rng.uniform(-0.01, 0.01, t.size) / FS     # ±1 % jitter: fine
    assert sampling_rate(jittered) == pytest.approx(FS, rel=1e-2)
    gappy = np.delete(t, np.arange(500, 520))                # a 0.2 s gap
    with pytest.raises(ApmcalError, match="irregular"):
        highpass_t(gappy, np.zeros(gappy.size))
    back = t.copy()
    back[700] = back[698]
    with pytest.raises(ApmcalError, match="increasing"):
        sampling_rate(back)


def test_bad_values_raise():
    x = np.zeros(1000)
    x[10] = np.nan
    with pytest.raises(ApmcalError, match="NaN"):
        highpass(x, FS)
    with pytest.raises(ApmcalError, match="order"):
        highpass(np.zeros(1000), FS, order=0)
