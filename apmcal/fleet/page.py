"""DIR/index.html: one self-contained page (no network): the flag table, the failed logs, and
per vehicle its trends as matplotlib PNGs embedded in base64 — heading error, gyro bias
against board temperature, |specific force| − g — with the flights' table.

Plots cost about 0.3 s a vehicle, so the page draws at most :data:`MAX_PLOTTED` vehicles,
those with action flags first; the others keep their table.
"""
from __future__ import annotations

import base64
import html
import io

import numpy as np
import pandas as pd

STYLE = """body{font-family:sans-serif;margin:2em;max-width:75em}table{border-collapse:collapse;
font-size:90%}td,th{border:1px solid #ccc;padding:3px 6px;text-align:left}
.action{background:#fde2e2}.info{background:#e8f0fe}img{max-width:100%}h2{margin-top:2em}"""


MAX_PLOTTED = 100


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=72)    # no bbox_inches="tight": it draws twice
    return base64.b64encode(buf.getvalue()).decode("ascii")


def trend_png(flights: pd.DataFrame, title: str) -> str:
    """Base64 PNG of one vehicle's trends (Agg backend: no display needed)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 3.2))
    axes = fig.subplots(1, 3)
    fig.subplots_adjust(left=0.05, right=0.98, bottom=0.22, top=0.82, wspace=0.25)
    x = flights["date"] if flights["date"].notna().all() else pd.Series(np.arange(len(flights)))
    if "heading_error_deg" in flights:
        axes[0].errorbar(x, flights["heading_error_deg"],
                         yerr=1.96 * flights.get("heading_error_sigma_deg", 0), fmt="o-")
    from apmcal.fleet.flags import HEADING_LIMIT_DEG

    axes[0].axhline(HEADING_LIMIT_DEG, color="tab:red", lw=0.8, ls="--")
    axes[0].set_title("compass heading error [°] (95 %; -- flag limit)")
    for a in "xyz":
        for tag, mark in (("start", "o"), ("end", "s")):
            col = f"gyro_bias_{tag}_{a}_dps"
            if col in flights and f"temp_{tag}_c" in flights:
                axes[1].plot(flights[f"temp_{tag}_c"], flights[col], mark,
                             label=f"{a} {tag}", ms=4)
    axes[1].set_title("gyro bias [°/s] vs board temperature [°C]")
    if axes[1].lines:
        axes[1].legend(fontsize=6, ncol=3)
    if "acc_norm_err_ms2" in flights:
        axes[2].plot(x, flights["acc_norm_err_ms2"], "o-")
    axes[2].set_title("|specific force| − g [m/s²]")
    for ax in axes:
        ax.tick_params(labelsize=7)
        for label in ax.get_xticklabels():
            label.set_rotation(30)
    fig.suptitle(title, fontsize=9)
    return _png(fig)


def _table(df: pd.DataFrame, classes=None) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    rows = []
    for i, r in enumerate(df.itertuples(index=False)):
        cls = f' class="{classes[i]}"' if classes is not None else ""
        rows.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in r) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(rows)}</table>"


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, pd.Timestamp):
        return v.strftime("%Y-%m-%d %H:%M")
    return str(v)


FLIGHT_COLUMNS = ["date", "path", "heading_error_deg", "gyro_bias_start_x_dps", "temp_start_c",
                  "acc_norm_err_ms2", "gyro_noise_dps", "vibe_z_ms2", "notes"]


def write_page(out, flights: pd.DataFrame, vehicles: pd.DataFrame, flags: pd.DataFrame) -> None:
    """Write ``out``/index.html."""
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>apmcal fleet</title>"
             f"<style>{STYLE}</style></head><body><h1>apmcal fleet</h1>",
             f"<p>{len(flights)} logs, {int((flights['status'] == 'ok').sum())} read, "
             f"{len(vehicles)} vehicles, {int((flags['level'] == 'action').sum())} action flags."
             f"</p><h2>Flags</h2>"]
    parts.append(_table(flags, list(flags["level"])) if len(flags) else "<p>none</p>")
    bad = flights[flights["status"] != "ok"]
    if len(bad):
        parts.append("<h2>Logs not read</h2>" + _table(bad[["path", "reason"]]))
    flagged = set(flags.loc[flags["level"] == "action", "vehicle_id"])
    groups = sorted(flights[flights["status"] == "ok"].groupby("vehicle_id", sort=True),
                    key=lambda g: (g[0] not in flagged, str(g[0])))
    for n, (vid, group) in enumerate(groups):
        group = group.reset_index(drop=True)
        parts.append(f"<h2>{html.escape(str(vid))}</h2>")
        if n < MAX_PLOTTED:
            parts.append(f"<img alt='trends of {html.escape(str(vid))}' src='data:image/png;"
                         f"base64,{trend_png(group, str(vid))}'>")
        cols = [c for c in FLIGHT_COLUMNS if c in group]
        parts.append(_table(group[cols]))
    parts.append("</body></html>")
    (out / "index.html").write_text("\n".join(parts), encoding="utf-8")
