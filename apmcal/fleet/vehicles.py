"""Per vehicle: the flights in time order, change points, drift rates with σ, and robust
outliers against the other vehicles of the same type.

- flights: each vehicle's read logs in date order (else by file name), numbered from 1
  (``flight``);
- change points: between consecutive flights, a calibration parameter with a new value
  (:func:`apmcal.fleet.identity.compares_as_change`: the boot gyro offsets excluded) or a
  sensor's DEV_ID with a new value (the hardware changed; 0 = no sensor); a parameter logged in
  only one of the two flights is no change; and a compass's hard iron, as the flight compass
  check fits it, moved between flights (:func:`hard_iron_moves`: the compass's surroundings
  changed);
- drift rates: least-squares slopes over time [per day] with their standard errors, over the
  flights since the last compass calibration change;
- gyro temperature sensitivity: the slope of the gyro bias against board temperature between
  the first and last still period of each flight, pooled over flights (a line through the
  origin of Δbias against ΔT) [°/s per °C] with its σ;
- outliers: robust z-scores (median and 1.4826·MAD, the MAD floored at 10 % of the median) of
  each vehicle's median noise against its type's; an outlier also lies at least
  ``OUTLIER_RATIO`` times the type's median (a gyro that drifts with temperature inflates its
  still-period spread by tens of per cent, not by a factor of two).
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd

from apmcal.fleet.identity import compares_as_change, sensor_of

REL_TOL = 1e-5                 # a parameter "changed" beyond this relative difference
OUTLIER_Z = 5.0
OUTLIER_RATIO = 2.0            # and at least this many times the type's median
OUTLIER_MIN_VEHICLES = 5
MAD_FLOOR = 0.10
OUTLIER_METRICS = ("gyro_noise_dps", "acc_noise_ms2")
# a hard iron "moved" when some axis moved more than HARD_IRON_SIGMAS combined σ of the two
# flights' fits, and those axes together by at least what costs compass_heading.GOOD_DEG of
# heading across the horizontal field: the fits' σ alone are optimistic on short flights
# (fits of one untouched vehicle scatter by a few σ), and a smaller move keeps a good
# calibration good
HARD_IRON_SIGMAS = 3.0
MAX_COMPASSES = 3


def flights_table(records: list[dict]) -> pd.DataFrame:
    """All records, one row per log, ordered by vehicle, date (else file name) and path."""
    df = pd.DataFrame(records)
    for col in ("start_unix_s", "vehicle_id", "status", "reason", "cached"):
        if col not in df:
            df[col] = None
    df["date"] = pd.to_datetime(df["start_unix_s"], unit="s", utc=True)
    df = df.sort_values(["vehicle_id", "start_unix_s", "path"], na_position="last",
                        kind="stable").reset_index(drop=True)
    ok = df["status"] == "ok"
    df["flight"] = pd.Series(pd.NA, index=df.index, dtype="Int64")
    df.loc[ok, "flight"] = df[ok].groupby("vehicle_id", sort=False).cumcount() + 1
    return df


def _changed(old: dict, new: dict, keep) -> dict:
    """Parameters logged in both flights whose values differ, name → (old, new). A parameter
    logged in only one of them is no change: another firmware logs another set."""
    out = {}
    for name in sorted(set(old) & set(new)):
        a, b = old[name], new[name]
        if keep(name) and abs(a - b) > REL_TOL * max(abs(a), abs(b), 1e-3):
            out[name] = (a, b)
    return out


def change_points(flights: pd.DataFrame) -> list[dict]:
    """Calibration changes and hardware changes between consecutive flights of one vehicle.

    Returns
    -------
    list of dict
        kind ("calibration_changed" or "hardware_changed"), vehicle_id, index (position in
        ``flights`` of the first flight after the change), date, path, changes {name: (old, new)}
        and for hardware the sensor.
    """
    out = []
    rows = flights.to_dict("records")
    for prev, cur, i in zip(rows, rows[1:], range(1, len(rows))):
        cal = _changed(json.loads(prev["calibration_json"]), json.loads(cur["calibration_json"]),
                       compares_as_change)
        dev = _changed(json.loads(prev["dev_ids_json"]), json.loads(cur["dev_ids_json"]),
                       lambda n: True)
        base = {"vehicle_id": cur["vehicle_id"], "index": i, "date": cur["date"],
                "path": cur["path"]}
        if cal:
            out.append(dict(base, kind="calibration_changed", changes=cal))
        for sensor in sorted({sensor_of(n) for n in dev}):
            out.append(dict(base, kind="hardware_changed", sensor=sensor,
                            changes={n: v for n, v in dev.items() if sensor_of(n) == sensor}))
    return out + hard_iron_moves(flights)


def _hard_iron(row: dict, instance: int) -> tuple[np.ndarray, np.ndarray] | None:
    k = f"compass{instance}_hard_iron"
    try:
        v = np.array([row[f"{k}_{a}_mgauss"] for a in "xyz"], dtype=float)
        s = np.array([row[f"{k}_sigma_{a}_mgauss"] for a in "xyz"], dtype=float)
    except KeyError:
        return None
    return (v, s) if np.isfinite(v).all() and np.isfinite(s).all() else None


def hard_iron_moves(flights: pd.DataFrame) -> list[dict]:
    """Compasses whose fitted hard iron moved between consecutive flights that fitted it (see
    :data:`HARD_IRON_SIGMAS`): kind "hard_iron_moved", compass, index, date, path, the move
    [mGauss], its combined σ, the flight it is measured from, and the heading it is worth [deg]
    (asin(|move| / horizontal field))."""
    from apmcal.solvers.compass_heading import GOOD_DEG

    out = []
    rows = flights.to_dict("records")
    for inst in range(MAX_COMPASSES):
        last = None
        for i, row in enumerate(rows):
            fit = _hard_iron(row, inst)
            if fit is None:
                continue
            if last is not None:
                j, (v0, s0) = last
                move, sigma = fit[0] - v0, np.hypot(fit[1], s0)
                beyond = np.abs(move) > HARD_IRON_SIGMAS * sigma
                size = float(np.linalg.norm(move[beyond]))
                b_h = row.get("wmm_horizontal_mgauss")
                b_h = float(b_h) if b_h is not None and np.isfinite(b_h) else np.nan
                worth = float(np.degrees(np.arcsin(min(size / b_h, 1.0)))) if b_h > 0 else np.nan
                if beyond.any() and worth >= GOOD_DEG:
                    out.append({"vehicle_id": row["vehicle_id"], "kind": "hard_iron_moved",
                                "compass": inst, "index": i, "date": row["date"],
                                "path": row["path"], "from_index": j, "move": move.tolist(),
                                "sigma": sigma.tolist(), "heading_deg": worth})
            last = (i, fit)
    return out


def slope_sigma(x, y) -> tuple[float, float]:
    """Least-squares slope of y on x and its standard error (nan when fewer than 3 points)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) < 3 or np.ptp(x) == 0:
        return float("nan"), float("nan")
    A = np.column_stack([x - x.mean(), np.ones(len(x))])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    s2 = r @ r / (len(x) - 2)
    return float(coef[0]), float(np.sqrt(s2 / np.sum((x - x.mean()) ** 2)))


def gyro_temperature_slope(flights: pd.DataFrame) -> dict:
    """Pooled within-flight slope of gyro bias against temperature [°/s/°C], per axis, its σ,
    the largest |slope| axis, and the board temperatures' span over the flights [°C]."""
    need = ["temp_start_c", "temp_end_c"] + [f"gyro_bias_{t}_{a}_dps" for t in ("start", "end")
                                            for a in "xyz"]
    if not all(c in flights for c in need):
        return {}
    f = flights.dropna(subset=need)
    dt = (f["temp_end_c"] - f["temp_start_c"]).to_numpy(float)
    use = np.abs(dt) >= 1.0
    if use.sum() < 2:
        return {}
    dt = dt[use]
    best: dict = {}
    for a in "xyz":
        db = (f[f"gyro_bias_end_{a}_dps"] - f[f"gyro_bias_start_{a}_dps"]).to_numpy(float)[use]
        k = float(dt @ db / (dt @ dt))
        r = db - k * dt
        sigma = float(np.sqrt((r @ r) / max(len(dt) - 1, 1) / (dt @ dt)))
        if not best or abs(k) > abs(best["gyro_temp_slope_dps_per_c"]):
            best = {"gyro_temp_slope_dps_per_c": k, "gyro_temp_slope_sigma": sigma,
                    "gyro_temp_axis": a}
    temps = np.concatenate([f["temp_start_c"].to_numpy(float), f["temp_end_c"].to_numpy(float)])
    best["temp_span_c"] = float(np.ptp(temps))
    return best


def since_last_compass_change(flights: pd.DataFrame, changes: list[dict]) -> pd.DataFrame:
    """The flights after the last change of a COMPASS_* calibration, of the compass hardware or
    of its surroundings (a hard iron that moved)."""
    start = 0
    for c in changes:
        if c["kind"] == "hard_iron_moved":
            start = max(start, c["index"])
        if c["kind"] == "hardware_changed" and c.get("sensor") == "compass":
            start = max(start, c["index"])
        if c["kind"] == "calibration_changed" and any(n.startswith("COMPASS") for n in c["changes"]):
            start = max(start, c["index"])
    return flights.iloc[start:]


def vehicle_summary(vid: str, flights: pd.DataFrame, changes: list[dict]) -> dict:
    """One vehicles.parquet row: counts, dates, latest figures, drift rates with σ."""
    last = flights.iloc[-1]
    row = {"vehicle_id": vid, "vehicle_type": last.get("vehicle_type"),
           "board": last.get("board"), "uid": last.get("uid"), "sysid": last.get("sysid"),
           "firmware": last.get("firmware"), "frame": last.get("frame"),
           "flights": len(flights), "first_date": flights["date"].min(),
           "last_date": flights["date"].max(),
           "calibration_changes": sum(c["kind"] == "calibration_changed" for c in changes),
           "hardware_changes": sum(c["kind"] == "hardware_changed" for c in changes),
           "identified_by": identified_by(flights)}
    for col in ("heading_error_deg", "acc_norm_err_ms2", "gyro_noise_dps", "acc_noise_ms2",
                "vibe_x_ms2", "vibe_y_ms2", "vibe_z_ms2"):
        if col in flights:
            vals = flights[col].to_numpy(float)
            row[f"{col}_last"] = float(vals[-1]) if len(vals) else float("nan")
            row[f"{col}_median"] = float(np.nanmedian(vals)) if np.isfinite(vals).any() else float("nan")
    seg = since_last_compass_change(flights, changes)
    days = (seg["start_unix_s"].to_numpy(float) - np.nanmin(flights["start_unix_s"].to_numpy(float))
            ) / 86400.0 if flights["start_unix_s"].notna().all() else np.arange(len(seg), dtype=float)
    for col in ("heading_error_deg", "mag_residual_horizontal_mgauss"):
        if col in seg:
            k, s = slope_sigma(days, seg[col].to_numpy(float))
            row[f"{col}_per_day"], row[f"{col}_per_day_sigma"] = k, s
    row.update(gyro_temperature_slope(flights))
    return row


def identified_by(flights: pd.DataFrame) -> str:
    """How a vehicle's logs were identified, in words, with counts when they differ."""
    if "identified_by" not in flights:
        return ""
    counts = flights["identified_by"].fillna("?").value_counts(sort=True)
    if len(counts) == 1:
        return str(counts.index[0])
    return "; ".join(f"{how}: {n} log{'s' if n > 1 else ''}" for how, n in counts.items())


def robust_outliers(vehicles: pd.DataFrame) -> list[dict]:
    """Vehicles whose median noise lies more than OUTLIER_Z robust σ above their type's and at
    least OUTLIER_RATIO times it."""
    out = []
    for vtype, group in vehicles.groupby("vehicle_type"):
        if len(group) < OUTLIER_MIN_VEHICLES:
            continue
        for metric in OUTLIER_METRICS:
            col = f"{metric}_median"
            if col not in group:
                continue
            vals = group[col].to_numpy(float)
            ok = np.isfinite(vals)
            if ok.sum() < OUTLIER_MIN_VEHICLES:
                continue
            med = float(np.median(vals[ok]))
            mad = max(1.4826 * float(np.median(np.abs(vals[ok] - med))), MAD_FLOOR * abs(med), 1e-12)
            for vid, v in zip(group["vehicle_id"], vals):
                if np.isfinite(v) and (v - med) / mad > OUTLIER_Z and v >= OUTLIER_RATIO * med:
                    out.append({"vehicle_id": vid, "vehicle_type": vtype, "metric": metric,
                                "value": float(v), "type_median": med, "z": (v - med) / mad,
                                "n_vehicles": int(ok.sum())})
    return out


def analyse(flights: pd.DataFrame) -> tuple[pd.DataFrame, list[dict], list[dict]]:
    """(vehicles table, change points, outliers) of the "ok" flights, grouped by vehicle."""
    ok = flights[flights["status"] == "ok"]
    rows, changes = [], []
    for vid, group in ok.groupby("vehicle_id", sort=True):
        group = group.reset_index(drop=True)
        cps = change_points(group)
        changes += cps
        rows.append(vehicle_summary(vid, group, cps))
    vehicles = pd.DataFrame(rows)
    outliers = robust_outliers(vehicles) if len(vehicles) else []
    return vehicles, changes, outliers
