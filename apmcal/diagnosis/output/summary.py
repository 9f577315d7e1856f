"""The terminal summary of ``apmcal gap``: what to do first (one sentence per selected effect,
:mod:`apmcal.diagnosis.output.advice`), then the verdict, where the gap lies (in nats and as
"real noise is N× the twin's") and the candidate effects ranked. Works from the saved result
alone (:class:`GapResult`)."""
from __future__ import annotations

import numpy as np
from rich.text import Text

from apmcal.diagnosis.model.wald import MAX_P_VALUE
from apmcal.diagnosis.scoring.select import MIN_EVIDENCE_NATS


def _say(console, text) -> None:
    """One line, wrapped by the terminal rather than inside a number or a list when piped."""
    console.print(text, soft_wrap=True)


def _pct(part: float, total: float) -> str:
    return f"{100 * part / total:.0f} %" if total > 0 else "-"


def verdict(result) -> str:
    """One sentence: is there a gap, and what closes it."""
    gap = result.gap["heldout"]
    after = result.after["heldout"]
    if not result.selected:
        if gap <= 0 or not any(e.get("supported_alone") for e in result.effects):
            return (f"No candidate effect explains the gap (held-out {gap:.2e} nats/sample): "
                    "either the simulator already matches this board, or the gap comes from "
                    "something outside the candidate list.")
    names = ", ".join(result.selected)
    return (f"Modelling {names} shrinks the held-out gap from {gap:.2e} to {after:.2e} "
            f"nats/sample ({_pct(gap - after, gap)} of it).")


def top_parts(parts: dict, total: float, n: int = 3) -> str:
    """The ``n`` largest positive parts of a split, each with its share of ``total``."""
    items = sorted(parts.items(), key=lambda kv: -kv[1])[:n]
    return ", ".join(f"{k} {_pct(v, total)}" for k, v in items if v > 0) or "-"


def print_summary(result, console) -> None:
    """Print the summary of a result (module docstring)."""
    s = result.session
    temp = (f"; temperature {s['temperature_c'][0]:.1f}-{s['temperature_c'][1]:.1f} °C"
            if "temperature_c" in s else "")
    from apmcal.diagnosis.output.advice import advice

    for line in advice(result):
        _say(console, Text(line, style="bold"))
    _say(console, Text(f"apmcal gap — {result.source}", style="bold"))
    _say(console, f"{s['duration_s']:.0f} s at {s['rate_hz']:.0f} Hz; {s['holds']} holds, "
                  f"{s['moves']} moves, {s['orientations']} orientations; "
                  f"sensors {', '.join(s['sensors'])}{temp}")
    _say(console, Text(verdict(result), style="bold"))
    g = result.gap
    against = f"the recorded twin {s['twin_log']}" if s.get("twin_log") else \
        "its simulated twin"
    _say(console, f"Gap of the nominal model (real vs {against}): in-sample "
                  f"{g['total']:.2e}, held-out {g['heldout']:.2e} nats/sample")
    b, total = g["breakdown_heldout"], g["heldout"]
    for key, what in (("sensor", "by sensor"), ("kind", "holds / moves"),
                      ("band", "by frequency band"), ("segment", "by segment"),
                      ("scale", "within / across pieces"), ("temperature", "by temperature")):
        if key in b:
            _say(console, f"  {what}: {top_parts(b[key], total)}")
    ratios = ratio_text(g.get("noise_ratio_heldout", {}))
    if ratios:
        _say(console, f"  real noise vs the twin's (held-out RMS ratio): {ratios}")
    print_noise(result, console)
    print_effects(result, console)
    for note in result.notes:
        _say(console, f"note: {note}")


def ratio_text(ratios: dict, n: int = 2) -> str:
    """"gyr 3.1× at 0.0195-0.0391 Hz, ..." — per sensor the ``n`` bands where the real
    residuals' RMS is furthest from the twin's (by |log ratio|), "≈1×" when all within 10 %."""
    out = []
    for sensor, bands in ratios.items():
        far = sorted(bands.items(), key=lambda kv: -abs(np.log(max(kv[1], 1e-300))))[:n]
        if not far or all(abs(r - 1.0) < 0.1 for _, r in far):
            out.append(f"{sensor} ≈1×")
        else:
            out.append(f"{sensor} " + ", ".join(f"{r:.2g}× at {band}" for band, r in far))
    return "; ".join(out)


def noise_line(axes: dict) -> str:
    """One sensor's noise terms: the white density real/twin ratio per axis, and where the
    real residuals have a bias instability or random walk (and whether the twin has one)."""
    ratios = []
    for _name, d in axes.items():
        real, twin = d["real"].get("white_density"), d["twin"].get("white_density")
        ratios.append(f"{real['value'] / twin['value']:.2f}" if real and twin else "-")
    parts = [f"white noise real/twin {' '.join(ratios)}"]
    for term, label in (("bias_instability", "bias instability"),
                        ("random_walk", "rate random walk")):
        found = [f"{name} {param_text(d['real'][term])} (twin "
                 f"{param_text(d['twin'][term]) if d['twin'].get(term) else 'none'})"
                 for name, d in axes.items() if d["real"].get(term)]
        unit = next((d["real"][term]["unit"] for d in axes.values() if d["real"].get(term)), "")
        parts.append(f"{label} " + (", ".join(found) + f" {unit}" if found else "none"))
    return "; ".join(parts)


def print_noise(result, console) -> None:
    """The noise structure of the hold residuals, one line per sensor (:func:`noise_line`)."""
    if not result.noise_structure:
        return
    _say(console, "Noise of the hold residuals (IEEE 952 terms by GMWM, real vs twin):")
    for sensor, axes in result.noise_structure.items():
        _say(console, f"  {sensor}: {noise_line(axes)}")


def print_effects(result, console) -> None:
    """Significant effects with their fitted parameters; the rest on one line each."""
    _say(console, "Candidate effects, each alone on the nominal model (held-out shrink, "
                  "evidence [nats]):")
    note = rate_note(result)
    if note:
        _say(console, f"  ({note})")
    tested = [e for e in result.effects if not e.get("not_tested")]
    for e in tested:
        if e["significant"]:
            _say(console, Text(f"  significant {e['name']:<21} {_shrink(e):>6}  evidence "
                               f"{e['evidence_nats']:.0f}{_by_chance(e)}", style="bold"))
            for name, p in e.get("params", {}).items():
                _say(console, f"      {name} = {param_text(p)} {p['unit']}")
    confounded = [e for e in tested if e.get("confounded_with")]
    if confounded:
        _say(console, "  supported alone, but confounded: it adds nothing where its shape and "
                      "the other's part, the other still does: " + ", ".join(
                          f"{e['name']} (by {e['confounded_with']})" for e in confounded))
    redundant = [e for e in tested if e["supported_alone"] and not e["significant"]
                 and not e.get("confounded_with")]
    if redundant:
        _say(console, "  supported alone, but explained by the selection (evidence left on top "
                      "of it): " + ", ".join(f"{e['name']} {_shrink(e)} ({_left_out(e)})"
                                             for e in redundant))
    odd = [e for e in tested if e.get("implausible")]
    if odd:
        _say(console, "  implausible (fitted beyond physical limits: standing in for something "
                      "the candidates lack) or undetermined: " + ", ".join(
                          f"{e['name']} {_shrink(e)} ({e['implausible']})" for e in odd))
    rest = [e for e in tested if not e["supported_alone"] and not e.get("implausible")]
    if rest:
        _say(console, "  not supported: " + ", ".join(f"{e['name']} {_shrink(e)}{_chance(e)}"
                                                      for e in rest))
    for e in result.effects:
        if e.get("not_tested"):
            _say(console, f"  not testable: {e['name']} ({e['not_tested']})")
    if result.selected:
        _say(console, f"Selected combination: {', '.join(result.selected)}")


def rate_note(result) -> str | None:
    """How a fast recording was scored (apmcal.diagnosis.session.decimate), or None when every
    effect was scored at the recorded rate."""
    rate = result.session["rate_hz"]
    slow = {round(e["scored_at_hz"]) for e in result.effects
            if e.get("scored_at_hz") and e["scored_at_hz"] < 0.9 * rate}
    if not slow:
        return None
    return (f"slow effects scored on the session averaged to {', '.join(map(str, slow))} Hz, "
            f"on top of a low-pass filter when one was found; rounding, the low-pass filter "
            f"and the noise's distribution at the recorded {rate:.0f} Hz, on top of the slow "
            f"effects selected")


def _left_out(e: dict) -> str:
    """What an effect supported alone still adds on top of the selection [nats], and why it
    is not in it when the selection says so."""
    parts = [f"{e.get('evidence_beyond_selection_nats', 0):.0f}"]
    if e.get("stands_in_for"):
        parts.append(f"stands in for {e['stands_in_for']}")
    if e.get("chance_on_top_p_value") is not None:
        parts.append("chance gives as much on sessions drawn from the selection: p "
                     f"{e['chance_on_top_p_value']:.2g}")
    return "; ".join(parts)


def _by_chance(e: dict) -> str:
    """How often chance gives that much evidence on this session (the null sessions of
    apmcal.diagnosis.scoring.null), when they were needed."""
    p = e.get("null_p_value")
    if p is None:
        return ""
    said = "p < 1e-12" if p < 1e-12 else f"p {p:.2g}"
    return f" (by chance: {said} in {e.get('null_sessions', 0)} null sessions)"


def _chance(e: dict) -> str:
    """Why an effect with enough evidence is still not supported: its parameters are all
    within their noise of "off" (Wald test, apmcal.diagnosis.model.wald), or chance gives it
    as much on this session (the null sessions)."""
    if e.get("evidence_nats", 0.0) < MIN_EVIDENCE_NATS:
        return ""
    p = e.get("parameters_p_value")
    if p is not None and p >= MAX_P_VALUE:
        return (f" (evidence {e['evidence_nats']:.0f}, but its parameters are within their "
                f"noise of off: p {p:.2g})")
    p, needed = e.get("null_p_value"), e.get("null_threshold_nats")
    if p is None or needed is None:
        return ""
    return (f" (evidence {e['evidence_nats']:.0f}, but chance gives as much on this session: "
            f"p {p:.2g} in {e.get('null_sessions', 0)} null sessions; it needs {needed:.0f})")


def _shrink(e: dict) -> str:
    v = e.get("shrink_heldout", float("nan"))
    return f"{100 * v:.0f} %" if v is not None and np.isfinite(v) else "-"


def param_text(p: dict) -> str:
    """A fitted parameter as text: "v ± σ" where the fit gives σ, element by element."""
    v = np.asarray(p["value"], dtype=float)
    s = np.asarray(p.get("sigma", np.nan), dtype=float)
    s = s.reshape(v.shape) if s.size == v.size else np.full(v.shape, np.nan)
    if v.ndim == 0:
        return f"{float(v):.4g}" + (f" ± {float(s):.2g}" if np.isfinite(s) else "")
    return "[" + ", ".join(param_text({"value": a, "sigma": b}) for a, b in zip(v, s)) + "]"
