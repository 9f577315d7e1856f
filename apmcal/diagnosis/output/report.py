"""``apmcal gap --report DIR``: a Markdown report with its figures, for a person who has never
seen the code."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from apmcal.diagnosis.output import html, plots
from apmcal.diagnosis.output.advice import advice
from apmcal.diagnosis.output.summary import param_text, rate_note, verdict

SPLITS = (("sensor", "sensor"), ("kind", "holds or moves"), ("band", "frequency band"),
          ("scale", "within or across pieces"), ("time", "time"),
          ("temperature", "temperature"), ("segment", "segment (largest first)"))

METHOD = """\
- **Real and twin.** The log's samples are prepared as for a calibration (the firmware's own
  correction undone) and cut into still holds and the moves between them. The *nominal model*
  is what ArduPilot's parameters can hold: accelerometer offset and per-axis scale, gyro offset,
  compass offset and soft-iron matrix, white noise. Its *twin* is the same session — same
  timestamps, poses, moves, temperatures — simulated by apmcal's simulator (`sitl`) with the
  fitted parameters.
- **Gap.** Real and twin go through the same fit; their residuals are compared scale by scale
  (Haar wavelet coefficients in each hold and move). The gap is the Kullback-Leibler divergence
  between them, in nats per residual sample, with its expected value for two draws of the same
  process removed: a model that describes the board scores 0 on average.
- **Held out.** Each hold is cut into pieces that alternate between two folds; a model fitted on
  one fold is scored on the other, both ways round.
- **Effects.** Each candidate is added to the nominal model alone, refitted, re-twinned and
  scored held out. Its *evidence* is the held-out gap it removes, in nats (the log of how many
  times better it predicts the held-out data); it is *supported* when the evidence reaches 15
  nats, its fitted parameters differ from the values that switch it off (Wald test, p < 0.001)
  and lie within physical limits (else it is *implausible*: standing in for something else),
  and chance alone would not give it that much: the candidate is scored the same way on
  sessions drawn from the fitted nominal model (*null sessions*: the same motion and
  temperatures, no effect), and its real evidence must lie beyond what those give it (p below
  5 % shared among the candidates tested).
  Supported effects are then combined stepwise: each round adds the one with the most evidence
  on top of those chosen and drops an earlier one the later ones explain. An effect is
  *significant* when it is in that combination (or still supported on top of it); one supported
  alone but not significant only mimicked a part of a larger effect.
"""


def _table(rows: list[list[str]], header: list[str]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _parts_table(parts: dict, total: float, limit: int = 12) -> str:
    keys = list(parts)
    if len(keys) > limit:
        keys = sorted(keys, key=lambda k: -abs(parts[k]))[:limit]
    rows = [[k, f"{parts[k]:.3g}", f"{100 * parts[k] / total:.0f} %" if total > 0 else "-"]
            for k in keys]
    return _table(rows, ["part", "nats/sample", "share"])


def _session_table(result) -> str:
    s = result.session
    rows = [["source", f"`{result.source}`"], ["duration", f"{s['duration_s']:.0f} s"],
            ["sample rate", f"{s['rate_hz']:.0f} Hz"],
            ["holds / moves / pieces", f"{s['holds']} / {s['moves']} / {s['pieces']}"],
            ["distinct orientations", str(s["orientations"])],
            ["sensors", ", ".join(s["sensors"])]]
    if "temperature_c" in s:
        rows.append(["temperature", "{:.1f} to {:.1f} °C".format(*s["temperature_c"])])
    if "current_a" in s:
        rows.append(["battery current", "{:.1f} to {:.1f} A".format(*s["current_a"])])
    if s.get("integer_format"):
        rows.append(["stored as integers by the log format", ", ".join(s["integer_format"])])
    return _table(rows, ["what", "value"])


def _rate_paragraph(result) -> str:
    note = rate_note(result)
    return f"The {note[0].upper()}{note[1:]}.\n" if note else ""


def _effects_table(result) -> str:
    rows = []
    for e in result.effects:
        if e.get("not_tested"):
            rows.append([e["name"], "-", "-", "not tested", e["not_tested"]])
            continue
        params = "; ".join(f"{k} = {param_text(p)} {p['unit']}"
                           for k, p in e.get("params", {}).items())
        rows.append([e["name"], f"{100 * e['shrink_heldout']:.0f} %",
                     f"{e['evidence_nats']:.0f}", _beyond(e),
                     "**yes**" if e["significant"] else "no", params])
    return _table(rows, ["effect", "held-out shrink alone", "evidence alone [nats]",
                         "evidence with the selection [nats]", "significant",
                         "fitted parameters (alone)"])


def _beyond(e: dict) -> str:
    """The effect's evidence when it joined the selection, or left on top of it."""
    if "evidence_when_selected_nats" in e:
        return f"{e['evidence_when_selected_nats']:.0f} (selected)"
    if "evidence_beyond_selection_nats" in e:
        return f"{e['evidence_beyond_selection_nats']:.0f}"
    return "-"


def _fmt(value) -> str:
    v = np.asarray(value, dtype=float)
    if v.ndim == 0:
        return f"{float(v):.4g}"
    return "[" + ", ".join(_fmt(x) for x in v) + "]"


def write_report(diagnosis, directory) -> Path:
    """Write ``report.md`` and its PNG figures into ``directory`` (created if needed)."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    result = diagnosis.result
    figures = {
        "segments.png": plots.gap_parts(diagnosis, "segment", out / "segments.png",
                                        "held-out gap by segment"),
        "bands.png": plots.gap_parts(diagnosis, "band", out / "bands.png",
                                     "held-out gap by frequency band"),
        "psd.png": plots.psd(diagnosis, out / "psd.png"),
        "allan.png": plots.allan(diagnosis, out / "allan.png"),
        "temperature.png": plots.temperature(diagnosis, out / "temperature.png"),
    }
    # what to do first, in the console's words, then the same verdict in numbers
    text = [f"# apmcal gap report — {Path(result.source).name}", "", "## What to do", "",
            *[f"{line}\n" for line in advice(result)],
            f"**The gap in numbers.** {verdict(result)}", "", "## The session", "",
            _session_table(result), "", "## How big is the gap", ""]
    g, a = result.gap, result.after
    text += [f"- nominal model: in-sample **{g['total']:.3g}**, held-out **{g['heldout']:.3g}** "
             "nats per sample",
             f"- with the selected effects ({', '.join(result.selected) or 'none'}): "
             f"in-sample {a['total']:.3g}, held-out {a['heldout']:.3g}", "",
             "## Where the gap lies (nominal model, held out)", ""]
    for key, what in SPLITS:
        parts = g["breakdown_heldout"].get(key)
        if parts:
            text += [f"### By {what}", "", _parts_table(parts, g["heldout"]), ""]
    text += [_figure(figures, "segments.png", "Held-out gap by segment"),
             _figure(figures, "bands.png", "Held-out gap by frequency band"), "",
             "## Which unmodelled effect", "", _rate_paragraph(result), _effects_table(result), "",
             "## Real against twin", "",
             _figure(figures, "psd.png", "Power spectral density of the hold residuals"),
             _figure(figures, "allan.png", "Allan deviation of the hold residuals"),
             _figure(figures, "temperature.png", "Residuals against temperature"), "",
             "## How this was computed", "", METHOD]
    if result.notes:
        text += ["## Notes", ""] + [f"- {n}" for n in result.notes]
    path = out / "report.md"
    path.write_text("\n".join(text) + "\n")
    html.write_index(out)       # the same report as one self-contained page, index.html
    return path


def _figure(figures: dict, name: str, caption: str) -> str:
    return f"![{caption}]({name})\n" if figures.get(name) else ""
