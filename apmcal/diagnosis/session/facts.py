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
    rounding then reproduces (apmcal.diagnosis.session.decimate). A sensor the log stores as
    integers has the format's step (``session.resolution``) even where its samples hardly
    change (a gyro at rest under a 1 mrad/s step: too few differences to see a lattice in).

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
    for sensor, step in getattr(session, "resolution", {}).items():
        if out.get(sensor) is None and sensor in out:
            out[sensor] = np.full(3, float(step))
    return out


FLOAT32_SPACING = 2.0 ** -23    # a float32's spacing relative to its leading power of two


def variance_floors(session, steps: dict) -> dict:
    """The smallest variance [unit²] a Haar coefficient of each channel can be told to have:
    the rounding of its readings, step²/12 per coefficient (the Haar transform is orthonormal,
    so white rounding noise of variance step²/12 per sample has it at every level and in the
    piece means). The step is the sensor's lattice (``steps``, :func:`lattice_steps`), or the
    spacing of a float32 (dataflash stores floats) at the largest reading of the axis — both
    for the real readings and for the twin, which is rounded the same way. A variance below
    that is the rounding's, not the sensor's, and a ratio of two such variances is noise: a
    twin whose reading does not change in a cell would otherwise have a variance of zero and
    a gap of 1e+293.

    Parameters
    ----------
    session : Session
    steps : dict
        Lattice step per axis of each sensor, (3,) or None.

    Returns
    -------
    dict
        {channel ("acc_x", ..., "mag_z", and "acc_norm", "mag_norm" for the piece means along
        the field): variance floor [unit²]}.
    """
    samples = {"acc": session.acc, "gyr": session.gyr}
    if session.mag is not None:
        samples["mag"] = session.mag.values
    out = {}
    for sensor, x in samples.items():
        top = np.max(np.abs(x), axis=0) if len(x) else np.zeros(3)
        spacing = FLOAT32_SPACING * 2.0 ** np.floor(np.log2(np.maximum(top, 1e-30)))
        step = steps.get(sensor)
        step = np.maximum(spacing, step) if step is not None else spacing
        floors = step ** 2 / 12.0
        for axis, floor in zip("xyz", floors):
            out[f"{sensor}_{axis}"] = float(floor)
        out[f"{sensor}_norm"] = float(np.mean(floors))
    return out


def _axis_steps(x: np.ndarray) -> np.ndarray | None:
    steps = [lattice_step(x[:, k]) for k in range(3)]
    return None if any(s is None for s in steps) else np.array(steps)
