"""Independent reference: the same IMU/MAG/param values decoded by pymavlink's own parsers.

Used by the tests and by benchmarks/readers.py (kept out of the installed package) to check
that apmcal's vectorised readers give values identical to pymavlink (mavutil.mavlink_connection
for .tlog, DFReader for .bin/.log).
Each message is decoded by pymavlink, one at a time; only the unit conversion documented in the
readers (mG × 9.80665/1000, mrad/s × 1e-3, cdegC × 0.01, Gauss × 1000, µs × 1e-6, ms × 1e-3,
cA × 0.01) is applied here, written out again so a wrong reader formula is caught too.

The optional ``current`` column [A] is rebuilt the way the readers document it: the first
battery's BAT/CURR ``Curr`` (integer formats are centi-amps) or the autopilot's SYS_STATUS
``current_battery`` (-1 = not measured), the tlog's per-frame timestamps mapped onto each
recording's boot clock by the median offset, linearly interpolated, NaN outside the records.
"""
from __future__ import annotations

import contextlib
import math
import os
import re

import numpy as np
from pymavlink import mavutil

TLOG_IMU = ["RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU"]
# what the tlog reader turns into recordings (HEARTBEAT: which SYS_STATUS is the autopilot's)
TLOG_READ = TLOG_IMU + ["SCALED_PRESSURE", "SYS_STATUS", "HEARTBEAT"]
_DF_IMU = re.compile(r"^(IMU|ACC|GYR|MAG)(\d?)$")
_XYZ = ("x", "y", "z")
_INT_FORMATS = set("bBhHiIqQ")      # dataflash integer format characters (no multiplier)
MAX_CLOCK_SPREAD_S = 0.5            # the tlog reader's limit on the clock offset's spread
CLOCK_SAMPLES = 1 << 16             # the tlog reader estimates it on every k-th message


@contextlib.contextmanager
def _mavlink2_dialect():
    """Use pymavlink's MAVLink 2 dialect inside the block, restoring the previous choice after.

    pymavlink picks the MAVLink 1 dialect (which ignores extension fields such as RAW_IMU.id and
    .temperature) when a tlog starts with a v1 packet, unless MAVLINK20 is set. The v2 dialect
    decodes v1 and v2 packets alike, so the reference does not depend on the file's first byte.
    """
    before = os.environ.get("MAVLINK20")
    os.environ["MAVLINK20"] = "1"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("MAVLINK20", None)
        else:
            os.environ["MAVLINK20"] = before
        mavutil.set_dialect(mavutil.current_dialect)


def pymavlink_messages(path, types):
    """All messages of ``types`` (None: all) in file order, decoded by pymavlink."""
    with _mavlink2_dialect():
        conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
        out = []
        while True:
            m = conn.recv_match(type=types)
            if m is None:
                break
            out.append(m)
        conn.close()
    return out


def _tlog_columns(name: str, ms: list) -> dict[str, np.ndarray]:
    g = 9.80665 / 1000.0
    if name == "HIGHRES_IMU":
        cols = {"t": np.array([m.time_usec for m in ms], dtype=np.float64) * 1e-6}
        for a in _XYZ:
            cols[f"acc_{a}"] = np.array([getattr(m, a + "acc") for m in ms], np.float64)
            cols[f"gyr_{a}"] = np.array([getattr(m, a + "gyro") for m in ms], np.float64)
            cols[f"mag_{a}"] = np.array([getattr(m, a + "mag") for m in ms], np.float64) * 1000.0
        cols["temp"] = np.array([m.temperature for m in ms], np.float64)
        return cols
    if name == "RAW_IMU":
        cols = {"t": np.array([m.time_usec for m in ms], dtype=np.float64) * 1e-6}
    else:
        cols = {"t": np.array([m.time_boot_ms for m in ms], dtype=np.float64) * 1e-3}
    for a in _XYZ:
        cols[f"acc_{a}"] = np.array([getattr(m, a + "acc") for m in ms]) * g
        cols[f"gyr_{a}"] = np.array([getattr(m, a + "gyro") for m in ms]) * 1e-3
        cols[f"mag_{a}"] = np.array([getattr(m, a + "mag") for m in ms], np.float64)
    temp = np.array([getattr(m, "temperature", 0) for m in ms])
    cols["temp"] = np.where(temp != 0, temp * 0.01, np.nan) if temp.any() else np.zeros(len(ms))
    return cols


def tlog_expected(msgs: list) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    """(message, instance) → SI columns, from pymavlink-decoded tlog IMU messages."""
    groups: dict[tuple[str, int], list] = {}
    inst_of = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
    for m in msgs:
        name = m.get_type()
        if name not in TLOG_IMU:
            continue
        inst = inst_of.get(name, m.id if "id" in m.get_fieldnames() else 0)
        groups.setdefault((name, inst), []).append(m)
    out = {k: _tlog_columns(k[0], v) for k, v in groups.items()}
    baro = [m for m in msgs if m.get_type() == "SCALED_PRESSURE"]
    for (name, _), cols in out.items():
        if name != "HIGHRES_IMU" and not np.nan_to_num(cols["temp"]).any():
            cols["temp"] = _baro_temperature(baro, cols["t"])
    current = _sys_status_current(msgs)
    for key, cols in out.items():
        amps = None if current is None else _tlog_current_at(
            cols["t"], np.array([m._timestamp for m in groups[key]]), current)
        if amps is not None:
            cols["current"] = amps
    return out


def _current_records(times: list, amps: list) -> tuple[np.ndarray, np.ndarray] | None:
    """(time [s], current [A]) ready to interpolate, or None: finite records only; None when no
    current is non-zero, the time goes back or fewer than two distinct times remain; the first
    of records sharing one time is kept."""
    recs = [(t, a) for t, a in zip(times, amps) if math.isfinite(t) and math.isfinite(a)]
    if not any(a != 0 for _, a in recs):
        return None
    if any(b[0] < a[0] for a, b in zip(recs, recs[1:])):
        return None
    kept = []
    for t, a in recs:
        if not kept or t > kept[-1][0]:
            kept.append((t, a))
    if len(kept) < 2:
        return None
    return np.array([t for t, _ in kept]), np.array([a for _, a in kept])


def _interp_inside(t: np.ndarray, t_cur: np.ndarray, amps: np.ndarray) -> np.ndarray | None:
    """Current interpolated at t, NaN outside the records; None when the clock of t jumps back
    or no t lies within the records."""
    if np.any(np.diff(t) < 0):
        return None
    inside = (t >= t_cur[0]) & (t <= t_cur[-1])
    if not inside.any():
        return None
    return np.where(inside, np.interp(t, t_cur, amps), np.nan)


def _sys_status_current(msgs: list) -> tuple[np.ndarray, np.ndarray] | None:
    """The autopilot's SYS_STATUS current: (tlog time [s since 1970], current [A]) or None.

    The autopilot is the source of the first HEARTBEAT whose autopilot is not
    MAV_AUTOPILOT_INVALID (8); without one every SYS_STATUS counts. -1 cA = not measured."""
    beats = [m for m in msgs if m.get_type() == "HEARTBEAT" and m.autopilot != 8]
    src = (beats[0].get_srcSystem(), beats[0].get_srcComponent()) if beats else None
    ss = [m for m in msgs if m.get_type() == "SYS_STATUS" and m.current_battery != -1
          and (src is None or (m.get_srcSystem(), m.get_srcComponent()) == src)]
    return _current_records([m._timestamp for m in ss], [m.current_battery * 0.01 for m in ss])


def _tlog_current_at(t: np.ndarray, stamps: np.ndarray,
                     current: tuple[np.ndarray, np.ndarray]) -> np.ndarray | None:
    """SYS_STATUS current at the boot times t of one recording whose messages the ground
    station stamped ``stamps`` [s since 1970]: None when a clock goes back or the 5th..95th
    percentile spread of (stamp − t) exceeds MAX_CLOCK_SPREAD_S. The offset's statistics use
    every k-th message, k = ceil(n / CLOCK_SAMPLES) (at least 1), as the reader does."""
    k = max(math.ceil(len(t) / CLOCK_SAMPLES), 1)
    if np.any(np.diff(t) < 0) or np.any(np.diff(stamps[::k]) < 0):
        return None
    d = stamps[::k] - t[::k]
    lo, median, hi = np.percentile(d, [5.0, 50.0, 95.0])
    if hi - lo > MAX_CLOCK_SPREAD_S:
        return None
    return _interp_inside(t, current[0] - float(median), current[1])


def _baro_temperature(baro: list, t: np.ndarray) -> np.ndarray:
    """SCALED_PRESSURE temperature [cdegC → °C] linearly interpolated at times t [s], NaN
    outside the barometer's samples; zeros (no column) without a usable barometer."""
    times = [m.time_boot_ms * 1e-3 for m in baro]
    if any(b < a for a, b in zip(times, times[1:])) or np.any(np.diff(t) < 0):
        return np.zeros(len(t))                           # a reboot: nothing attached
    tb, temp = [], []
    for m in baro:
        if not tb or m.time_boot_ms * 1e-3 > tb[-1]:      # repeated times once only
            tb.append(m.time_boot_ms * 1e-3)
            temp.append(m.temperature * 0.01)
    inside = (t >= tb[0]) & (t <= tb[-1]) if len(tb) >= 2 and any(temp) else np.zeros(len(t), bool)
    if not inside.any():
        return np.zeros(len(t))
    return np.where(inside, np.interp(t, tb, temp), np.nan)


def df_expected(msgs: list) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    """(message, instance) → SI columns, from DFReader-decoded IMU/ACC/GYR/MAG messages."""
    groups: dict[tuple[str, int], list] = {}
    for m in msgs:
        name = m.get_type()
        mt = _DF_IMU.match(name)
        if not mt:
            continue
        fam, num = mt.groups()
        number = int(num) - 1 if num else 0     # IMU2 → 1, ACC1 → 0, MAG3 → 2
        inst = m.I if "I" in m._fieldnames else number
        groups.setdefault((name, int(inst)), []).append(m)
    out = {}
    for (name, inst), ms in groups.items():
        fam = _DF_IMU.match(name).group(1)
        f = ms[0]._fieldnames
        tk, scale = ("TimeUS", 1e-6) if "TimeUS" in f else ("TimeMS", 1e-3)
        cols = {"t": np.array([getattr(m, tk) for m in ms], np.float64) * scale}
        for a, A in zip(_XYZ, "XYZ"):
            if fam in ("IMU", "ACC"):
                cols[f"acc_{a}"] = np.array([getattr(m, "Acc" + A) for m in ms], np.float64)
            if fam in ("IMU", "GYR"):
                cols[f"gyr_{a}"] = np.array([getattr(m, "Gyr" + A) for m in ms], np.float64)
            if fam == "MAG":
                cols[f"mag_{a}"] = np.array([getattr(m, "Mag" + A) for m in ms], np.float64)
        for tc in ("T", "Temp"):
            if fam == "IMU" and tc in f:
                cols["temp"] = np.array([getattr(m, tc) for m in ms], np.float64)
                break
        out[(name, inst)] = cols
    current = _df_current(msgs)
    for cols in out.values():
        amps = None if current is None else _interp_inside(cols["t"], *current)
        if amps is not None:
            cols["current"] = amps
    return out


def _df_current(msgs: list) -> tuple[np.ndarray, np.ndarray] | None:
    """First battery's current from BAT (else CURR): (time [s], current [A]) or None.

    An integer ``Curr`` format character means centi-amps (Copter 3.x CURR), a float A."""
    for name in ("BAT", "CURR"):
        ms = [m for m in msgs if m.get_type() == name]
        if not ms or "Curr" not in ms[0]._fieldnames:
            continue
        f = ms[0]._fieldnames
        if "TimeUS" not in f and "TimeMS" not in f:
            continue
        tk, scale = ("TimeUS", 1e-6) if "TimeUS" in f else ("TimeMS", 1e-3)
        inst = next((c for c in ("Instance", "Inst") if c in f), None)
        if inst is not None:
            lowest = min(getattr(m, inst) for m in ms)
            ms = [m for m in ms if getattr(m, inst) == lowest]
        fmt = ms[0].fmt
        centi = fmt.format[fmt.columns.index("Curr")] in _INT_FORMATS
        times = np.array([getattr(m, tk) for m in ms], np.float64) * scale
        curr = np.array([m.Curr for m in ms], np.float64)
        return _current_records(list(times), list(curr * 0.01 if centi else curr))
    return None


def expected_params(msgs: list) -> dict[str, float]:
    """Last finite value of each parameter from PARAM_VALUE (tlog) or PARM (dataflash)."""
    params = {}
    for m in msgs:
        if m.get_type() == "PARAM_VALUE":
            name, value = m.param_id, m.param_value
        elif m.get_type() == "PARM":
            name, value = m.Name, m.Value
        else:
            continue
        if math.isfinite(value):
            params[name] = float(value)
    return params


def compare(contents, expected: dict) -> int:
    """Assert apmcal's recordings equal ``expected`` exactly; returns the number of values compared.

    A column may be missing from apmcal's output only when it is zero in every sample (the
    readers drop all-zero sensors); a whole (message, instance) only when all its columns are.
    """
    got = {(r.message, r.instance): r for r in contents.recordings}
    extra = set(got) - set(expected)
    assert not extra, f"recordings not in pymavlink's output: {sorted(extra)}"
    n = 0
    for key, cols in expected.items():
        rec = got.get(key)
        assert rec is None or "current" not in rec.data.columns or "current" in cols, \
            f"{key} current attached, but not by the reference"
        for c, want in cols.items():
            if rec is None or c not in rec.data.columns:
                assert c == "t" or not np.nan_to_num(want).any(), f"{key} {c} dropped but non-zero"
                continue
            have = rec.data[c].to_numpy()
            assert have.shape == want.shape, f"{key} {c}: {have.shape} != {want.shape}"
            np.testing.assert_array_equal(have, want, err_msg=f"{key} {c}")
            n += have.size
    return n
