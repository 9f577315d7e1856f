"""Oppong et al.'s one-minute, one-position static calibration ([Oppong] §5), reproduced as written.

The platform is level, x pointing north, z down ([Oppong] §3.2), so body = NED.

Sign convention (document of the mapping). The paper writes the accelerometer input as the
gravity vector ``a_p = (0, 0, g)`` in a z-down frame and fixes the diagonal constants of F at −1
("the value 1 ... leads to inversion of the x- and y-inputs to the accelerometer, hence they are
negated", [Oppong] §6.2; its Table 4 shows F ≈ −I). ArduPilot's accelerometer measures specific
force: level and still it reads (0, 0, −g) (ardupilot-facts.md, "Frames and signs"). We use
``a_p = (0, 0, −g)`` (specific force, FRD) with diagonal constants +1: the same equations with
F_ours = −F_paper, and the calibrated output stays in ArduPilot's convention.
Step 2 ("the norm of the mean is subtracted from the z output") removes the gravity reading from
z: for ArduPilot's z ≈ −g that means adding ‖mean‖ (we subtract sign(mean_z)·‖mean‖).

Degeneracies of the paper's recipe, reported to the user (in words by
:func:`apmcal.report.lines.one_position_lines`):

* A zero-phase high-pass of a static signal has mean ≈ 0, so ``R_f ≈ 0`` and the bias
  ``b = R − R_f ≈ R``: x/y bias = the mean itself (a tilt of θ reads as g·sin θ bias, 1° ≈
  0.17 m/s²), z bias ≈ (m_x² + m_y²)/(2g) ≈ 0 by construction.
* Read literally (a_s = R of step 3), step 9 gives ``F·a_p = R_f`` → μ = R_fz/g ≈ 0 (singular F).
  Table 4's μ = −1.000 is only reproduced with a_s = the step-1 mean, which we use; the literal μ
  is kept in the report. With g := ‖mean‖ (step 7) this makes μ = 1 − R_fz/g ≈ 1 and
  β, γ = −R_fx/g, −R_fy/g ≈ 0 by construction: F ≈ I whatever the sensor.
* Gyroscope: ``E·ω_p = R_f`` with ω_p = Ω(cos φ, 0, −sin φ): τ = (R_fx − Ω cos φ)/(−Ω sin φ) ≈
  cot φ, ξ ≈ R_fy/ω_D, ν ≈ R_fz/ω_D ≈ 0 — Table 2's τ = 8.5258 is cot(6.7°), Kumasi's latitude.
  The Earth rate (0.073 mrad/s) is below RAW_IMU's 1 mrad/s step (ardupilot-facts.md), so E is
  not determinable; see :mod:`apmcal.solvers.identifiability`.
"""
from __future__ import annotations

import numpy as np

from apmcal.core.constants import EARTH_RATE
from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.highpass import highpass  # zero-phase Butterworth ([Oppong] §5)
from apmcal.solvers.report_types import (
    CalibrationReport,
    OnePositionAcc,
    OnePositionFit,
    OnePositionGyr,
)
from apmcal.solvers.result import Calibration, SensorCalibration


def c_ecef_to_ned(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Direction-cosine matrix ECEF → NED ([Oppong] §5.2, 'C_ecef^ned').

    Parameters
    ----------
    lat_deg, lon_deg : float
        Position [deg].

    Returns
    -------
    (3, 3) array
    """
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    sla, cla, slo, clo = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    return np.array([[-sla * clo, -sla * slo, cla],
                     [-slo, clo, 0.0],
                     [-cla * clo, -cla * slo, -sla]])


def _sample_rate(t: np.ndarray) -> float:
    dt = np.diff(np.asarray(t, dtype=float))
    if len(dt) == 0 or not np.all(np.isfinite(dt)) or np.median(dt) <= 0:
        raise ApmcalError("one-position method: sample times must be finite and increasing")
    return float(1.0 / np.median(dt))


def accelerometer_one_position(acc: np.ndarray, fs: float, cutoff_hz: float = 0.5
                               ) -> tuple[SensorCalibration, OnePositionAcc]:
    """[Oppong] §5.1 steps 1-9 on level, still specific-force samples (n, 3) [m/s², body FRD].

    Returns the SensorCalibration (offset = b, matrix = F⁻¹) and the intermediate quantities.

    Parameters
    ----------
    acc : (n, 3) array
        Specific force [m/s²], body FRD, level and still.
    fs : float
        Sample rate [Hz].
    cutoff_hz : float
        High-pass cut-off [Hz].

    Returns
    -------
    SensorCalibration
        offset b (3,) [m/s²], matrix F⁻¹ (3, 3); no sigma.
    OnePositionAcc
        The intermediate quantities.
    """
    m = acc.mean(axis=0)                                   # step 1
    norm = float(np.linalg.norm(m))
    sgn = -1.0 if m[2] < 0 else 1.0                        # ArduPilot level: m_z ≈ −g
    acc2 = acc.copy()
    acc2[:, 2] -= sgn * norm                               # step 2 (gravity reading removed)
    R = acc2.mean(axis=0)                                  # step 3
    Rf = highpass(acc2, fs, cutoff_hz).mean(axis=0)        # steps 4-5
    b = R - Rf                                             # step 6: eq. (1), F = I, a_p = R_f
    g = norm                                               # step 7: g := ‖mean‖
    a_p = np.array([0.0, 0.0, sgn * g])                    # specific force (see module doc)
    # steps 8-9: F = [[1, 0, β], [0, 1, γ], [0, 0, μ]] (α = 0); a_s − b = F·a_p, a_s = step-1 mean
    beta, gamma, mu = (m - b) / a_p[2]
    F = np.array([[1.0, 0.0, beta], [0.0, 1.0, gamma], [0.0, 0.0, mu]])
    mu_literal = (R - b)[2] / a_p[2]                       # a_s = step-3 R read literally
    tilt = float(np.degrees(np.arccos(min(1.0, abs(m[2]) / norm)))) if norm > 0 else 90.0
    sc = SensorCalibration(offset=b, matrix=np.linalg.inv(F))
    return sc, OnePositionAcc(mean=m, g=g, R=R, R_f=Rf, bias=b, F=F,
                              beta_gamma_mu=np.array([beta, gamma, mu]),
                              mu_literal=float(mu_literal), F_paper_convention=-F, tilt_deg=tilt)


def gyroscope_one_position(gyr: np.ndarray, fs: float, cutoff_hz: float = 0.5,
                           lat_deg: float | None = None, lon_deg: float | None = None
                           ) -> tuple[SensorCalibration, OnePositionGyr]:
    """[Oppong] §5.2 on still gyro samples (n, 3) [rad/s], x north, z down.

    Returns SensorCalibration (offset = b, matrix = I) and the intermediate quantities. The
    paper's E is computed and reported but never applied: its terms are set by the Earth rate
    and the latitude, not by the gyro (module docstring), so E⁻¹ would distort every reading.

    Parameters
    ----------
    gyr : (n, 3) array
        Angular rate [rad/s], still, x north, z down.
    fs : float
        Sample rate [Hz].
    cutoff_hz : float
        High-pass cut-off [Hz].
    lat_deg, lon_deg : float, optional
        Position [deg]; without the latitude E is not computed.

    Returns
    -------
    SensorCalibration
        offset b (3,) [rad/s], identity matrix, sigma["offset"] (3,) [rad/s].
    OnePositionGyr
        The intermediate quantities.

    Raises
    ------
    ApmcalError
        At the equator (E undefined).
    """
    R = gyr.mean(axis=0)                                   # mean
    Rf = highpass(gyr, fs, cutoff_hz).mean(axis=0)         # high-pass mean
    b = R - Rf                                             # eq. (2) with E = I
    out = OnePositionGyr(R=R, R_f=Rf, bias=b)
    if lat_deg is not None:
        C = c_ecef_to_ned(lat_deg, 0.0 if lon_deg is None else lon_deg)
        w_p = C @ np.array([0.0, 0.0, EARTH_RATE])         # = Ω(cos φ, 0, −sin φ), any longitude
        if abs(w_p[2]) < 1e-12:
            raise ApmcalError("one-position gyro: at the equator the Earth rate has no vertical "
                              "component, τ, ξ, ν are undefined ([Oppong] §5.2)")
        # E = [[1, 0, τ], [0, 1, ξ], [0, 0, ν]] (σ = 0); ω_s − b = E·ω_p with ω_s = R
        d = R - b
        tau = (d[0] - w_p[0]) / w_p[2]
        xi = (d[1] - w_p[1]) / w_p[2]
        nu = d[2] / w_p[2]
        E = np.array([[1.0, 0.0, tau], [0.0, 1.0, xi], [0.0, 0.0, nu]])
        out.omega_p, out.E, out.tau_xi_nu = w_p, E, np.array([tau, xi, nu])
    # white-noise standard error of the mean; the resolution floor is added by the pipeline
    sigma = {"offset": gyr.std(axis=0, ddof=1) / np.sqrt(len(gyr))}
    return SensorCalibration(offset=b, matrix=np.eye(3), sigma=sigma), out


def one_position_calibration(t, acc, gyr, *, lat_deg: float | None = None,
                             lon_deg: float | None = None, cutoff_hz: float = 0.5,
                             fs: float | None = None) -> Calibration:
    """The one-minute static calibration of [Oppong] §5 → Calibration (method "static").

    Parameters
    ----------
    t : (n,) array [s]
    acc : (n, 3) array [m/s²]
        Body FRD, vehicle level and still (ArduPilot: z ≈ −g).
    gyr : (n, 3) array [rad/s]
        Same samples, x pointing north.
    lat_deg, lon_deg : float, optional
        Position ([Oppong] uses GPS); only latitude matters for the Earth-rate vector.
    cutoff_hz : float
        High-pass cut-off ([Oppong]: 0.5 Hz, from Lötters et al.).
    fs : float, optional
        Sample rate [Hz]; from ``t`` when omitted.

    Returns
    -------
    Calibration
        Method "static": sensors "acc" and "gyr", report with the OnePositionFit.

    Raises
    ------
    ApmcalError
        On mismatched shapes, non-finite samples, bad sample times, too short a record for the
        high-pass, or the equator.
    """
    t = np.asarray(t, dtype=float)
    acc = np.asarray(acc, dtype=float)
    gyr = np.asarray(gyr, dtype=float)
    if acc.ndim != 2 or acc.shape[1] != 3 or gyr.shape != acc.shape or len(t) != len(acc):
        raise ApmcalError(f"one-position method: t {t.shape}, acc {acc.shape}, gyr {gyr.shape} "
                          "must be (n,), (n, 3), (n, 3)")
    if not (np.all(np.isfinite(acc)) and np.all(np.isfinite(gyr))):
        raise ApmcalError("one-position method: NaN or inf in the samples")
    fs = _sample_rate(t) if fs is None else float(fs)
    if len(t) <= 3 * fs / cutoff_hz:      # highpass pads three cut-off periods
        raise ApmcalError(f"one-position method: {len(t)} samples at {fs:.3g} Hz is too short for "
                          f"a {cutoff_hz} Hz high-pass ([Oppong] records about a minute)")
    acc_cal, a = accelerometer_one_position(acc, fs, cutoff_hz)
    gyr_cal, w = gyroscope_one_position(gyr, fs, cutoff_hz, lat_deg, lon_deg)
    fit = OnePositionFit(acc=a, gyr=w, fs_hz=fs, duration_s=float(t[-1] - t[0]),
                         cutoff_hz=cutoff_hz, lat_deg=lat_deg)
    return Calibration(method="static", sensors={"acc": acc_cal, "gyr": gyr_cal},
                       report=CalibrationReport(one_position=fit))
