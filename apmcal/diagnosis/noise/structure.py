"""The noise structure of the hold residuals, real against twin: white noise, bias instability
and rate random walk per sensor axis (IEEE Std 952 terms).

Each side's terms come from the GMWM fit of :mod:`apmcal.diagnosis.noise.terms` (components
chosen by its prediction criterion, with one-sigma uncertainties); the real side also gets the
reading Kalibr and allan_variance_ros make, fixed-slope lines on the Allan deviation, for
comparison. The residuals are the nominal model's, fitted on fold 0, over every hold piece.
The twin has white noise only, so a bias instability or random walk found in the real data and
not in the twin is structure the nominal model lacks.
"""
from __future__ import annotations

import numpy as np

from apmcal.diagnosis.noise.terms import fit_noise_terms, noise_terms_allan_lines

UNITS = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}
TERMS = ("white_density", "bias_instability", "random_walk")
MIN_PIECE = 64          # samples a piece needs to enter the wavelet variance


def _term(t) -> dict | None:
    return None if t is None else {"value": t.value, "sigma": t.sigma, "unit": t.unit}


def gmwm_terms(pieces: list, fs: float, unit: str) -> dict:
    """{term: {"value", "sigma", "unit"} or None} of one axis, and the components chosen.

    Parameters
    ----------
    pieces : list of 1-D arrays
        Hold residuals of one axis, piece by piece [unit].
    fs : float
        Sample rate [Hz].
    unit : str
        The residuals' unit, e.g. "rad/s".

    Returns
    -------
    dict
        "white_density" [unit/√Hz], "bias_instability" [unit], "random_walk" [unit/√s]
        (:func:`~apmcal.diagnosis.noise.terms.fit_noise_terms`) and "components"; or
        "not_fitted" with the reason.
    """
    try:
        fit = fit_noise_terms(pieces, fs, unit=unit)
    except ValueError as exc:            # too few scales (short or constant pieces)
        return {"not_fitted": str(exc)}
    out = {name: _term(getattr(fit, name)) for name in TERMS}
    out["components"] = list(fit.selected)
    return out


def allan_line_terms(pieces: list, fs: float, unit: str) -> dict:
    """The fixed-slope-line reading of one axis (values only: the method gives no σ).

    Parameters
    ----------
    pieces : list of 1-D arrays
        Hold residuals of one axis, piece by piece [unit].
    fs : float
        Sample rate [Hz].
    unit : str
        The residuals' unit.

    Returns
    -------
    dict
        "white_density" [unit/√Hz], "bias_instability" [unit], "random_walk" [unit/√s].
    """
    lines = noise_terms_allan_lines(pieces, fs)
    return {"white_density": {"value": lines.white_density, "unit": f"{unit}/√Hz"},
            "bias_instability": {"value": lines.bias_instability, "unit": unit},
            "random_walk": {"value": lines.random_walk, "unit": f"{unit}/√s"}}


def noise_structure(evaluation, fs_of: dict, parts=None) -> dict:
    """{sensor: {axis: {"real": terms, "twin": terms, "real_allan_lines": terms}}} of the
    hold residuals of ``evaluation`` (an :class:`~apmcal.diagnosis.scoring.evaluate.Evaluation`), of
    every sensor axis or of the (sensor, axis) pairs in ``parts`` (e.g. ("gyr", "x"))."""
    wanted = None if parts is None else {tuple(p) for p in parts}
    fold = evaluation.folds[0]
    twin_blocks = {c.block.names[0].split("_")[0]: c.block for c in fold.twin if c.block.shape}
    out = {}
    for coeffs in fold.real:
        block = coeffs.block
        sensor = block.names[0].split("_")[0]
        if not block.shape or sensor not in twin_blocks or \
                wanted is not None and not any(s == sensor for s, _ in wanted):
            continue
        out[sensor] = {}
        for axis, name in enumerate("xyz"):
            real = _pieces(block, axis)
            if not real or wanted is not None and (sensor, name) not in wanted:
                continue
            unit, fs = UNITS[sensor], fs_of[sensor]
            out[sensor][name] = {
                "real": gmwm_terms(real, fs, unit),
                "twin": gmwm_terms(_pieces(twin_blocks[sensor], axis), fs, unit),
                "real_allan_lines": allan_line_terms(real, fs, unit)}
    return out


def merged(parts: list[dict]) -> dict:
    """Noise structures of separate sensor axes (:func:`noise_structure` with ``parts``) as
    one, in the order given."""
    out: dict = {}
    for part in parts:
        for sensor, axes in part.items():
            out.setdefault(sensor, {}).update(axes)
    return out


def _pieces(block, axis: int) -> list[np.ndarray]:
    return [block.values[a:b, axis] for a, b in zip(block.i0, block.i1) if b - a >= MIN_PIECE]
