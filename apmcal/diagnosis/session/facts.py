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
    integers has the format's step (``session.resolution``), which the twin's formatting uses:
    also where its samples hardly change (a gyro at rest under a 1 mrad/s step: too few
    differences to see a lattice in), and where they only move between 0 and ±1.5 steps (an
    accelerometer at rest whose noise hardly reaches a step, truncated and moved half a step
    out: its smallest difference is 1.5 steps).

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
        if sensor in out and (out.get(sensor) is None or sensor in session.integer_sensors):
            out[sensor] = session.format_of(sensor)[1] if sensor in session.integer_sensors \
                else np.full(3, float(step))
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
    a gap of 1e+293. The piece means add the rounding errors of a piece's samples up, and
    where the readings are not dithered they do so coherently: their floor is raised by
    :func:`coherent_runs` (the channel's name + :data:`MEANS`).

    Parameters
    ----------
    session : Session
    steps : dict
        Lattice step per axis of each sensor, (3,) or None.

    Returns
    -------
    dict
        {channel ("acc_x", ..., "mag_z", and "acc_norm", "mag_norm" for the piece means along
        the field), and each channel + :data:`MEANS` for its piece means: variance floor
        [unit²]}.
    """
    pc = session.pieces
    ids = pc.select(hold=True)
    samples = {"acc": (session.acc, pc.i0[ids], pc.i1[ids]),
               "gyr": (session.gyr, pc.i0[ids], pc.i1[ids])}
    if session.mag is not None:
        samples["mag"] = (session.mag.values, session.mag.i0[ids], session.mag.i1[ids])
    out = {}
    for sensor, (x, i0, i1) in samples.items():
        top = np.max(np.abs(x), axis=0) if len(x) else np.zeros(3)
        spacing = FLOAT32_SPACING * 2.0 ** np.floor(np.log2(np.maximum(top, 1e-30)))
        step = steps.get(sensor)
        step = np.maximum(spacing, step) if step is not None else spacing
        floors = step ** 2 / 12.0
        coherent = floors * coherent_runs(x, i0, i1)
        for axis, floor, means in zip("xyz", floors, coherent):
            out[f"{sensor}_{axis}"] = float(floor)
            out[f"{sensor}_{axis}{MEANS}"] = float(means)
        out[f"{sensor}_norm"] = float(np.mean(floors))
        out[f"{sensor}_norm{MEANS}"] = float(np.mean(coherent))
    return out


MEANS = ":means"    # suffix of a channel's floor for its piece means (variance_floors)


def coherent_runs(x: np.ndarray, i0: np.ndarray, i1: np.ndarray) -> np.ndarray:
    """How many samples' rounding errors a piece mean adds up coherently, per axis: the mean
    over the pieces ``[i0, i1)`` of Σ L²/n, the L the lengths of the runs of equal readings in
    a piece of n samples.

    The rounding error of a reading is white only where noise of a step or more dithers it;
    a reading that stays on one lattice value for a run of L samples carries one error for all
    of them (the signal moves less than a step meanwhile), and √n times the piece mean (the
    Haar piece-mean coefficient) then holds that error L/√n times per run: its variance is
    Σ L²/n · Δ²/12 instead of Δ²/12. On an ArduPilot RAW_IMU gyro at rest (int16 mrad/s,
    noise a fifth of a step) a 30-s piece is one or two runs: differences between piece means
    far below a step are not what the readings show. Float readings, and readings dithered by
    their noise, change at (nearly) every sample: 1.

    Parameters
    ----------
    x : (n, 3) array
        Readings.
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces.

    Returns
    -------
    (3,) array
        ≥ 1 (1 without a piece).
    """
    factors = []
    for a, b in zip(i0, i1):
        if b - a < 1:
            continue
        change = np.diff(x[a:b], axis=0) != 0
        factors.append([_squared_runs(change[:, k]) / (b - a) for k in range(x.shape[1])])
    return np.maximum(np.mean(factors, axis=0), 1.0) if factors else np.ones(x.shape[1])


def _squared_runs(change: np.ndarray) -> float:
    """Σ L² of the runs a sequence of n samples splits into where ``change`` (n − 1,) is
    True (a new reading)."""
    edges = np.concatenate([[0], np.flatnonzero(change) + 1, [len(change) + 1]])
    return float(np.sum(np.diff(edges).astype(float) ** 2))


def _axis_steps(x: np.ndarray) -> np.ndarray | None:
    steps = [lattice_step(x[:, k]) for k in range(3)]
    return None if any(s is None for s in steps) else np.array(steps)
