"""Flags: what needs doing on which vehicle, with the reason in figures and the next step.

Level "action" flags make ``apmcal fleet`` exit 1; level "info" flags (an intended recalibration)
are reported but do not. Thresholds (module constants) and what each flag means:

Every flag about a vehicle's state is judged from that vehicle's own flights in date order, over
the flights since the last change of what it judges (a compass recalibration, a new compass, its
hard iron moved): the latest flight and the median of the last ``RECENT_FLIGHTS`` must both pass
the limit (one odd flight neither raises nor hides a flag); the flag names the flight where the
state began (``flight``, ``date``, ``path``).

- compass: the median heading error (:mod:`apmcal.calibration.health`: on a flight the flight
  compass check's 95 % heading error of the calibration in force, worst compass in use, the
  figure ``apmcal log FLIGHT`` prints) of the last ``RECENT_FLIGHTS`` flights since the last
  compass change passes usable (``HEADING_LIMIT_DEG`` =
  :data:`apmcal.solvers.compass_heading.USABLE_DEG`); the next step is the flight's own fit
  (``apmcal log FLIGHT --param-file``) when its proposal grades usable or better, else a
  compass calibration;
- compass surroundings: a compass's fitted hard iron moved between flights beyond its σ and by
  a heading-relevant amount (:func:`apmcal.fleet.vehicles.hard_iron_moves`); an action unless
  the compass was recalibrated on that flight;
- gyro temperature: the pooled gyro bias slope against temperature (:mod:`apmcal.fleet.
  vehicles`) is ``SLOPE_SIGMAS`` σ from zero and moves the bias by ``GYRO_MOVE_LIMIT_DPS`` over
  the board temperatures seen;
- hardware: a sensor's DEV_ID changed between flights;
- calibration changed (info): with the health before and after (heading error for a compass,
  |a| − g for the accelerometers) on the flight where it happened;
- accelerometer: the median |specific force| − g in still periods of the recent flights reaches
  ``ACC_NORM_LIMIT_MS2`` (an accelerometer calibration off by that much);
- vibration: the recent flights' median VIBE level reaches ``VIBE_LIMIT_MS2``;
- outlier: a vehicle's median sensor noise is a robust outlier among its type.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from apmcal.solvers.compass_heading import USABLE_DEG

HEADING_LIMIT_DEG = USABLE_DEG
RECENT_FLIGHTS = 3
GYRO_MOVE_LIMIT_DPS = 0.15
SLOPE_SIGMAS = 4.0
ACC_NORM_LIMIT_MS2 = 0.3
VIBE_LIMIT_MS2 = 30.0
FLAG_COLUMNS = ["vehicle_id", "level", "kind", "date", "flight", "reason", "next_step", "path"]


def _day(ts) -> str:
    """A date in words ("4 Mar 2026"), "undated" without one."""
    if ts is None or pd.isna(ts):
        return "undated"
    return f"{ts.day} {ts.strftime('%b %Y')}"


def flight_name(row) -> str:
    """"flight 3 (4 Mar 2026)" of a flights-table row (a dict or a Series)."""
    return f"flight {int(row['flight'])} ({_day(row['date'])})"


def _flag(vid, level, kind, reason, next_step, at=None) -> dict:
    """One flag; ``at`` the flights-table row of the flight it names (None: the vehicle)."""
    if at is None:
        return {"vehicle_id": vid, "level": level, "kind": kind, "date": "", "flight": None,
                "reason": reason, "next_step": next_step, "path": ""}
    date = at["date"]
    return {"vehicle_id": vid, "level": level, "kind": kind,
            "date": date.strftime("%Y-%m-%d") if not pd.isna(date) else "",
            "flight": int(at["flight"]), "reason": reason, "next_step": next_step,
            "path": at["path"]}


def onset(values: pd.Series, over) -> int:
    """Position of the first of the trailing values for which ``over(value)`` holds (the flight
    where the present state began); the last position when the last value does not hold."""
    start = len(values) - 1
    while start > 0 and over(values.iloc[start - 1]):
        start -= 1
    return start


def _bad_compasses(row, limit: float) -> list[tuple[int, float]]:
    """(instance, 95 % heading error) of the compasses in use past ``limit`` on one flight."""
    out = []
    for i in range(3):
        v, use = row.get(f"compass{i}_heading_p95_deg"), row.get(f"compass{i}_in_use", True)
        if v is not None and np.isfinite(v) and v > limit and use is not False:
            out.append((i, float(v)))
    return out


def _fit_is_usable(row, compasses) -> bool:
    """True when the flight's own fit of every compass in ``compasses`` grades usable or better."""
    return bool(compasses) and all(row.get(f"compass{i}_proposed_verdict") in ("good", "usable")
                                   for i, _ in compasses)


def compass_flag(vid: str, seg: pd.DataFrame) -> dict | None:
    """"recalibrate the compass" when the recent heading error passes usable."""
    if "heading_error_deg" not in seg:
        return None
    he = seg.dropna(subset=["heading_error_deg"])
    if len(he) == 0:
        return None
    recent = he.iloc[-RECENT_FLIGHTS:]
    level = float(np.median(recent["heading_error_deg"]))
    if level <= HEADING_LIMIT_DEG or recent["heading_error_deg"].iloc[-1] <= HEADING_LIMIT_DEG:
        return None
    first = he.iloc[onset(he["heading_error_deg"], lambda v: v > HEADING_LIMIT_DEG)]
    last = recent.iloc[-1].to_dict()
    bad = _bad_compasses(last, HEADING_LIMIT_DEG)
    which = ", ".join(f"compass {i} {v:.1f}°" for i, v in bad)
    method = ("95 % along the flight" if last.get("heading_error_method") == "flight"
              else "worst over headings")
    reason = (f"compass heading error past usable ({HEADING_LIMIT_DEG:g}°) since "
              f"{flight_name(first)}: {last['heading_error_deg']:.1f}° ({method}) on the latest, "
              f"{flight_name(last)}{' — ' + which if which else ''}; median {level:.1f}° over "
              f"the last {len(recent)} flight(s)")
    if last.get("heading_error_method") == "flight" and _fit_is_usable(last, bad):
        step = (f"write this flight's own fit: apmcal log {last['path']} --param-file cal.param, "
                "then apmcal upload LINK cal.param (or calibrate the compass)")
    else:
        step = ("calibrate the compass (turn it through every direction: the onboard compass "
                "calibration), then fly once and rerun apmcal fleet")
    return _flag(vid, "action", "compass_recalibrate", reason, step, first)


def _vector(v: list[float], fmt: str = "+.0f") -> str:
    return "(" + ", ".join(format(x, fmt).replace("-", "−") for x in v) + ")"


def hard_iron_flags(flights: pd.DataFrame, changes: list[dict]) -> list[dict]:
    """A flag per hard iron that moved: action, unless its compass was recalibrated on the
    flight where it moved (then info)."""
    out = []
    for c in (c for c in changes if c["kind"] == "hard_iron_moved"):
        at, before = flights.iloc[c["index"]], flights.iloc[c["from_index"]]
        recal = _recalibrated(changes, c["index"], "compass")
        reason = (f"compass {c['compass']}'s surroundings changed: its hard iron moved by "
                  f"{_vector(c['move'])} mGauss from {flight_name(before)} to {flight_name(at)} "
                  f"(σ {_vector(c['sigma'], '.1f')}), worth {c['heading_deg']:.0f}° of heading")
        if recal:
            out.append(_flag(c["vehicle_id"], "info", "compass_surroundings",
                             reason + "; the compass was recalibrated on that flight",
                             "none if the change was intended", at))
        else:
            out.append(_flag(c["vehicle_id"], "action", "compass_surroundings", reason,
                             f"undo what changed near the compass, or recalibrate it for its new "
                             f"surroundings (apmcal log {at['path']} --param-file cal.param, or a "
                             "compass calibration)", at))
    return out


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
                 "INS_TCAL parameters")


def _before_after(flights: pd.DataFrame, index: int, col: str, fmt: str) -> str | None:
    """"<before> → <after>" of a figure across the change at ``index``: the last flight before
    it that has the figure, and the flight itself; None when either lacks it."""
    if col not in flights:
        return None
    before = flights[col].iloc[:index].dropna()
    after = flights[col].iloc[index]
    if len(before) == 0 or after is None or pd.isna(after):
        return None
    return f"{format(float(before.iloc[-1]), fmt)} → {format(float(after), fmt)}"


def _health_change(flights: pd.DataFrame, index: int, names) -> str:
    """The health before and after a calibration change, for the sensors it touched."""
    parts = []
    if any(n.startswith("COMPASS") for n in names):
        ba = _before_after(flights, index, "heading_error_deg", ".1f")
        if ba:
            parts.append(f"compass heading error {ba.replace(' →', '° →')}°")
    if any(n.startswith("INS_ACC") for n in names):
        ba = _before_after(flights, index, "acc_norm_err_ms2", "+.2f")
        if ba:
            parts.append(f"|specific force| − g {ba} m/s²")
    return "; health before → after: " + ", ".join(parts) if parts else ""


# the parameters a calibration of each sensor writes (the flags on the slot, orientation and
# boot offsets are not a calibration by the user)
CALIBRATION_OF = {"compass": ("COMPASS_OFS", "COMPASS_DIA", "COMPASS_ODI", "COMPASS_MOT"),
                  "accelerometer": ("INS_ACCOFFS", "INS_ACCSCAL", "INS_ACC2OFFS",
                                    "INS_ACC2SCAL", "INS_ACC3OFFS", "INS_ACC3SCAL"),
                  "gyro": ("INS_TCAL",)}


def _recalibrated(changes: list[dict], index: int, sensor: str) -> bool:
    """True when a calibration of ``sensor`` changed on the flight at ``index``."""
    return any(c["kind"] == "calibration_changed" and c["index"] == index
               and any(n.startswith(CALIBRATION_OF[sensor]) for n in c["changes"])
               for c in changes)


def change_flags(flights: pd.DataFrame, changes: list[dict]) -> list[dict]:
    """Hardware changes (action) and calibration changes (info, with the health before and
    after) of one vehicle, on the flight where they happened."""
    out = []
    for c in changes:
        if c["kind"] not in ("hardware_changed", "calibration_changed"):
            continue
        vid, at = c["vehicle_id"], flights.iloc[c["index"]]
        what = ", ".join(f"{n} {_g(a)} → {_g(b)}" for n, (a, b) in list(c["changes"].items())[:6])
        more = len(c["changes"]) - 6
        what += f" and {more} more" if more > 0 else ""
        if c["kind"] == "hardware_changed":
            step = ("recalibrated on the same flight: check the health of the next flights"
                    if _recalibrated(changes, c["index"], c["sensor"]) else
                    f"recalibrate the {c['sensor']}: the calibration in force was made for the "
                    "old one")
            out.append(_flag(vid, "action", "hardware_changed",
                             f"{c['sensor']} hardware changed on {flight_name(at)} ({what})",
                             step, at))
        else:
            out.append(_flag(vid, "info", "calibration_changed",
                             f"calibration changed on {flight_name(at)}: {what}"
                             f"{_health_change(flights, c['index'], c['changes'])}",
                             "none if intended", at))
    return out


def _g(v) -> str:
    return f"{v:g}"


def acc_flag(vid: str, flights: pd.DataFrame) -> dict | None:
    """"recalibrate the accelerometers" when |a| − g of the recent flights reaches the limit."""
    if "acc_norm_err_ms2" not in flights:
        return None
    have = flights.dropna(subset=["acc_norm_err_ms2"])
    vals = have["acc_norm_err_ms2"].iloc[-RECENT_FLIGHTS:]
    if len(vals) == 0 or abs(float(np.median(vals))) < ACC_NORM_LIMIT_MS2:
        return None
    err = float(np.median(vals))
    if abs(vals.iloc[-1]) < ACC_NORM_LIMIT_MS2:
        return None
    first = have.iloc[onset(have["acc_norm_err_ms2"], lambda v: abs(v) >= ACC_NORM_LIMIT_MS2)]
    return _flag(vid, "action", "acc_recalibrate",
                 f"recalibrate the accelerometers: |specific force| off g by "
                 f"{ACC_NORM_LIMIT_MS2:g} m/s² or more in still periods since {flight_name(first)}: "
                 f"{err:+.2f} m/s² (median of the last {len(vals)} flight(s))",
                 "run the six-face accelerometer calibration (apmcal live --guide ardupilot6)",
                 first)


def vibration_flag(vid: str, flights: pd.DataFrame) -> dict | None:
    """"reduce vibration" when the recent VIBE level reaches the limit."""
    cols = [c for c in ("vibe_x_ms2", "vibe_y_ms2", "vibe_z_ms2") if c in flights]
    if not cols:
        return None
    level = flights[cols].max(axis=1)
    have = flights[level.notna()]
    worst = level.dropna()
    if (len(worst) == 0 or float(np.median(worst.iloc[-RECENT_FLIGHTS:])) < VIBE_LIMIT_MS2
            or worst.iloc[-1] < VIBE_LIMIT_MS2):
        return None
    first = have.iloc[onset(worst, lambda v: v >= VIBE_LIMIT_MS2)]
    recent = worst.iloc[-RECENT_FLIGHTS:]
    return _flag(vid, "action", "vibration",
                 f"reduce vibration: VIBE {float(np.median(recent)):.0f} m/s² over the last "
                 f"{len(recent)} flight(s) (limit {VIBE_LIMIT_MS2:.0f}), since "
                 f"{flight_name(first)}",
                 "balance the propellers and soft-mount the flight controller", first)


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

    flags = outlier_flags(outliers)
    ok = flights[flights["status"] == "ok"]
    rows = {r["vehicle_id"]: r for r in vehicles.to_dict("records")} if len(vehicles) else {}
    for vid, group in ok.groupby("vehicle_id", sort=True):
        group = group.reset_index(drop=True)
        own = [c for c in changes if c["vehicle_id"] == vid]
        flags += change_flags(group, own) + hard_iron_flags(group, own)
        for f in (compass_flag(vid, since_last_compass_change(group, own)),
                  gyro_flag(vid, rows.get(vid, {})), acc_flag(vid, group),
                  vibration_flag(vid, group)):
            if f:
                flags.append(f)
    table = pd.DataFrame(flags, columns=FLAG_COLUMNS)
    table["flight"] = table["flight"].astype("Int64")
    return table.sort_values(["vehicle_id", "flight", "kind"], kind="stable",
                             na_position="last").reset_index(drop=True)
