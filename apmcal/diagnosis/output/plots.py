"""The report's figures (PNG): where the gap lies, and real against twin.

Each function draws one figure from a :class:`~apmcal.diagnosis.run.Diagnosis` and saves it;
residuals are the nominal model's, fitted on fold 0 (its held-out side is fold 1).
"""
from __future__ import annotations

import numpy as np

SENSOR_UNITS = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}
SENSOR_WORDS = {"acc": "accelerometer", "gyr": "gyro", "mag": "compass"}


def save(fig, path) -> None:
    """Lay ``fig`` out, shrink any title wider than its share of the figure until it fits (a
    title is never cut at the figure's edge or under its neighbour's), save it as PNG."""
    fig.tight_layout()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        title = ax.title
        share = ax.get_window_extent(renderer).width + 40      # pixels: the axes and a margin
        while title.get_text() and title.get_fontsize() > 5 and (
                title.get_window_extent(renderer).width > share
                or not fits(title.get_window_extent(renderer), fig.bbox)):
            title.set_fontsize(title.get_fontsize() - 0.5)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def fits(box, frame) -> bool:
    """True when the extent ``box`` lies within ``frame`` (both display bounding boxes)."""
    return box.x0 >= frame.x0 - 0.5 and box.x1 <= frame.x1 + 0.5 and box.y1 <= frame.y1 + 0.5


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")          # files only, no screen
    import matplotlib.pyplot as plt

    return plt


def _hold_blocks(evaluation, side: str) -> dict:
    """sensor -> ResidualBlock of the hold residuals (side "real" or "twin")."""
    coeffs = getattr(evaluation.folds[0], side)
    return {c.block.names[0].split("_")[0]: c.block for c in coeffs if c.block.shape}


def _pieces(block, axis: int) -> list[np.ndarray]:
    return [block.values[a:b, axis] for a, b in zip(block.i0, block.i1) if b - a >= 64]


def _bars(ax, labels, before, after, title):
    y = np.arange(len(labels))
    ax.barh(y - 0.2, before, 0.4, label="nominal model")
    ax.barh(y + 0.2, after, 0.4, label="with the selected effects")
    ax.set_yticks(y, labels, fontsize=7)
    ax.invert_yaxis()
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("held-out gap [nats per sample]")
    ax.set_title(title)
    ax.legend(fontsize=7)


def gap_parts(diagnosis, key: str, path, title: str, top: int = 25) -> bool:
    """Bar chart of the held-out gap split by ``key`` (segment, band, ...)."""
    before = diagnosis.result.gap["breakdown_heldout"].get(key)
    after = diagnosis.result.after["breakdown_heldout"].get(key, {})
    if not before:
        return False
    labels = sorted(before, key=lambda k: -abs(before[k]))[:top]
    if key in ("band", "time", "temperature"):
        labels = [k for k in before if k in labels]
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 1.0 + 0.22 * len(labels)))
    _bars(ax, labels, [before[k] for k in labels], [after.get(k, 0.0) for k in labels], title)
    save(fig, path)
    plt.close(fig)
    return True


def psd(diagnosis, path) -> bool:
    """Welch power spectral density of the hold residuals, real against twin, per sensor."""
    from scipy.signal import welch

    real, twin = _hold_blocks(diagnosis.nominal, "real"), _hold_blocks(diagnosis.nominal, "twin")
    fs = diagnosis.evaluator.fs_of
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(real), figsize=(4.2 * len(real), 3.4), squeeze=False)
    for ax, sensor in zip(axes[0], real):
        pieces = {side: [x for axis in range(3) for x in _pieces(blocks[sensor], axis)]
                  for side, blocks in (("real", real), ("twin", twin))}
        if not pieces["real"]:
            continue
        nperseg = min(512, min(len(x) for x in pieces["real"]))
        for side, style in (("real", "-"), ("twin", "--")):
            spectra = [welch(x, fs=fs[sensor], nperseg=nperseg) for x in pieces[side]]
            f = spectra[0][0]
            ax.loglog(f[1:], np.mean([p for _, p in spectra], axis=0)[1:], style, label=side)
        ax.set_title(f"{sensor} residual PSD")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"[({SENSOR_UNITS[sensor]})²/Hz]")
        ax.legend(fontsize=7)
    save(fig, path)
    plt.close(fig)
    return bool(real)


def allan(diagnosis, path) -> bool:
    """Allan deviation of the hold residuals (overlapping, pooled over the holds), real
    against twin, per sensor axis."""
    from apmcal.diagnosis.noise.allan import allan_deviation

    real, twin = _hold_blocks(diagnosis.nominal, "real"), _hold_blocks(diagnosis.nominal, "twin")
    fs = diagnosis.evaluator.fs_of
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(real), figsize=(4.2 * len(real), 3.4), squeeze=False)
    for ax, sensor in zip(axes[0], real):
        for axis, color in zip(range(3), ("C0", "C1", "C2")):
            for side, blocks, style in (("real", real, "-"), ("twin", twin, "--")):
                pieces = _pieces(blocks[sensor], axis)
                if not pieces:
                    continue
                ad = allan_deviation(pieces, fs[sensor], taus="octave")
                ax.loglog(ad.tau, ad.adev, style, color=color,
                          label=f"{'xyz'[axis]} {side}")
        ax.set_title(f"{sensor} Allan deviation")
        ax.set_xlabel("τ [s]")
        ax.set_ylabel(f"[{SENSOR_UNITS[sensor]}]")
        ax.legend(fontsize=6, ncol=2)
    save(fig, path)
    plt.close(fig)
    return bool(real)


def temperature(diagnosis, path) -> bool:
    """Gyro and accelerometer hold residuals (block means) against the board temperature."""
    session = diagnosis.evaluator.session
    if session.temp is None:
        return False
    real = _hold_blocks(diagnosis.nominal, "real")
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8.4, 3.4))
    for ax, sensor in zip(axes, ("gyr", "acc")):
        block = real[sensor]
        for axis, color in zip(range(3), ("C0", "C1", "C2")):
            means = [block.values[a:b, axis].mean() for a, b in zip(block.i0, block.i1)]
            temps = [np.mean(block.temp[a:b]) for a, b in zip(block.i0, block.i1)]
            ax.plot(temps, means, "o", ms=3, color=color, label="xyz"[axis])
        ax.set_xlabel("temperature [°C]")
        ax.set_ylabel(f"{sensor} residual, piece mean [{SENSOR_UNITS[sensor]}]")
        ax.set_title(f"{SENSOR_WORDS.get(sensor, sensor)}: residual vs temperature")
        ax.legend(fontsize=7)
    save(fig, path)
    plt.close(fig)
    return True
