"""The terminal summary of ``apmcal gap``: the verdict first, then where the gap lies and the
candidate effects ranked. Works from the saved result alone (:class:`GapResult`)."""
from __future__ import annotations

import numpy as np
from rich.text import Text


def _pct(part: float, total: float) -> str:
    return f"{100 * part / total:.0f} %" if total > 0 else "-"


def verdict(result) -> str:
    """One sentence: is there a gap, and what closes it."""
    gap = result.gap["heldout"]
    after = result.after["heldout"]
    if not result.selected:
        if gap <= 0 or not any(e["significant"] for e in result.effects):
            return (f"No candidate effect explains the gap (held-out {gap:.2e} nats/sample): "
                    "either the simulator already matches this board, or the gap comes from "
                    "something outside the candidate list.")
    names = ", ".join(result.selected)
    return (f"Modelling {names} shrinks the held-out gap from {gap:.2e} to {after:.2e} "
            f"nats/sample ({_pct(gap - after, gap)} of it).")


def top_parts(parts: dict, total: float, n: int = 3) -> str:
    items = sorted(parts.items(), key=lambda kv: -kv[1])[:n]
    return ", ".join(f"{k} {_pct(v, total)}" for k, v in items if v > 0) or "-"


def print_summary(result, console) -> None:
    s = result.session
    temp = (f"; temperature {s['temperature_c'][0]:.1f}-{s['temperature_c'][1]:.1f} °C"
            if "temperature_c" in s else "")
    console.print(Text(f"apmcal gap — {result.source}", style="bold"))
    console.print(f"{s['duration_s']:.0f} s at {s['rate_hz']:.0f} Hz; {s['holds']} holds, "
                  f"{s['moves']} moves, {s['orientations']} orientations; "
                  f"sensors {', '.join(s['sensors'])}{temp}")
    console.print(Text(verdict(result), style="bold"))
    g = result.gap
    console.print(f"Gap of the nominal model (real vs its simulated twin): in-sample "
                  f"{g['total']:.2e}, held-out {g['heldout']:.2e} nats/sample")
    b, total = g["breakdown_heldout"], g["heldout"]
    for key, what in (("sensor", "by sensor"), ("kind", "holds / moves"),
                      ("band", "by frequency band"), ("segment", "by segment"),
                      ("scale", "within / across pieces"), ("temperature", "by temperature")):
        if key in b:
            console.print(f"  {what}: {top_parts(b[key], total)}")
    print_effects(result, console)
    for note in result.notes:
        console.print(f"note: {note}")


def print_effects(result, console) -> None:
    """Supported effects with their fitted parameters; the rest on one line each."""
    console.print("Candidate effects, each alone on the nominal model (held-out shrink):")
    for e in result.effects:
        if e.get("not_tested") or not e["significant"]:
            continue
        console.print(Text(f"  supported  {e['name']:<21} {_shrink(e):>6}  evidence "
                           f"{e['evidence_nats']:.0f} nats", style="bold"))
        for name, p in e.get("params", {}).items():
            console.print(f"      {name} = {_value_text(p['value'])} {p['unit']}")
    rest = [e for e in result.effects if not e.get("not_tested") and not e["significant"]]
    if rest:
        console.print("  not supported: " + ", ".join(f"{e['name']} {_shrink(e)}" for e in rest))
    for e in result.effects:
        if e.get("not_tested"):
            console.print(f"  not testable: {e['name']} ({e['not_tested']})")
    if result.selected:
        console.print(f"Selected combination: {', '.join(result.selected)}")


def _shrink(e: dict) -> str:
    v = e.get("shrink_heldout", float("nan"))
    return f"{100 * v:.0f} %" if v is not None and np.isfinite(v) else "-"


def _value_text(value) -> str:
    v = np.asarray(value, dtype=float)
    if v.ndim == 0:
        return f"{float(v):.4g}"
    return "[" + ", ".join(_value_text(x) for x in v) + "]"
