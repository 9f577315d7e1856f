"""Flags: what needs doing on which vehicle, with the reason in figures and the next step.

Level "action" flags make ``apmcal fleet`` exit 1; level "info" flags (an intended recalibration)
are reported but do not. Thresholds (module constants) and what each flag means:

- compass: the median heading error (:mod:`apmcal.fleet.health`) of the last
  ``RECENT_FLIGHTS`` flights since the last compass change reaches ``HEADING_LIMIT_DEG``;
- gyro temperature: the pooled gyro bias slope against temperature (:mod:`apmcal.fleet.
  vehicles`) is ``SLOPE_SIGMAS`` σ from zero and moves the bias by ``GYRO_MOVE_LIMIT_DPS`` over
  the board temperatures seen;
- hardware: a sensor's DEV_ID changed between flights;
- accelerometer: the median |specific force| − g in still periods of the recent flights reaches
  ``ACC_NORM_LIMIT_MS2`` (an accelerometer calibration off by that much);
- vibration: the recent flights' median VIBE level reaches ``VIBE_LIMIT_MS2``;
- outlier: a vehicle's median sensor noise is a robust outlier among its type.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

HEADING_LIMIT_DEG = 5.0
RECENT_FLIGHTS = 3
GYRO_MOVE_LIMIT_DPS = 0.15
SLOPE_SIGMAS = 4.0
ACC_NORM_LIMIT_MS2 = 0.3
VIBE_LIMIT_MS2 = 30.0
FLAG_COLUMNS = ["vehicle_id", "level", "kind", "date", "reason", "next_step", "path"]


def _day(ts) -> str:
    return ts.strftime("%Y-%m-%d") if ts is not None and not pd.isna(ts) else "an undated flight"


def _flag(vid, level, kind, reason, next_step, date=None, path=None) -> dict:
    dated = date is not None and not pd.isna(date)
    return {"vehicle_id": vid, "level": level, "kind": kind, "date": _day(date) if dated else "",
            "reason": reason, "next_step": next_step, "path": path or ""}


def compass_flag(vid: str, seg: pd.DataFrame) -> dict | None:
    """"recalibrate the compass" when the recent heading error reaches the limit."""
    if "heading_error_deg" not in seg:
        return None
    he = seg[["heading_error_deg", "heading_error_sigma_deg", "date", "path"]].dropna(
        subset=["heading_error_deg"])
    if len(he) == 0:
        return None
    recent = he.iloc[-RECENT_FLIGHTS:]
    level = float(np.median(recent["heading_error_deg"]))
    if level < HEADING_LIMIT_DEG:
        return None
    last = recent.iloc[-1]
    bound = last["heading_error_deg"] + 1.96 * (last["heading_error_sigma_deg"] or 0.0)
    reason = (f"recalibrate the compass: heading error {level:.1f}° over the last {len(recent)} "
              f"flight(s) (latest {last['heading_error_deg']:.1f}°, 95 % bound {bound:.1f}°), "
              f"was {he.iloc[0]['heading_error_deg']:.1f}° on {_day(he.iloc[0]['date'])}")
    return _flag(vid, "action", "compass_recalibrate", reason,
                 "recalibrate the compass (turns through all orientations), then fly once and "
                 "rerun apmcal fleet", last["date"], last["path"])


def gyro_flag(vid: str, row: dict) -> dict | None:
    """"run apmcal tcal" when the gyro bias moves with temperature beyond the limit."""
    k, s = row.get("gyro_temp_slope_dps_per_c"), row.get("gyro_temp_slope_sigma")
    span = row.get("temp_span_c")
    if k is None or s is None or span is None or not np.isfinite([k, s, span]).all():
        return None
    move = abs(k) * span
    if move < GYRO_MOVE_LIMIT_DPS or abs(k) < SLOPE_SIGMAS * s:
        return None
    reason = (f"run apmcal tcal: gyro bias moves {move:.2f} °/s over {span:.0f} °C "
              f"({row['gyro_temp_axis']} axis, {k:+.4f} ± {s:.4f} °/s per °C)")
    return _flag(vid, "action", "gyro_tcal", reason,
                 "log a warm-up from cold and run apmcal tcal on it, then upload the "
                 "INS_TCAL parameters", row.get("last_date"))


def change_flags(changes: list[dict]) -> list[dict]:
    """Hardware changes (action) and calibration changes (info)."""
    out = []
    recal = {(c["vehicle_id"], c["index"]) for c in changes if c["kind"] == "calibration_changed"}
    for c in changes:
        vid = c["vehicle_id"]
        what = ", ".join(f"{n} {_g(a)} → {_g(b)}" for n, (a, b) in list(c["changes"].items())[:6])
        more = len(c["changes"]) - 6
        what += f" and {more} more" if more > 0 else ""
        if c["kind"] == "hardware_changed":
            redone = (vid, c["index"]) in recal
            step = ("recalibrated on the same flight: check the heading error of the next "
                    "flights" if redone else f"recalibrate the {c['sensor']}: the calibration in "
                    "force was made for the old one")
            out.append(_flag(vid, "action", "hardware_changed",
                             f"{c['sensor']} hardware changed on {_day(c['date'])} ({what})",
                             step, c["date"], c["path"]))
        else:
            out.append(_flag(vid, "info", "calibration_changed",
                             f"calibration changed on {_day(c['date'])}: {what}",
                             "none if intended; compare the health figures before and after",
                             c["date"], c["path"]))
    return out


def _g(v) -> str:
    return f"{v:g}"


def acc_flag(vid: str, flights: pd.DataFrame) -> dict | None:
    """"recalibrate the accelerometers" when |a| − g of the recent flights reaches the limit."""
    if "acc_norm_err_ms2" not in flights:
        return None
    vals = flights["acc_norm_err_ms2"].dropna().iloc[-RECENT_FLIGHTS:]
    if len(vals) == 0 or abs(float(np.median(vals))) < ACC_NORM_LIMIT_MS2:
        return None
    err = float(np.median(vals))
    return _flag(vid, "action", "acc_recalibrate",
                 f"recalibrate the accelerometers: |specific force| is {err:+.2f} m/s² off g in "
                 f"still periods over the last {len(vals)} flight(s)",
                 "run the six-face accelerometer calibration (apmcal live --guide ardupilot6)",
                 flights["date"].iloc[-1], flights["path"].iloc[-1])


def vibration_flag(vid: str, flights: pd.DataFrame) -> dict | None:
    """"reduce vibration" when the recent VIBE level reaches the limit."""
    cols = [c for c in ("vibe_x_ms2", "vibe_y_ms2", "vibe_z_ms2") if c in flights]
    if not cols:
        return None
    worst = flights[cols].max(axis=1).dropna().iloc[-RECENT_FLIGHTS:]
    if len(worst) == 0 or float(np.median(worst)) < VIBE_LIMIT_MS2:
        return None
    return _flag(vid, "action", "vibration",
                 f"reduce vibration: VIBE {float(np.median(worst)):.0f} m/s² over the last "
                 f"{len(worst)} flight(s) (limit {VIBE_LIMIT_MS2:.0f})",
                 "balance the propellers and soft-mount the flight controller",
                 flights["date"].iloc[-1], flights["path"].iloc[-1])


def outlier_flags(outliers: list[dict]) -> list[dict]:
    """A flag per robust noise outlier."""
    names = {"gyro_noise_dps": ("gyro noise", "°/s"), "acc_noise_ms2": ("accelerometer noise", "m/s²")}
    out = []
    for o in outliers:
        name, unit = names.get(o["metric"], (o["metric"], ""))
        out.append(_flag(o["vehicle_id"], "action", "outlier",
                         f"{name} {o['value']:.3g} {unit} is {o['value'] / o['type_median']:.1f}× "
                         f"the median of {o['n_vehicles']} {o['vehicle_type']} vehicles "
                         f"(robust z {o['z']:.0f})",
                         "check the IMU's mounting and the sensor; compare with a spare board"))
    return out


def all_flags(flights: pd.DataFrame, vehicles: pd.DataFrame, changes: list[dict],
              outliers: list[dict]) -> pd.DataFrame:
    """Every flag of the fleet as a table (:data:`FLAG_COLUMNS`), ordered by vehicle and date."""
    from apmcal.fleet.vehicles import since_last_compass_change

    flags = change_flags(changes) + outlier_flags(outliers)
    ok = flights[flights["status"] == "ok"]
    rows = {r["vehicle_id"]: r for r in vehicles.to_dict("records")} if len(vehicles) else {}
    for vid, group in ok.groupby("vehicle_id", sort=True):
        group = group.reset_index(drop=True)
        own = [c for c in changes if c["vehicle_id"] == vid]
        for f in (compass_flag(vid, since_last_compass_change(group, own)),
                  gyro_flag(vid, rows.get(vid, {})), acc_flag(vid, group),
                  vibration_flag(vid, group)):
            if f:
                flags.append(f)
    table = pd.DataFrame(flags, columns=FLAG_COLUMNS)
    return table.sort_values(["vehicle_id", "date", "kind"], kind="stable").reset_index(drop=True)
