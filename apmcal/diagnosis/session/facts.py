"""What a session offers the models, found once per evaluator: the Earth field at its site, the
noise of its samples, and the rounding lattice of each sensor (:class:`apmcal.diagnosis.scoring.evaluate.
Evaluator`)."""
from __future__ import annotations

import numpy as np

from apmcal.diagnosis.noise.fit import lattice_step


def earth_field(session) -> tuple[float | None, float]:
    """WMM field magnitude [mGauss] and declination [rad] at the site, when it is known.

    Returns
    -------
    field_mgauss : float or None
        None without a compass or a full site (latitude and longitude).
    declination_rad : float
        0 when the field is not known.
    """
    if session.mag is None or session.lat_deg is None or session.lon_deg is None:
        return None, 0.0
    import datetime

    from apmcal.core.geomag import decimal_year, earth_field_ned

    when = session.date or datetime.date.today()
    ned, _ = earth_field_ned(session.lat_deg, session.lon_deg, 0.0, decimal_year(when))
    return float(np.linalg.norm(ned)), float(np.arctan2(ned[1], ned[0]))


def sample_sigma(session) -> dict:
    """Per-sample noise of the accelerometer and compass in the holds (robust: successive
    differences, which cancel slow changes), to weight the move fits.

    Returns
    -------
    dict
        "acc" [m/s²] and, with a compass, "mag" [mGauss].
    """
    from apmcal.preprocessing.resolution import noise_std

    pc = session.pieces
    ids = pc.select(hold=True)
    out = {"acc": np.mean([noise_std(session.acc[a:b]) for a, b in zip(pc.i0[ids], pc.i1[ids])])}
    if session.mag is not None:
        m = session.mag
        out["mag"] = np.mean([noise_std(m.values[a:b]) for a, b in zip(m.i0[ids], m.i1[ids])
                              if b - a > 2])
    return {k: float(v) for k, v in out.items()}


def lattice_steps(session) -> dict:
    """Quantization step per axis of each sensor's hold samples (None: not on a lattice). In
    block means of rounded readings it is the step over the block length, which the twin's
    rounding then reproduces (apmcal.diagnosis.session.decimate).

    Returns
    -------
    dict
        "acc" [m/s²], "gyr" [rad/s] and, with a compass, "mag" [mGauss]: a (3,) array, or
        None unless all three axes are on a lattice.
    """
    pc = session.pieces
    ids = pc.select(hold=True)
    idx = np.concatenate([np.arange(a, b) for a, b in zip(pc.i0[ids], pc.i1[ids])])
    out = {}
    for sensor, x in (("acc", session.acc), ("gyr", session.gyr)):
        out[sensor] = _axis_steps(x[idx])
    if session.mag is not None:
        m = session.mag
        out["mag"] = _axis_steps(np.concatenate([m.values[a:b] for a, b in zip(m.i0[ids], m.i1[ids])]))
    return out


def _axis_steps(x: np.ndarray) -> np.ndarray | None:
    steps = [lattice_step(x[:, k]) for k in range(3)]
    return None if any(s is None for s in steps) else np.array(steps)
