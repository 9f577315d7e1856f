"""A calibration's findings in words: the solvers' numbers (:mod:`apmcal.solvers.report_types`)
turned into the report's lines.

:func:`calibration_lines` gives every line, in report order; :mod:`apmcal.report.text` prints the
technical ones only with --verbose (:func:`apmcal.report.text.is_technical`), and
:func:`verbose_lines` the specialist's extra figures (the six-face misfit, the Earth rate).
"""
from __future__ import annotations

import numpy as np

from apmcal.solvers.coverage import MIN_SCATTER_FULL
from apmcal.solvers.report_types import (
    CalibrationReport,
    Debias,
    EllipsoidFit,
    JointFit,
    MagneticField,
    MseScore,
    OnePositionFit,
)

UNEVEN_COVERAGE = 0.3      # smallest coverage eigenvalue below which the fit leans to one side
LARGE_RESIDUAL = 0.05      # robust σ of |calibrated| above this share of the field
MANY_OUTLIERS = 0.05       # share of samples beyond 5σ
POOR_OFFSET = 0.05         # offset 1σ above this share of the field
MIN_RESIDUAL_DOF = 10      # below this the residual-based sigma is itself uncertain by > 20 %
LEVEL_TOLERANCE_DEG = 5.0  # one-position hold tilted more than this: "NOT LEVEL"


def calibration_lines(report: CalibrationReport, sensors: dict) -> list[str]:
    """Every report line of a calibration, in order (``sensors``: name → SensorCalibration,
    whose offset σ the ellipsoid lines quote).

    Parameters
    ----------
    report : CalibrationReport
    sensors : dict
        name → SensorCalibration.

    Returns
    -------
    list of str
    """
    lines: list[str] = []
    if report.one_position is not None:
        lines += one_position_lines(report.one_position)
    if "acc" in report.ellipsoids:
        lines += ellipsoid_lines("acc", report.ellipsoids["acc"], _offset_sigma(sensors, "acc"))
    if report.gyro_offset_only:
        lines.append("gyr: offset only (mean at rest, [Niespodziany] §VIII); scale and cross-axis need "
                     "known rotations")
    if report.magnetic_field is not None:
        lines.append(field_line(report.magnetic_field))
    if report.joint is not None:
        lines += joint_lines(report.joint)
    if "mag" in report.ellipsoids:
        lines += ellipsoid_lines("mag", report.ellipsoids["mag"], _offset_sigma(sensors, "mag"))
    return lines


def _offset_sigma(sensors: dict, name: str):
    cal = sensors.get(name)
    return None if cal is None else cal.sigma.get("offset")


def field_line(f: MagneticField) -> str:
    """The field magnitude [mGauss] the compass was scaled to, where it came from, and what
    that means for the soft-iron matrix's overall gain."""
    if f.sigma_mgauss:
        return (f"mag: field magnitude {f.mgauss:.1f} ± {f.sigma_mgauss:.2g} mGauss from "
                f"{f.source} (the model's own uncertainty, carried into the matrix's ±)")
    return (f"mag: field magnitude {f.mgauss:.1f} mGauss from {f.source}: the matrix's overall "
            "gain is the readings' own, as ArduPilot's compass calibration without a position; "
            "--lat/--lon scale it to the Earth's field")


# --------------------------------------------------------------------------- ellipsoid fits
def ellipsoid_lines(sensor: str, fit: EllipsoidFit, offset_sigma=None) -> list[str]:
    """Plain-words judgement of an ellipsoid fit, one line per finding: coverage, residuals,
    offset σ (``offset_sigma`` (3,), sensor units), the fit's notes, its scores.

    Parameters
    ----------
    sensor : str
        "acc" or "mag", the lines' prefix.
    fit : EllipsoidFit
    offset_sigma : (3,) array, optional
        One-sigma of the offset [sensor units].

    Returns
    -------
    list of str
    """
    r = fit.radius
    lines = []
    if fit.coverage is not None:
        eig = np.asarray(fit.coverage.eigenvalues)
        lines.append(f"{sensor}: {fit.samples} samples, directions cover "
                     f"{100 * fit.coverage.fraction:.0f}% of the sphere (20° cones), coverage "
                     f"eigenvalues {np.array2string(eig, precision=2)} (1 = uniform)")
        if eig[0] < MIN_SCATTER_FULL:
            lines.append(f"{sensor}: POORLY DETERMINED — samples lie close to a plane or a few "
                         "directions; cross-axis terms (and the offset along the missing "
                         "direction) cannot be trusted: add orientations")
        elif eig[0] < UNEVEN_COVERAGE:
            lines.append(f"{sensor}: uneven coverage — the fit is weighted toward the densest "
                         "directions ([Niespodziany] §VII); more orientations would help")
    if fit.residuals is not None:
        e = fit.residuals
        lines.append(f"{sensor}: residual |calibrated| − {r:.4g}: RMS {e.rms:.4g} "
                     f"({100 * e.rms / r:.2f}% of the field), robust σ {e.robust_sigma:.4g}, "
                     f"{e.outliers} outliers (> 5σ)")
        if e.robust_sigma > LARGE_RESIDUAL * r:
            lines.append(f"{sensor}: LARGE RESIDUAL — motion during the static holds, a "
                         "disturbed field, or the wrong radius")
        if e.outliers > MANY_OUTLIERS * e.samples:
            lines.append(f"{sensor}: {100 * e.outliers / e.samples:.0f}% outliers — motion "
                         "during \"static\" samples or magnetic disturbances; check the data")
    if offset_sigma is not None:
        so = np.asarray(offset_sigma)
        lines.append(f"{sensor}: offset ± {np.array2string(so, precision=3)} (1σ)")
        if np.any(so > POOR_OFFSET * r):
            lines.append(f"{sensor}: POORLY DETERMINED offset (1σ > 5% of the field)")
    lines += [f"{sensor}: {n}" for n in fit.notes]
    lines += few_residuals_lines(sensor, fit.samples, fit.n_params)
    if fit.score is not None:
        lines.append(score_line(sensor, fit.score))
    if fit.debias is not None:
        lines.append(f"{sensor}: {debias_line(fit.debias)}")
    if fit.held_out is not None:
        lines.append(score_line(sensor, fit.held_out))
    return lines


def few_residuals_lines(sensor: str, n_samples: int, n_params: int | None) -> list[str]:
    """A warning when the sigmas rest on few residuals (e.g. 7 hold means, 6 parameters).

    A sigma estimated from k residual degrees of freedom is itself uncertain by about 1/√(2k).

    Parameters
    ----------
    sensor : str
    n_samples : int
        Residuals fitted.
    n_params : int or None
        Parameters fitted (None: no lines).

    Returns
    -------
    list of str
        Empty with ≥ ``MIN_RESIDUAL_DOF`` degrees of freedom.
    """
    if n_params is None:
        return []
    dof = n_samples - n_params
    if dof >= MIN_RESIDUAL_DOF:
        return []
    if dof <= 0:
        return [f"{sensor}: {n_samples} samples for {n_params} parameters: no residual is left "
                "to estimate the uncertainty; the sigmas are not meaningful (add holds)"]
    return [f"{sensor}: only {dof} residual degree(s) of freedom ({n_samples} samples, "
            f"{n_params} parameters): the sigmas are themselves uncertain by about "
            f"{100 / np.sqrt(2 * dof):.0f}% (add holds)"]


def score_line(sensor: str, s: MseScore) -> str:
    """[Niespodziany]'s relative MSE, raw → calibrated, and what it was scored on."""
    if s.failed:
        return (f"{sensor}: no held-out score: half of the samples is not enough for a fit of "
                f"its own ({s.failed})")
    on = (f"held-out samples (odd blocks of {s.blocks}, fitted on the even ones)"
          if s.blocks else f"{s.scored_on} samples")
    return (f"{sensor}: relative MSE of |calibrated| ([Niespodziany]) raw {s.raw:.3g} → "
            f"{s.calibrated:.3g} on {on}")


def debias_line(d: Debias) -> str:
    """The second-order bias the bootstrap removed from the compass fit (offset, matrix)."""
    return (f"second-order fit bias removed ({d.pairs} antithetic refit pairs): offset by "
            f"{np.array2string(np.asarray(d.offset_shift), precision=3)}, matrix by up to "
            f"{d.matrix_shift_max:.2g}")


# --------------------------------------------------------------------------- one position
def _e(v: float) -> str:
    return f"{v:.2e}"


def one_position_lines(fit: OnePositionFit) -> list[str]:
    """Plain-words notes on what [Oppong]'s one-position recipe did determine, then what the
    pose can identify (:mod:`apmcal.solvers.identifiability`)."""
    from apmcal.core.constants import MG_TO_MS2, MRAD_TO_RAD
    from apmcal.solvers.identifiability import identifiability

    a, w, lat = fit.acc, fit.gyr, fit.lat_deg
    lines = [
        f"acc: g taken as ‖mean‖ = {a.g:.4f} m/s² ([Oppong] §5.1 step 7), tilt from level "
        f"{a.tilt_deg:.2f}°",
        f"acc: high-pass mean R_f = {np.array2string(a.R_f, formatter={'float': _e})} m/s² "
        "≈ 0, so bias = "
        "R − R_f ≈ R: x/y bias is the mean itself (tilt and bias cannot be told apart: 1° of tilt "
        "= 0.17 m/s²), z bias ≈ 0 by construction",
        f"acc: β, γ, μ = {np.array2string(a.beta_gamma_mu, precision=4)}: μ = 1 − R_fz/g ≈ 1 by "
        f"construction, β, γ = −R_f/g ≈ 0; read literally (a_s = step-3 R) μ would be "
        f"{a.mu_literal:.3g} (singular F)",
    ]
    if a.tilt_deg > LEVEL_TOLERANCE_DEG:
        lines.append(f"acc: NOT LEVEL ({a.tilt_deg:.1f}° > {LEVEL_TOLERANCE_DEG}°): the method "
                     "assumes a level platform; its bias absorbs the tilt")
    lines.append(f"gyr: bias = {np.array2string(w.bias * 1e3, precision=3)} mrad/s "
                 "(≈ mean: the high-pass mean is ≈ 0)")
    if w.tau_xi_nu is not None:
        lines.append(f"gyr: τ, ξ, ν = {np.array2string(w.tau_xi_nu, precision=4)} at latitude "
                     f"{lat:.3f}°: τ ≈ cot(latitude) = {1 / np.tan(np.radians(lat)):.4f}, "
                     "ν ≈ R_fz/ω_D — artefacts of the recipe, not gyro properties")
    else:
        lines.append("gyr: no latitude: E not computed")
    lines.append("gyr: gyro matrix left at identity: one pose cannot determine it (E is "
                 "reported, not applied)")
    lines += identifiability("acc", [[0.0, 0.0, -a.g]], matrix="upper",
                             resolution=MG_TO_MS2).lines
    if w.omega_p is not None:
        lines += identifiability("gyr", [w.omega_p], matrix="upper", resolution=MRAD_TO_RAD).lines
    return lines


# --------------------------------------------------------------------------- joint
def joint_lines(j: JointFit) -> list[str]:
    """[Chow]'s joint fit: conditions, noise scales, parameters estimated, what ArduPilot
    cannot hold."""
    dropped = (f"; insignificant at 95 % (t-test, fixed to nominal and refitted): "
               f"{', '.join(j.dropped_t_test)}" if j.dropped_t_test else "")
    if j.fallback:
        return ["joint ([Chow]): fit not used, " + j.fallback] + _joint_fit_lines(j)
    return [
        "joint ([Chow]): " + ", ".join(f"{k} {n}" + (f" ({j.rejected[k]} rejected)"
                                                       if j.rejected.get(k) else "")
                                         for k, n in j.conditions.items()) + " conditions",
        "joint: noise scale per family (1 = the still periods' white noise, never less) "
        + ", ".join(f"{k} {v:.2f}" for k, v in j.noise_scale.items() if k != "mag_datum"),
        f"joint: {j.n_estimated} of {j.n_params} parameters estimated{dropped}",
        f"joint: gyro scale/misalignment cannot be held by ArduPilot (INS_GYROFFS only): "
        f"left uncorrected it costs up to {j.gyr_matrix_cost_deg_per_turn:.2f}° per 360° turn",
        f"joint: gyro g-sensitivity cannot be held either: up to "
        f"{j.gyr_g_sensitivity_at_1g:.2g} rad/s at 1 g",
    ] + _joint_fit_lines(j) + _joint_input_lines(j)


def _joint_fit_lines(j: JointFit) -> list[str]:
    """How the joint fit went: passes, whether they settled, and how well its result and its
    start (the ellipsoid and static results) explain the session's conditions."""
    if not j.passes:
        return []
    lines = [f"joint: {j.passes} passes, "
             + ("converged" if j.converged else "stopped at the pass limit before settling")]
    if j.clipped_turns:
        lines.append(f"joint: {j.clipped_turns} turn(s) left out: the gyro or accelerometer was "
                     f"at its range limit in them (turn more slowly)")
    if j.explained:
        lines.append("joint: median misclosure in units of the still periods' noise, start → "
                     "fit: " + ", ".join(f"{k} {a:.3g} → {b:.3g}"
                                         for k, (a, b) in j.explained.items()))
    return lines


def _joint_input_lines(j: JointFit) -> list[str]:
    """What the joint fit ran on: block means of a faster recording; the compass's own fit."""
    lines = []
    if j.block_samples > 1 and j.recorded_rate_hz:
        lines.append(f"joint: samples averaged in blocks of {j.block_samples} "
                     f"({j.recorded_rate_hz:.0f} → {j.recorded_rate_hz / j.block_samples:.0f} Hz)"
                     " to bound the fit's cost")
    if j.compass_own_fit:
        lines.append("mag: from its own ellipsoid fit over every sample; the joint fit's compass "
                     "(consistent only within its windows) served the gyro")
    return lines


# --------------------------------------------------------------------------- verbose extras
def verbose_lines(report: CalibrationReport) -> list[str]:
    """The specialist's extra figures: the six-face model's misfit and the noise-only σ it
    widened, and the Earth rate left in the gyro bias."""
    lines = []
    six = report.six_face
    if six is not None:
        m = six.misfit
        lines.append(f"acc: six-face model against {m.n_holds} holds: χ² {m.chi2:.1f} on "
                     f"{m.dof} checks (Birge ratio {m.birge_ratio:.2f}), largest residual "
                     f"{m.worst:.4f} m/s²; extra scatter per hold {_vector(m.tau, '.2g')}, "
                     f"offset spread {_vector(m.offset_spread, '.2g')} m/s²")
        noise_only = six.sigma_noise_only.get("offset")
        if noise_only is not None:
            lines.append(f"acc: offset ± from the noise alone {_vector(noise_only, '.2g')} m/s² "
                         "(before the misfit)")
    turns = report.gyro_turns
    if turns is not None and turns.earth_rate_left is not None:
        lines.append(f"gyr: Earth rate: vertical component Ω sin φ removed; horizontal Ω cos φ "
                     f"= {turns.earth_rate_left:.3g} rad/s needs the heading and stays in the "
                     "bias")
    return lines


def _vector(values, fmt: str) -> str:
    """``(a, b, c)`` with each value in ``fmt``."""
    return "(" + ", ".join(format(v, fmt) for v in np.ravel(values)) + ")"
