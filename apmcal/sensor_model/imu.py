"""Streaming IMU error model: true board-frame motion in, raw sensor samples out.

Per sample at the model rate fs (1 kHz like the MPU-6000 on APM 2.x inside :class:`SimVehicle`;
any rate works, e.g. a real log's 50-400 Hz for a twin), in the SENSOR frame:

accelerometer  s = F_a·f(t − τ) + k2_a ⊙ (F_a f)² + b_a + c_a·ΔT + n_a
gyroscope      w = F_g·ω + k2_g ⊙ (F_g ω)² + b_g + b1·t + rw(t) + d_tri(t)·[1 1 1] + G·f
                   + c_g·ΔT + n_g
magnetometer   m = S·B_board + h + i·throttle + n_m

then for acc/gyro the on-chip 2nd-order Butterworth low-pass (MPU-6000 DLPF at 20 Hz,
INS_MPU6K_FILTER on APM 2.x; ``lowpass_hz`` a float or per sensor) and the ADC quantization
(4096 LSB/g, 16.4 LSB/(°/s), with range saturation).
F_a, F_g, S come from :class:`apmcal.sensor_model.truth.Truth`; every term is switchable by effect name.

- ΔT = T − ``temperature["ambient_c"]``, T the warm-up curve :meth:`ImuErrorModel.temperature`
  or an explicit per-sample board temperature passed to :meth:`accel` / :meth:`gyro` (a twin
  passes the real log's temperatures).
- Noise n_a, n_g: white with one-sided density N, so σ per sample = N·√(fs/2) at any fs; n_m has
  σ = ``mag_noise`` per sample. Each of N, σ_m and the random-walk q (rw increments q·√dt) is a
  float or one value per sensor axis. Gaussian, or with ``uniform_noise`` on uniform in
  [−√3σ, √3σ] — the same σ (ArduPilot SITL's ``noise·rand_float()``).
- d_tri (``triangle_drift``, ArduPilot SITL's gyro_drift()): with P = 2·time_min [minutes] and
  u = fmod(t/60, P), d_tri = u·radians(speed) for u < P/2, else (P − u)·radians(speed) [rad/s],
  the same on all three axes (t = seconds since boot).
- The Butterworth low-pass needs its cutoff below the Nyquist frequency fs/2: a cutoff at or
  above it (a slow log rate) skips that sensor's filter, without error — the samples are then
  as if already filtered on the chip.
- Compass interference i is per unit throttle; :class:`SimVehicle` reports a battery current of
  ``FULL_THROTTLE_CURRENT_A`` (20 A) × throttle, so i = 20 × the per-amp coefficient.

Each random term has its own seeded generator so the output does not depend on how time is
chunked.
"""
from __future__ import annotations

import numpy as np

from apmcal.sensor_model.truth import Truth, per_axis

DEG = np.pi / 180.0
SQRT3 = np.sqrt(3.0)


class ImuErrorModel:
    """Applies a :class:`Truth` to true motion, sample block by sample block.

    Parameters
    ----------
    truth : Truth
    fs : float
        Model sample rate [Hz] (the rate of the samples passed in).
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
        # (b, a) per sensor; None: no filter (off, or cutoff at/above Nyquist)
        self.filters = {"acc": None, "gyro": None}
        if truth.on("lowpass_filter"):
            # scipy.signal only when a filter is on: its import (0.8 s) would otherwise delay
            # every program that simulates a sensor without one (apmcal gap's twins)
            from scipy.signal import butter

            for key in self.filters:
                wn = truth.lowpass_cutoff(key) / (fs / 2)
                self.filters[key] = butter(2, wn) if wn < 1 else None
        self.zi = {"acc": None, "gyro": None}

    # ---- helpers ---------------------------------------------------------------------------
    def temperature(self, t: np.ndarray) -> np.ndarray:
        """Board temperature [°C]: warm-up curve T_amb + ΔT(1 − e^(−t/τ)) (constant when off).

        With the optional ``temperature["cool_start_s"]`` = t_c the heating stops at t_c and
        the board cools back towards ambient with the same τ: T(t) = T_amb + (T(t_c) −
        T_amb)·e^(−(t − t_c)/τ) after t_c (a warm-up and cool-down, for held-out checks).
        """
        p = self.truth.temperature
        if not self.truth.on("temperature_drift"):
            return np.full(np.shape(t), p["ambient_c"], dtype=float)
        t = np.asarray(t, dtype=float)
        rise = p["rise_k"] * (1 - np.exp(-t / p["tau_s"]))
        t_cool = p.get("cool_start_s")
        if t_cool is not None:
            peak = p["rise_k"] * (1 - np.exp(-float(t_cool) / p["tau_s"]))
            cooling = peak * np.exp(-np.maximum(t - float(t_cool), 0.0) / p["tau_s"])
            rise = np.where(t > float(t_cool), cooling, rise)
        return p["ambient_c"] + rise

    def _delta_t(self, t: np.ndarray, temperature) -> np.ndarray:
        """ΔT [K] from ambient: of the explicit ``temperature`` series, else of the curve."""
        temp = self.temperature(t) if temperature is None else np.asarray(temperature, float)
        return np.broadcast_to(temp, np.shape(t)) - self.truth.temperature["ambient_c"]

    def _noise(self, key: str, shape: tuple, level: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """White noise of per-axis σ = level·scale: Gaussian, or uniform of the same σ
        (uniform_noise). Evaluated as draw·level·scale, in that order (bit-stable output)."""
        if self.truth.on("uniform_noise"):
            return self.rng[key].uniform(-SQRT3, SQRT3, shape) * level * scale
        return self.rng[key].standard_normal(shape) * level * scale

    def triangle_drift(self, t: np.ndarray) -> np.ndarray:
        """ArduPilot SITL gyro drift [rad/s] (n,) at t [s since boot] (zeros when off)."""
        t = np.asarray(t, float)
        if not self.truth.on("triangle_drift"):
            return np.zeros(np.shape(t))
        p = self.truth.triangle_drift
        period = 2.0 * float(p["time_min"])
        minutes = np.fmod(t / 60.0, period)
        ramp = np.where(minutes < period / 2, minutes, period - minutes)
        return ramp * np.radians(float(p["speed_dps_per_min"]))

    def _lowpass(self, key: str, x: np.ndarray) -> np.ndarray:
        if self.filters[key] is None:
            return x
        from scipy.signal import lfilter, lfilter_zi

        b, a = self.filters[key]
        if self.zi[key] is None:  # start settled on the first sample (sensor powered long ago)
            self.zi[key] = lfilter_zi(b, a)[:, None] * x[0][None, :]
        y, self.zi[key] = lfilter(b, a, x, axis=0, zi=self.zi[key])
        return y

    def _quantize(self, x: np.ndarray, lsb: float, full_scale: float) -> np.ndarray:
        """ADC counts: round to 1/lsb steps, saturate at ± full scale (sensor units); an lsb
        of 0 leaves this sensor unrounded (the other one may still be)."""
        if not self.truth.on("quantization") or not lsb > 0:
            return x
        return np.clip(np.round(x * lsb), -32768, 32767).clip(-full_scale * lsb,
                                                                full_scale * lsb) / lsb

    # ---- the three sensors -------------------------------------------------------------------
    def accel(self, t: np.ndarray, f_board: np.ndarray, temperature=None) -> np.ndarray:
        """Raw accelerometer [m/s², sensor frame] from true specific force f(t − τ) [m/s², board].

        ``temperature``: optional board temperature [°C] per sample (n,), used instead of the
        warm-up curve for temperature_drift.
        """
        tr = self.truth
        s = f_board @ self.f_acc.T
        if tr.on("scale_nonlinearity"):
            s = s + np.asarray(tr.scale_nonlinearity["acc"]) * s ** 2
        if tr.on("acc_bias"):
            s = s + np.asarray(tr.acc_bias)
        if tr.on("temperature_drift"):
            s = s + np.outer(self._delta_t(t, temperature), tr.temperature["acc_coef"])
        if tr.on("acc_noise"):
            s = s + self._noise("acc", s.shape, per_axis(tr.acc_noise, "acc_noise"),
                                np.sqrt(self.fs / 2))
        s = self._lowpass("acc", s)
        g0 = 9.80665
        q = tr.quantization
        return self._quantize(s, q["acc_lsb_per_g"] / g0, q["acc_range_g"] * g0)

    def gyro(self, t: np.ndarray, w_board: np.ndarray, f_board: np.ndarray,
             temperature=None) -> np.ndarray:
        """Raw gyroscope [rad/s, sensor frame] from true rate [rad/s] and specific force, board.

        ``temperature``: optional board temperature [°C] per sample (n,), used instead of the
        warm-up curve for temperature_drift.
        """
        tr = self.truth
        w = w_board @ self.f_gyr.T
        if tr.on("scale_nonlinearity"):
            w = w + np.asarray(tr.scale_nonlinearity["gyro"]) * w ** 2
        if tr.on("gyro_bias"):
            w = w + np.asarray(tr.gyro_bias)
        if tr.on("gyro_bias_drift"):
            w = w + np.outer(t, tr.gyro_bias_drift)          # [Oppong] eq. 5: b0 + b1·t
        if tr.on("gyro_bias_random_walk"):
            q = per_axis(tr.gyro_bias_random_walk, "gyro_bias_random_walk")
            steps = self.rng["rw"].standard_normal(w.shape) * q / np.sqrt(self.fs)
            walk = self.rw_state + np.cumsum(steps, axis=0)
            self.rw_state = walk[-1].copy()
            w = w + walk
        if tr.on("triangle_drift"):
            w = w + self.triangle_drift(t)[:, None]          # the same on all three axes
        if tr.on("g_sensitivity"):
            w = w + f_board @ np.asarray(tr.g_sensitivity).T
        if tr.on("temperature_drift"):
            w = w + np.outer(self._delta_t(t, temperature), tr.temperature["gyro_coef"])
        if tr.on("gyro_noise"):
            w = w + self._noise("gyro", w.shape, per_axis(tr.gyro_noise, "gyro_noise"),
                                np.sqrt(self.fs / 2))
        w = self._lowpass("gyro", w)
        q = tr.quantization
        return self._quantize(w, q["gyro_lsb_per_dps"] / DEG, q["gyro_range_dps"] * DEG)

    def mag(self, b_board: np.ndarray, throttle: np.ndarray) -> np.ndarray:
        """Raw magnetometer [mGauss, sensor frame] from the true field [mGauss, board frame].

        ``throttle`` (0..1) per sample drives mag_interference [mGauss per unit throttle]; the
        simulator's battery current is ``FULL_THROTTLE_CURRENT_A`` (20 A) × throttle, so a
        per-amp coefficient [mGauss/A] is ``mag_interference`` / 20.
        """
        tr = self.truth
        m = b_board @ self.s_mag.T
        if tr.on("mag_hard_iron"):
            m = m + np.asarray(tr.mag_hard_iron)
        if tr.on("mag_interference"):
            m = m + np.outer(throttle, tr.mag_interference)
        if tr.on("mag_noise"):
            m = m + self._noise("mag", m.shape, per_axis(tr.mag_noise, "mag_noise"))
        return m
