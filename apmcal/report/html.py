"""The HTML report (``--report DIR``): one self-contained page, ``DIR/index.html``, with the
verdict first, the figures (:mod:`apmcal.report.figures`) embedded as base64 PNG and the text
report below them. Nothing is loaded from the network: no scripts, fonts or style sheets from
elsewhere, so the page opens offline and shows the same everywhere.
"""
from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

from apmcal.core.errors import ApmcalError

STYLE = """body{font-family:sans-serif;max-width:60em;margin:1em auto;padding:0 1em;color:#222}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em}
.good{color:#1a7f37}.usable{color:#9a6700}.redo{color:#cf222e}.not-measured{color:#57606a}
.nothing-to-apply{color:#9a6700}
pre{background:#f6f8fa;padding:.8em;overflow-x:auto;font-size:.85em}
img{max-width:100%}figure{margin:1em 0}figcaption{font-size:.9em;color:#57606a}"""


def page(title: str, verdict_html: str, figures: list[tuple[str, bytes]], text: str) -> str:
    """The whole page: title, verdict, figures (caption, PNG bytes), the text report."""
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>", verdict_html]
    if figures:
        parts.append("<h2>Figures</h2>")
    for caption, png in figures:
        data = base64.b64encode(png).decode("ascii")
        parts.append(f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,"
                     f"{data}'><figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append(f"<h2>The full report</h2><pre>{html.escape(text)}</pre></body></html>")
    return "\n".join(parts)


def verdict_block(verdicts: dict) -> str:
    """The overall grade and each sensor's grade, reason and next step as HTML."""
    from apmcal.report.verdict import NAMES

    overall = verdicts.get("overall")
    if overall is None:
        return "<p>No calibration.</p>"
    css = overall.grade.replace(" ", "-")
    out = [f"<p class='verdict'><b>verdict: <span class='{css}'>{overall.grade.upper()}"
           f"</span></b> — {html.escape(overall.reason)}</p><ul>"]
    for name, v in verdicts.items():
        if name == "overall":
            continue
        grade = v.grade if v.measured else "not measured by this session"
        step = f"<br>next: {html.escape(v.next_step)}" if v.next_step else ""
        out.append(f"<li>{NAMES[name]}: <span class='{v.grade.replace(' ', '-')}'>{grade}"
                   f"</span> — {html.escape(v.reason)}{step}</li>")
    return "".join(out) + "</ul>"


def write_page(out_dir, text: str) -> Path:
    """``out_dir/index.html`` written (the folder made when missing); its path."""
    folder = Path(out_dir)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / "index.html"
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ApmcalError(f"cannot write the report ({exc.strerror or exc})", str(out_dir)) \
            from None
    return path


def _console_text(render) -> str:
    """What ``render(console)`` prints, as plain text."""
    from rich.console import Console

    buf = io.StringIO()
    render(Console(file=buf, width=100, markup=False, emoji=False, highlight=False,
                   color_system=None, soft_wrap=True))
    return buf.getvalue()


# --------------------------------------------------------------------------- log / live
def write_session_html(report, contents, out_dir) -> Path:
    """The page of ``apmcal log`` / ``live``: verdict, figures, text report.

    Parameters
    ----------
    report : SessionReport
        With its calibration.
    contents : LogContents
        The file the report is of (the figures redraw its samples).
    out_dir : str or Path

    Returns
    -------
    Path
        ``out_dir/index.html``.
    """
    text = _console_text(lambda c: (report.print_calibration(c), c.print(),
                                    report.print_summary(c)))
    figures = session_figures(report, contents)
    title = f"apmcal calibration of {Path(str(report.path)).name}"
    return write_page(out_dir, page(title, verdict_block(report.verdict), figures, text))


def session_figures(report, contents) -> list[tuple[str, bytes]]:
    """(caption, PNG) for each sensor the session calibrated (accelerometer, compass, gyro)."""
    from apmcal.core.constants import STANDARD_GRAVITY
    from apmcal.preprocessing.prepare import pick_recording, prepare
    from apmcal.preprocessing.static import find_static_segments
    from apmcal.report import figures as fig

    cal = report.calibration
    generation = None if report.proposal is None else report.proposal.generation
    recording, mag_recording = pick_recording(contents, None)
    raw = prepare(recording, generation).raw
    out = []
    t = raw.t
    acc_cal = cal.sensors.get("acc")
    if acc_cal is not None and raw.has("acc"):
        segments = find_static_segments(t, raw.xyz("acc"),
                                        raw.xyz("gyr") if raw.has("gyr") else None)
        if segments:
            means = np.array([s.acc_mean for s in segments])
            after = fig.correct(acc_cal, means, np.array([s.t_mean for s in segments]))
            six = cal.report.six_face
            gravity = six.gravity if six is not None else STANDARD_GRAVITY
            png = fig.accelerometer_figure(means, after, gravity,
                                           [f"{i + 1}" for i in range(len(segments))])
            if png:
                out.append(("Accelerometer: the mean of each still hold before (red) and "
                            "after (green) the calibration; after, they lie on the sphere of "
                            "radius g, and the residual per hold shrinks", png))
    mag_cal = cal.sensors.get("mag")
    mf = cal.report.magnetic_field
    if mag_cal is not None and mf is not None:
        source = raw if raw.has("mag") else (prepare(mag_recording, generation).raw
                                             if mag_recording is not None else None)
        if source is not None and source.has("mag"):
            m = source.xyz("mag")
            ok = np.isfinite(m).all(axis=1)
            png = fig.compass_figure(source.t[ok], m[ok], fig.correct(mag_cal, m[ok],
                                                                      source.t[ok]),
                                     float(mf.mgauss), mf.source, mf.coverage_fraction)
            if png:
                out.append(("Compass: samples before (red) and after (green), and the field "
                            "magnitude along time against the reference field "
                            f"({mf.source})", png))
    gyr_cal = cal.sensors.get("gyr")
    turns = cal.report.rotations
    if gyr_cal is not None and turns and raw.has("gyr"):
        spans = {axis: (tn.start_s, tn.end_s) for axis, tn in turns.items() if axis in "xyz"}
        g = raw.xyz("gyr")
        corrected = fig.correct(gyr_cal, g, t)
        # the turns made, in quarter turns; then each turn's angle as the fit integrates it:
        # its motions only, against the rate at rest around them
        expected = {a: 90.0 * round(v / 90.0)
                    for a, v in fig.integrated_angles(t, corrected, spans).items()}
        holds = find_static_segments(t, raw.xyz("acc"), g)
        png = fig.gyro_figure(fig.turn_errors(t, g, spans, holds, expected),
                              fig.turn_errors(t, corrected, spans, holds, expected), expected)
        if png:
            out.append(("Gyroscope: each full turn's angle minus the expected one, before (red) "
                        "and after (green) the calibration; integrated over the turn's motions "
                        "against the rate at rest around them, as the fit does, so after it the "
                        "turns read whole (that is how the gyro matrix is fitted)", png))
    return out


# --------------------------------------------------------------------------- tcal
def write_tcal_html(tcal, source: str, out_dir) -> Path:
    """The page of ``apmcal tcal``: what is proposed, the drift against temperature before and
    after per IMU, and the text report."""
    from apmcal.ardupilot.tcal_params import TEMP_REFERENCE_C, polynomial
    from apmcal.report import figures as fig
    from apmcal.report.tcal import action, print_tcal

    text = _console_text(lambda c: print_tcal(tcal.results, c))
    figures = []
    items = []
    for r, line in zip(tcal.results, action(tcal.results)):
        # the console's own first lines, the outcome coloured
        head, _, rest = line.partition(" — ")
        css = "redo" if r.withheld else "good"
        outcome, _, words = head.partition(": ")
        items.append(f"<li>{html.escape(outcome)}: <span class='{css}'>{html.escape(words)}"
                     f"</span> — {html.escape(rest)}</li>")
    for r in tcal.results:
        if r.blocks:
            png = fig.tcal_figure(r.blocks, {s: f.coeffs for s, f in r.fits.items()},
                                  polynomial, TEMP_REFERENCE_C)
            if png:
                figures.append((f"IMU {r.instance}: drift of the still blocks against "
                                "temperature, before and after subtracting the fitted "
                                "polynomial (one constant per orientation removed)", png))
    verdict = ("<p class='verdict'><b>temperature calibration</b></p><ul>" + "".join(items)
               + "</ul>")
    title = f"apmcal temperature calibration of {Path(str(source)).name}"
    return write_page(out_dir, page(title, verdict, figures, text))


# --------------------------------------------------------------------------- flight compass
def write_flight_html(result, out_dir) -> Path:
    """The page of ``apmcal log`` on a flight: each compass's verdict in heading degrees, its
    heading error along the flight with the calibration in force and the proposed one, and
    the text report.

    Parameters
    ----------
    result : FlightResult
        :func:`apmcal.calibration.flight.calibrate_flight_log`'s result.
    out_dir : str or Path

    Returns
    -------
    Path
        ``out_dir/index.html``.
    """
    from apmcal.report import figures as fig
    from apmcal.solvers.compass_heading import GOOD_DEG, USABLE_DEG

    items, figures = [], []
    for c in result.compasses:
        hi, hp = c.health_in_force, c.health_proposed
        items.append(f"<li>compass {c.instance}: calibration in force <span class='{hi.verdict}'>"
                     f"{hi.verdict}</span> — heading error 95 % {hi.p95_deg:.1f}°; proposed "
                     f"<span class='{hp.verdict}'>{hp.verdict}</span> — {hp.p95_deg:.1f}°</li>")
        series = c.series()
        png = fig.heading_figure(series["t_s"], series["in_force_deg"], series["proposed_deg"],
                                 (GOOD_DEG, USABLE_DEG))
        if png:
            figures.append((f"compass {c.instance}: heading error along the flight, with the "
                            f"calibration in force (red) and the proposed one (green); dotted "
                            f"±{GOOD_DEG:g}° good, dashed ±{USABLE_DEG:g}° usable", png))
    verdict = ("<p class='verdict'><b>compass in flight, in heading degrees</b></p><ul>"
               + "".join(items) + "</ul>")
    title = f"apmcal flight compass check of {Path(str(result.path)).name}"
    return write_page(out_dir, page(title, verdict, figures, "\n".join(result.lines())))
