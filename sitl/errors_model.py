"""Streaming IMU error model: true board-frame motion in, raw sensor samples out.

Per sample at the internal rate fs (1 kHz like the MPU-6000 on APM 2.x), in the SENSOR frame:

accelerometer  s = F_a·f(t − τ) + k2_a ⊙ (F_a f)² + b_a + c_a·ΔT + n_a
gyroscope      w = F_g·ω + k2_g ⊙ (F_g ω)² + b_g + b1·t + rw(t) + G·f + c_g·ΔT + n_g
magnetometer   m = S·B_board + h + i·throttle + n_m

then for acc/gyro the on-chip 20 Hz 2nd-order Butterworth low-pass (MPU-6000 DLPF, INS_MPU6K_FILTER
on APM 2.x) and the ADC quantization (4096 LSB/g, 16.4 LSB/(°/s), with range saturation).
F_a, F_g, S come from :class:`sitl.truth.Truth`; every term is switchable by effect name.
Noise: white with one-sided density N, so σ per sample = N·√(fs/2). Each random term has its own
seeded generator so the output does not depend on how time is chunked.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import butter, lfilter, lfilter_zi

from sitl.truth import Truth

DEG = np.pi / 180.0


class ImuErrorModel:
    """Applies a :class:`Truth` to true motion, sample block by sample block.

    Parameters
    ----------
    truth : Truth
    fs : float
        Internal sample rate [Hz].
    seed : int
        Seeds the noise / random-walk generators (independent of the truth draw).
    """

    def __init__(self, truth: Truth, fs: float = 1000.0, seed: int = 0):
        self.truth, self.fs = truth, fs
        ss = np.random.SeedSequence([seed, 0xE220])
        self.rng = {k: np.random.default_rng(s) for k, s in
                    zip(("acc", "gyro", "rw", "mag"), ss.spawn(4))}
        self.f_acc, self.f_gyr, self.s_mag = truth.acc_forward(), truth.gyro_forward(), truth.mag_forward()
        self.rw_state = np.zeros(3)
        self.b, self.a = butter(2, truth.lowpass_hz / (fs / 2))
        self.zi = {"acc": None, "gyro": None}

    # ---- helpers ---------------------------------------------------------------------------
    def temperature(self, t: np.ndarray) -> np.ndarray:
        """Board temperature [°C]: warm-up curve T_amb + ΔT(1 − e^(−t/τ)) (constant when off)."""
        p = self.truth.temperature
        if not self.truth.on("temperature_drift"):
            return np.full(np.shape(t), p["ambient_c"], dtype=float)
        return p["ambient_c"] + p["rise_k"] * (1 - np.exp(-np.asarray(t) / p["tau_s"]))

    def _lowpass(self, key: str, x: np.ndarray) -> np.ndarray:
        if not self.truth.on("lowpass_filter"):
            return x
        if self.zi[key] is None:  # start settled on the first sample (sensor powered long ago)
            self.zi[key] = lfilter_zi(self.b, self.a)[:, None] * x[0][None, :]
        y, self.zi[key] = lfilter(self.b, self.a, x, axis=0, zi=self.zi[key])
        return y

    def _quantize(self, x: np.ndarray, lsb: float, full_scale: float) -> np.ndarray:
        """ADC counts: round to 1/lsb steps, saturate at ± full scale (sensor units)."""
        if not self.truth.on("quantization"):
            return x
        return np.clip(np.round(x * lsb), -32768, 32767).clip(-full_scale * lsb,
                                                                full_scale * lsb) / lsb

    # ---- the three sensors -------------------------------------------------------------------
    def accel(self, t: np.ndarray, f_board: np.ndarray) -> np.ndarray:
        """Raw accelerometer [m/s², sensor frame] from true specific force f(t − τ) [m/s², board]."""
        tr = self.truth
        s = f_board @ self.f_acc.T
        if tr.on("scale_nonlinearity"):
            s = s + np.asarray(tr.scale_nonlinearity["acc"]) * s ** 2
        if tr.on("acc_bias"):
            s = s + np.asarray(tr.acc_bias)
        if tr.on("temperature_drift"):
            dt = self.temperature(t) - tr.temperature["ambient_c"]
            s = s + np.outer(dt, tr.temperature["acc_coef"])
        if tr.on("acc_noise"):
            s = s + self.rng["acc"].standard_normal(s.shape) * tr.acc_noise * np.sqrt(self.fs / 2)
        s = self._lowpass("acc", s)
        g0 = 9.80665
        q = tr.quantization
        return self._quantize(s, q["acc_lsb_per_g"] / g0, q["acc_range_g"] * g0)

    def gyro(self, t: np.ndarray, w_board: np.ndarray, f_board: np.ndarray) -> np.ndarray:
        """Raw gyroscope [rad/s, sensor frame] from true rate [rad/s] and specific force, board."""
        tr = self.truth
        w = w_board @ self.f_gyr.T
        if tr.on("scale_nonlinearity"):
            w = w + np.asarray(tr.scale_nonlinearity["gyro"]) * w ** 2
        if tr.on("gyro_bias"):
            w = w + np.asarray(tr.gyro_bias)
        if tr.on("gyro_bias_drift"):
            w = w + np.outer(t, tr.gyro_bias_drift)          # seed 002 eq. 5: b0 + b1·t
        if tr.on("gyro_bias_random_walk"):
            steps = self.rng["rw"].standard_normal(w.shape) * tr.gyro_bias_random_walk / np.sqrt(self.fs)
            walk = self.rw_state + np.cumsum(steps, axis=0)
            self.rw_state = walk[-1].copy()
            w = w + walk
        if tr.on("g_sensitivity"):
            w = w + f_board @ np.asarray(tr.g_sensitivity).T
        if tr.on("temperature_drift"):
            dt = self.temperature(t) - tr.temperature["ambient_c"]
            w = w + np.outer(dt, tr.temperature["gyro_coef"])
        if tr.on("gyro_noise"):
            w = w + self.rng["gyro"].standard_normal(w.shape) * tr.gyro_noise * np.sqrt(self.fs / 2)
        w = self._lowpass("gyro", w)
        q = tr.quantization
        return self._quantize(w, q["gyro_lsb_per_dps"] / DEG, q["gyro_range_dps"] * DEG)

    def mag(self, b_board: np.ndarray, throttle: np.ndarray) -> np.ndarray:
        """Raw magnetometer [mGauss, sensor frame] from the true field [mGauss, board frame]."""
        tr = self.truth
        m = b_board @ self.s_mag.T
        if tr.on("mag_hard_iron"):
            m = m + np.asarray(tr.mag_hard_iron)
        if tr.on("mag_interference"):
            m = m + np.outer(throttle, tr.mag_interference)
        if tr.on("mag_noise"):
            m = m + self.rng["mag"].standard_normal(m.shape) * tr.mag_noise
        return m
