"""The HTML report's figures (matplotlib, drawn off screen): each function takes the data and
returns one PNG as bytes, or None when the session holds nothing to draw.

- :func:`accelerometer_figure` — the hold means on the sphere of radius g before/after the
  calibration, and each hold's residual |a| − g;
- :func:`compass_figure` — the samples on the sphere before/after, with the coverage, and the
  field magnitude along time against the reference field (WMM or the fit's sphere);
- :func:`gyro_figure` — each full turn's angle, integrated over its motions against the rate
  at rest around them, before/after against the expected one;
- :func:`tcal_figure` — the drift against temperature before/after the temperature calibration;
- :func:`heading_figure` — a flight's compass heading error along the flight, with the
  calibration in force and with the proposed one.

All vectors are in the sensor frame of the data (raw: the firmware's correction undone).
"""
from __future__ import annotations

import io

import numpy as np

MAX_POINTS = 1500          # samples drawn per cloud: enough to see the shape, a small PNG
DPI = 80
BEFORE, AFTER = "#d62728", "#2ca02c"


def _png(fig) -> bytes:
    """The figure as PNG bytes (closed afterwards)."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _figure(width_in: float, height_in: float):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt.figure(figsize=(width_in, height_in))


def correct(cal, samples: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``cal`` (SensorCalibration) applied to raw (n, 3) samples at times ``t`` [s]; without
    the g-sensitivity term when the calibrated specific force is not at hand."""
    try:
        return cal.apply(samples, t)
    except ValueError:
        return (np.asarray(samples, dtype=float) - cal.offset) @ cal.matrix.T


def _sphere(ax, radius: float) -> None:
    """A wireframe sphere of ``radius`` on a 3-D axis, equal aspect."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
    ax.plot_wireframe(radius * np.cos(u) * np.sin(v), radius * np.sin(u) * np.sin(v),
                      radius * np.cos(v), color="0.8", linewidth=0.5)
    ax.set_box_aspect((1, 1, 1))


def accelerometer_figure(means_raw: np.ndarray, means_cal: np.ndarray, gravity: float,
                         labels: list[str]) -> bytes | None:
    """Hold means [m/s²] before (raw) and after on the sphere of radius ``gravity``, and each
    hold's residual |a| − g before/after."""
    if len(means_raw) == 0:
        return None
    fig = _figure(11, 4.2)
    fig.subplots_adjust(wspace=0.4)         # room for the 3-D axis's z label
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    _sphere(ax, gravity)
    for pts, color, name in ((means_raw, BEFORE, "before"), (means_cal, AFTER, "after")):
        ax.scatter(*pts.T, color=color, s=25, label=name, depthshade=False)
    ax.set_xlabel("x [m/s²]")
    ax.set_ylabel("y [m/s²]")
    ax.set_zlabel("z [m/s²]")
    ax.set_title(f"hold means on the sphere |a| = {gravity:.4g} m/s²")
    ax.legend(loc="upper left")
    ax2 = fig.add_subplot(1, 2, 2)
    k = np.arange(len(means_raw))
    ax2.bar(k - 0.2, np.linalg.norm(means_raw, axis=1) - gravity, 0.4, color=BEFORE,
            label="before")
    ax2.bar(k + 0.2, np.linalg.norm(means_cal, axis=1) - gravity, 0.4, color=AFTER,
            label="after")
    ax2.axhline(0, color="k", linewidth=0.8)
    ax2.set_xticks(k, labels, rotation=60, fontsize=7)
    ax2.set_ylabel("|a| − g [m/s²]")
    ax2.set_title("residual per hold")
    ax2.legend()
    return _png(fig)


def compass_figure(t: np.ndarray, raw: np.ndarray, cal: np.ndarray, field_mgauss: float,
                   field_source: str, coverage: float | None) -> bytes | None:
    """Compass samples [mGauss] before/after on the sphere of the reference field, and |m|
    along time against it."""
    if len(raw) == 0 or not np.isfinite(field_mgauss):
        return None
    step = max(1, len(raw) // MAX_POINTS)
    fig = _figure(11, 4.2)
    fig.subplots_adjust(wspace=0.4)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    _sphere(ax, field_mgauss)
    for pts, color, name in ((raw[::step], BEFORE, "before"), (cal[::step], AFTER, "after")):
        ax.scatter(*pts.T, color=color, s=2, label=name, depthshade=False)
    cover = "" if coverage is None else f"; {100 * coverage:.0f} % of directions covered"
    ax.set_title(f"samples on the sphere{cover}", fontsize=9)
    ax.set_xlabel("x [mGauss]")
    ax.set_ylabel("y [mGauss]")
    ax.set_zlabel("z [mGauss]")
    ax.legend(loc="upper left")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.plot(t[::step], np.linalg.norm(raw[::step], axis=1), ".", color=BEFORE, ms=2,
             label="before")
    ax2.plot(t[::step], np.linalg.norm(cal[::step], axis=1), ".", color=AFTER, ms=2,
             label="after")
    ax2.axhline(field_mgauss, color="k", linewidth=1, label=f"{field_source[:40]}")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("|m| [mGauss]")
    ax2.set_title("field magnitude along time")
    ax2.legend(fontsize=7)
    return _png(fig)


def integrated_angles(t: np.ndarray, gyr: np.ndarray, spans: dict) -> dict[str, float]:
    """The angle [deg] about each axis ("x", "y", "z") integrated over its span (start, end) [s]
    (trapezoidal rule on the axis's own rate): how many quarter turns were made."""
    out = {}
    for axis, (start, end) in spans.items():
        i = "xyz".index(axis)
        sel = (t >= start) & (t <= end)
        if sel.sum() > 1:
            w, ts = gyr[sel, i], t[sel]
            out[axis] = float(np.degrees(np.sum(0.5 * (w[1:] + w[:-1]) * np.diff(ts))))
    return out


def turn_errors(t: np.ndarray, gyr: np.ndarray, spans: dict, holds: list,
                expected: dict[str, float]) -> dict[str, float]:
    """Per turn axis, how far [deg] the turn's angle about that axis lies from ``expected``
    (axis → angle [deg]), integrated as the six-face fit integrates it
    (:func:`apmcal.solvers.gyro_bias.integrate_motions`): only the motions between the still
    ``holds`` (StaticSegment), each against the rate of the holds around it. Integrating the
    pauses too would add every bias the offsets leave at rest (g-sensitivity, Earth rate)
    times a minute of pauses: degrees that say nothing of the turn. Axes whose holds cannot be
    found are left out."""
    from types import SimpleNamespace

    from apmcal.solvers.gyro_bias import integrate_motions, motions_between_holds

    out = {}
    for axis, (start, end) in spans.items():
        turn = SimpleNamespace(i0=int(np.searchsorted(t, start)),
                               i1=int(np.searchsorted(t, end, side="right")))
        moves = motions_between_holds(turn, holds)
        if not moves or axis not in expected:
            continue
        total, _ = integrate_motions(t, gyr, moves)
        out[axis] = float(np.degrees(total["xyz".index(axis)]) - expected[axis])
    return out


def gyro_figure(before: dict[str, float], after: dict[str, float],
                expected: dict[str, float]) -> bytes | None:
    """Each full turn's error [deg] (:func:`turn_errors`) before and after, by axis, labelled
    with the turn expected."""
    axes = [a for a in "xyz" if a in before and a in after and a in expected]
    if not axes:
        return None
    fig = _figure(6, 3.5)
    ax = fig.add_subplot(1, 1, 1)
    k = np.arange(len(axes))
    ax.bar(k - 0.2, [before[a] for a in axes], 0.4, color=BEFORE, label="before")
    ax.bar(k + 0.2, [after[a] for a in axes], 0.4, color=AFTER, label="after")
    ax.axhline(0, color="k", linewidth=0.8)
    ax.set_xticks(k, [f"{a} ({expected[a]:+.0f}°)" for a in axes])
    ax.set_ylabel("integrated − expected [deg]")
    ax.set_title("full turns: integrated angle against the expected one")
    ax.legend()
    return _png(fig)


def tcal_figure(blocks: dict, coeffs: dict, polynomial, reference_c: float) -> bytes | None:
    """Per sensor, the still blocks' drift against temperature before (group means removed)
    and after subtracting ArduPilot's polynomial ``polynomial(coeffs, T − reference_c)``."""
    sensors = [s for s in ("acc", "gyr") if s in blocks and s in coeffs]
    if not sensors:
        return None
    units = {"acc": "m/s²", "gyr": "rad/s"}
    fig = _figure(10, 3.4 * len(sensors))
    for row, sensor in enumerate(sensors):
        temp, values, group = blocks[sensor]
        after_values = values - polynomial(coeffs[sensor], np.asarray(temp) - reference_c)
        for col, (vals, title) in enumerate(((values, "before"), (after_values, "after"))):
            centred = np.array(vals, dtype=float)
            for g in np.unique(group):
                centred[group == g] -= centred[group == g].mean(axis=0)
            ax = fig.add_subplot(len(sensors), 2, 2 * row + col + 1)
            for j, axis in enumerate("XYZ"):
                ax.plot(temp, centred[:, j], ".", ms=3, label=axis)
            ax.set_xlabel("temperature [°C]")
            ax.set_ylabel(f"{sensor} drift [{units[sensor]}]")
            ax.set_title(f"{sensor}: {title} the temperature calibration")
            ax.legend(fontsize=7)
    fig.tight_layout()
    return _png(fig)


def heading_figure(t_s, in_force_deg, proposed_deg, limits_deg: tuple[float, float]):
    """A flight's compass heading error [deg] along the flight [s], with the calibration in
    force (before) and the proposed one (after), the good / usable limits as lines; None
    without samples."""
    t = np.asarray(t_s, dtype=float)
    if t.size == 0:
        return None
    fig = _figure(8.0, 3.0)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(t - t[0], np.asarray(in_force_deg, dtype=float), color=BEFORE, lw=0.8,
            label="calibration in force")
    ax.plot(t - t[0], np.asarray(proposed_deg, dtype=float), color=AFTER, lw=0.8,
            label="proposed calibration")
    for limit, style in zip(limits_deg, (":", "--")):
        for sign in (1, -1):
            ax.axhline(sign * limit, color="#57606a", lw=0.7, ls=style)
    ax.set_xlabel("time in the flight [s]")
    ax.set_ylabel("heading error [°]")
    ax.legend(loc="upper right", fontsize=8)
    return _png(fig)
