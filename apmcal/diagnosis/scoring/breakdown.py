"""Where the gap lies: the same total split by sensor, axis, segment, frequency band, time,
temperature and scale. Every split adds up to the total, because each coefficient's share of
the gap (:class:`apmcal.diagnosis.scoring.gap.CellShare`) is counted in exactly one part of each.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np

from apmcal.diagnosis.scoring.gap import LEVEL_MEANS

TIME_BINS = 8
TEMP_BINS = 6


def _rate(cell, rates: dict | None = None) -> float:
    """Sample rate [Hz] of the cell's block (``rates``: known rates by block, filled here —
    one block carries hundreds of cells)."""
    rates = {} if rates is None else rates
    key = id(cell.block)
    if key not in rates:
        dt = np.diff(cell.block.t)
        dt = dt[dt > 0]
        rates[key] = float(1.0 / np.median(dt)) if len(dt) else float("nan")
    return rates[key]


def band_label(cell, rates: dict | None = None) -> str:
    """A cell's frequency band: level j covers fs/2^(j+1) .. fs/2^j Hz.

    Parameters
    ----------
    cell : CellShare
        The cell (:class:`apmcal.diagnosis.scoring.gap.CellShare`).
    rates : dict, optional
        Sample rates [Hz] known by block, filled here.

    Returns
    -------
    str
        "lo-hi Hz" over the cell's pooled levels, or the piece means' label.
    """
    if cell.level == LEVEL_MEANS:
        return "slower than a piece (piece means)"
    fs = _rate(cell, rates)
    lo_level, hi_level = min(cell.levels), max(cell.levels)
    hi = fs / 2 ** lo_level
    lo = fs / 2 ** (hi_level + 1)
    return f"{lo:.3g}-{hi:.3g} Hz"


def _band_key(cell, rates: dict | None = None) -> tuple:
    """Sort bands fast to slow (piece means last)."""
    if cell.level == LEVEL_MEANS:
        return (1, 0.0)
    return (0, -_rate(cell, rates) / 2 ** min(cell.levels))


def _edges(lo: float, hi: float, bins: int) -> np.ndarray:
    return np.linspace(lo, hi if hi > lo else lo + 1e-9, bins + 1)


def _labels(edges: np.ndarray, fmt: str) -> dict:
    """{bin label: index of the bin} (bins whose labels coincide: the last one's), in order."""
    return {fmt.format(edges[i], edges[i + 1]): i for i in range(len(edges) - 1)}


def _add_binned(out: dict, labels: dict, values: np.ndarray, nats: np.ndarray,
                edges: np.ndarray) -> None:
    """Add the sums of ``nats`` over the bins of ``values`` to ``out`` by bin label."""
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)
    sums = np.bincount(idx, nats, minlength=len(edges) - 1)
    for label, i in labels.items():
        out[label] += float(sums[i])


def breakdown(cells: list, n_samples: int, session) -> dict:
    """The gap of ``cells`` [nats per sample over ``n_samples``] split every way.

    Parameters
    ----------
    cells : list of CellShare
        The cells of one or more comparisons.
    n_samples : int
        Residual samples the gap is per (0: every part is 0).
    session : Session
        The session the cells come from (segments, sample times, temperature).

    Returns
    -------
    dict
        {split: {part: gap [nats per sample]}} for the splits "sensor", "axis", "segment",
        "band", "scale", "kind", "time" and, with a temperature, "temperature"; each split
        adds up to the total.
    """
    scale = 1.0 / n_samples if n_samples else 0.0
    parts: dict = {k: defaultdict(float) for k in ("sensor", "axis", "segment", "band",
                                                   "scale", "kind")}
    band_order: dict = {}
    rates: dict = {}
    seg_nats = np.zeros(len(session.segments))
    for c in cells:
        total = c.total * scale
        parts["sensor"][c.channel.split("_")[0]] += total
        parts["axis"][c.channel] += total
        label = band_label(c, rates)
        parts["band"][label] += total
        band_order[label] = _band_key(c, rates)
        within = "across pieces (slower than a piece)" if c.level == LEVEL_MEANS \
            else "within pieces"
        parts["scale"][within] += total
        parts["kind"]["holds" if c.block.shape else "moves"] += total
        np.add.at(seg_nats, session.pieces.segment[c.piece], c.nats * scale)
    out = {k: dict(v) for k, v in parts.items()}
    out["band"] = {k: out["band"][k] for k in sorted(out["band"], key=band_order.get)}
    out["segment"] = {s.label: float(v) for s, v in zip(session.segments, seg_nats) if v != 0}
    out["time"] = _time_parts(cells, session, scale)
    if session.temp is not None:
        out["temperature"] = _temp_parts(cells, session, scale)
    return out


def _time_parts(cells, session, scale) -> dict:
    t0, t1 = float(session.t[0]), float(session.t[-1])
    edges = _edges(t0, t1, TIME_BINS)
    labels = _labels(edges, "{:.0f}-{:.0f} s")     # formatted once, not once per cell
    out: dict = defaultdict(float)
    for c in cells:
        _add_binned(out, labels, c.time, c.nats * scale, edges)
    return dict(out)


def _temp_parts(cells, session, scale) -> dict:
    edges = _edges(float(np.nanmin(session.temp)), float(np.nanmax(session.temp)), TEMP_BINS)
    labels = _labels(edges, "{:.1f}-{:.1f} °C")
    imu_temp: dict = {}     # per block without temperature: the IMU's at its samples
    out: dict = defaultdict(float)
    for c in cells:
        temp = c.temp
        ok = np.isfinite(temp)
        if not ok.any():       # a compass block without temperature: by the IMU's
            temp = _imu_temp(c, session, imu_temp)
            ok = np.ones(len(temp), bool)
        _add_binned(out, labels, temp[ok], c.nats[ok] * scale, edges)
    return dict(out)


def _imu_temp(cell, session, known: dict) -> np.ndarray:
    """The IMU's temperature at the cell's coefficients (np.interp, point by point: once per
    block, then read off at each cell's centres — hundreds of cells share a block)."""
    block = cell.block
    if id(block) not in known:
        known[id(block)] = np.interp(block.t, session.t, session.temp)
    return known[id(block)][np.clip(cell.center, 0, len(block.t) - 1)]


def noise_ratios(cells: list) -> dict:
    """The gap in a unit people read: how many times the real residuals' RMS is the twin's,
    per sensor and frequency band ("real noise is N× the twin's"), √(Σ n·V_real / Σ n·V_twin)
    over the cells of that sensor and band (each variance at least its cell's floor, so a
    ratio stays finite where the readings cannot resolve it).

    Parameters
    ----------
    cells : list of CellShare

    Returns
    -------
    dict
        {sensor: {band label: ratio}}, bands fast to slow.
    """
    sums: dict = defaultdict(lambda: np.zeros(2))
    order: dict = {}
    rates: dict = {}
    for c in cells:
        label = band_label(c, rates)
        order[label] = _band_key(c, rates)
        sums[(c.channel.split("_")[0], label)] += (c.n * c.v_real, c.n * c.v_twin)
    out: dict = {}
    for (sensor, label) in sorted(sums, key=lambda k: (k[0], order[k[1]])):
        real, twin = sums[(sensor, label)]
        if twin > 0 and np.isfinite(real / twin):
            out.setdefault(sensor, {})[label] = float(np.sqrt(real / twin))
    return out


def gap_summary(evaluation, session) -> dict:
    """In-sample and held-out gap of an evaluation (:class:`apmcal.diagnosis.scoring.evaluate.
    Evaluation`), each with its breakdown.

    Returns
    -------
    dict
        "total" and "heldout" [nats per sample], "breakdown" and "breakdown_heldout"
        (:func:`breakdown`), and "noise_ratio_heldout" (:func:`noise_ratios`, held-out).
    """
    n_in = sum(f.gap_in.n_samples for f in evaluation.folds)
    n_out = sum(f.gap_out.n_samples for f in evaluation.folds)
    cells_in = [c for f in evaluation.folds for c in f.gap_in.cells]
    return {"total": evaluation.gap_in, "heldout": evaluation.gap_out,
            "breakdown": breakdown(cells_in, n_in, session),
            "breakdown_heldout": breakdown(evaluation.held_out_cells(), n_out, session),
            "noise_ratio_heldout": noise_ratios(evaluation.held_out_cells())}
