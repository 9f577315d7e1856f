"""DIR/index.html: one self-contained page (no network): the flag table, the logs not read, and
per vehicle how it was identified, its trends as matplotlib PNGs embedded in base64 and its
flights' table, with labels and dates in words.

A trend is drawn only where it has something to show: a panel per figure measured on at least
:data:`MIN_FLIGHTS` flights of the vehicle (compass heading error, the compass's fitted hard
iron, |specific force| − g) or, for the gyro bias against board temperature, at least two
temperatures :data:`MIN_TEMP_SPAN_C` apart; a vehicle with no such figure gets no image.

Plots cost about 0.3 s a vehicle, so the page draws at most :data:`MAX_PLOTTED` vehicles,
those with action flags first; the others keep their table.
"""
from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np
import pandas as pd

STYLE = """body{font-family:sans-serif;margin:2em;max-width:75em}table{border-collapse:collapse;
font-size:90%}td,th{border:1px solid #ccc;padding:3px 6px;text-align:left}
.action{background:#fde2e2}.info{background:#e8f0fe}img{max-width:100%}h2{margin-top:2em}"""

MAX_PLOTTED = 100
MIN_FLIGHTS = 2
MIN_TEMP_SPAN_C = 1.0

# flights-table column → its label on the page
FLIGHT_COLUMNS = {"flight": "flight", "date": "date", "path": "log",
                  "heading_error_deg": "compass heading error [°]",
                  "heading_error_method": "measured as",
                  "acc_norm_err_ms2": "|specific force| − g [m/s²]",
                  "gyro_bias_start_x_dps": "gyro bias x at start [°/s]",
                  "temp_start_c": "board temperature at start [°C]",
                  "gyro_noise_dps": "gyro noise [°/s]", "vibe_z_ms2": "vibration z [m/s²]",
                  "notes": "notes"}
FLAG_COLUMNS = {"level": "level", "kind": "what", "flight": "flight", "date": "date",
                "reason": "reason", "next_step": "next step", "path": "log"}
KINDS = {"compass_recalibrate": "compass heading", "compass_surroundings": "compass surroundings",
         "hardware_changed": "hardware changed", "calibration_changed": "calibration changed",
         "acc_recalibrate": "accelerometer", "gyro_tcal": "gyro temperature",
         "vibration": "vibration", "outlier": "noise outlier"}
METHODS = {"flight": "95 % along the flight", "sphere": "worst over headings"}


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=72)    # no bbox_inches="tight": it draws twice
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _enough(flights: pd.DataFrame, col: str) -> bool:
    return col in flights and int(flights[col].notna().sum()) >= MIN_FLIGHTS


def _temperature_pairs(flights: pd.DataFrame) -> list[tuple[str, str, str]]:
    """(temperature column, bias column, label) of the gyro bias points with a temperature."""
    return [(f"temp_{tag}_c", f"gyro_bias_{tag}_{a}_dps", f"{a} {tag}")
            for a in "xyz" for tag in ("start", "end")
            if f"temp_{tag}_c" in flights and f"gyro_bias_{tag}_{a}_dps" in flights]


def _temperature_span(flights: pd.DataFrame) -> float:
    temps = np.concatenate([flights[c].to_numpy(float) for c in ("temp_start_c", "temp_end_c")
                            if c in flights] or [np.array([])])
    temps = temps[np.isfinite(temps)]
    return float(np.ptp(temps)) if len(temps) else 0.0


def trend_panels(flights: pd.DataFrame) -> list[str]:
    """The panels one vehicle's flights have data for: "heading", "hard_iron", "gyro_temp",
    "acc" (see the module docstring)."""
    panels = []
    if _enough(flights, "heading_error_deg"):
        panels.append("heading")
    if any(_enough(flights, f"compass{i}_hard_iron_x_mgauss") for i in range(3)):
        panels.append("hard_iron")
    if _temperature_pairs(flights) and _temperature_span(flights) >= MIN_TEMP_SPAN_C:
        panels.append("gyro_temp")
    if _enough(flights, "acc_norm_err_ms2"):
        panels.append("acc")
    return panels


def _x(flights: pd.DataFrame):
    """Dates when every flight has one, else the flight numbers; and the axis label."""
    if flights["date"].notna().all():
        return flights["date"], "date (UTC)"
    return flights["flight"].astype(float), "flight (undated flights: by file name)"


def _draw(ax, panel: str, flights: pd.DataFrame) -> None:
    from apmcal.fleet.flags import ACC_NORM_LIMIT_MS2, HEADING_LIMIT_DEG

    x, xlabel = _x(flights)
    if panel == "heading":
        ax.plot(x, flights["heading_error_deg"], "o-")
        ax.axhline(HEADING_LIMIT_DEG, color="tab:red", lw=0.8, ls="--", label="usable limit")
        ax.legend(fontsize=6)
        ax.set_title("compass heading error [°]", fontsize=9)
    elif panel == "hard_iron":
        for i in range(3):
            if _enough(flights, f"compass{i}_hard_iron_x_mgauss"):
                for a, mark in zip("xyz", "os^"):
                    ax.plot(x, flights[f"compass{i}_hard_iron_{a}_mgauss"], mark + "-",
                            label=f"compass {i} {a}", ms=4)
        ax.legend(fontsize=6, ncol=3)
        ax.set_title("hard iron fitted in flight [mGauss]", fontsize=9)
    elif panel == "gyro_temp":
        for tcol, bcol, label in _temperature_pairs(flights):
            ax.plot(flights[tcol], flights[bcol], "o" if "start" in tcol else "s", label=label,
                    ms=4)
        ax.legend(fontsize=6, ncol=3)
        ax.set_title("gyro bias [°/s]", fontsize=9)
        xlabel = "board temperature [°C]"
    else:
        ax.plot(x, flights["acc_norm_err_ms2"], "o-")
        for sign in (-1, 1):
            ax.axhline(sign * ACC_NORM_LIMIT_MS2, color="tab:red", lw=0.8, ls="--",
                       label="flag limit" if sign > 0 else None)
        ax.legend(fontsize=6)
        ax.set_title("|specific force| − g at rest [m/s²]", fontsize=9)
    ax.set_xlabel(xlabel, fontsize=7)


def trend_png(flights: pd.DataFrame, title: str) -> str | None:
    """Base64 PNG of one vehicle's trends (Agg backend: no display needed), the panels of
    :func:`trend_panels`; None when there are none."""
    from matplotlib.figure import Figure

    panels = trend_panels(flights)
    if not panels:
        return None
    fig = Figure(figsize=(4.0 * len(panels), 3.4))
    axes = np.atleast_1d(fig.subplots(1, len(panels)))
    fig.subplots_adjust(left=0.08 if len(panels) > 1 else 0.15, right=0.98, bottom=0.27,
                        top=0.82, wspace=0.3)
    for ax, panel in zip(axes, panels):
        _draw(ax, panel, flights)
        ax.tick_params(labelsize=7)
        for label in ax.get_xticklabels():
            label.set_rotation(30)
    fig.suptitle(title, fontsize=9)
    return _png(fig)


def _when(v) -> str:
    """A date and time in words ("4 Mar 2026 09:00 UTC"), "undated" without one."""
    if v is None or pd.isna(v):
        return "undated"
    return f"{v.day} {v.strftime('%b %Y %H:%M')} UTC"


def _fmt(v) -> str:
    if v is None or v is pd.NA or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if isinstance(v, (float, np.floating)):
        return f"{v:.4g}"
    return str(v)


def _table(df: pd.DataFrame, labels: dict[str, str], classes=None) -> str:
    cols = [c for c in labels if c in df]
    head = "".join(f"<th>{html.escape(labels[c])}</th>" for c in cols)
    rows = []
    for i, r in enumerate(df[cols].to_dict("records")):
        cls = f' class="{classes[i]}"' if classes is not None else ""
        rows.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(_cell(c, r[c]))}</td>"
                                           for c in cols) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(rows)}</table>"


def _cell(col: str, v) -> str:
    if col == "date" and isinstance(v, str):          # a flag's day, "YYYY-MM-DD"
        return f"{pd.Timestamp(v).day} {pd.Timestamp(v).strftime('%b %Y')}" if v else ""
    if col == "date":
        return _when(v)
    if col == "path":
        return Path(v).name if isinstance(v, str) and v else ""
    if col == "kind":
        return KINDS.get(v, str(v))
    if col == "heading_error_method":
        return METHODS.get(v, "") if isinstance(v, str) else ""
    return _fmt(v)


def _vehicle_line(row: dict) -> str:
    parts = [f"identified by {row.get('identified_by') or '?'}", f"{row['flights']} flight(s)"]
    if row.get("firmware"):
        parts.append(str(row["firmware"]))
    if row.get("first_date") is not None and not pd.isna(row.get("first_date")):
        parts.append(f"{_when(row['first_date'])} to {_when(row['last_date'])}")
    return "<p>" + html.escape("; ".join(parts)) + "</p>"


def write_page(out, flights: pd.DataFrame, vehicles: pd.DataFrame, flags: pd.DataFrame) -> None:
    """Write ``out``/index.html."""
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>apmcal fleet</title>"
             f"<style>{STYLE}</style></head><body><h1>apmcal fleet</h1>",
             f"<p>{len(flights)} logs, {int((flights['status'] == 'ok').sum())} read, "
             f"{len(vehicles)} vehicles, {int((flags['level'] == 'action').sum())} action flags."
             f"</p><h2>Flags</h2>"]
    if len(flags):
        parts.append(_table(flags, {"vehicle_id": "vehicle", **FLAG_COLUMNS},
                            list(flags["level"])))
    else:
        parts.append("<p>none</p>")
    bad = flights[flights["status"] != "ok"]
    if len(bad):
        parts.append("<h2>Logs not read</h2>" + _table(bad, {"path": "log",
                                                             "reason": "why not read"}))
    about = {r["vehicle_id"]: r for r in vehicles.to_dict("records")} if len(vehicles) else {}
    flagged = set(flags.loc[flags["level"] == "action", "vehicle_id"])
    groups = sorted(flights[flights["status"] == "ok"].groupby("vehicle_id", sort=True),
                    key=lambda g: (g[0] not in flagged, str(g[0])))
    for n, (vid, group) in enumerate(groups):
        group = group.reset_index(drop=True)
        parts.append(f"<h2>{html.escape(str(vid))}</h2>")
        if vid in about:
            parts.append(_vehicle_line(about[vid]))
        png = trend_png(group, str(vid)) if n < MAX_PLOTTED else None
        if png:
            parts.append(f"<img alt='trends of {html.escape(str(vid))}' "
                         f"src='data:image/png;base64,{png}'>")
        parts.append(_table(group, FLIGHT_COLUMNS))
    parts.append("</body></html>")
    (out / "index.html").write_text("\n".join(parts), encoding="utf-8")
