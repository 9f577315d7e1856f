"""Independent reference: the same IMU/MAG/param values decoded by pymavlink's own parsers.

Used by the tests and by benchmarks/readers.py to check that apmcal's vectorised readers give
values identical to pymavlink (mavutil.mavlink_connection for .tlog, DFReader for .bin/.log).
Each message is decoded by pymavlink, one at a time; only the unit conversion documented in the
readers (mG × 9.80665/1000, mrad/s × 1e-3, cdegC × 0.01, Gauss × 1000, µs × 1e-6, ms × 1e-3) is
applied here, written out again so a wrong reader formula is caught too.
"""
from __future__ import annotations

import contextlib
import math
import os
import re

import numpy as np
from pymavlink import mavutil

TLOG_IMU = ["RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU"]
TLOG_READ = TLOG_IMU + ["SCALED_PRESSURE"]      # what the tlog reader turns into recordings
_DF_IMU = re.compile(r"^(IMU|ACC|GYR|MAG)(\d?)$")
_XYZ = ("x", "y", "z")


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
    return out


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
        inst = getattr(m, "I") if "I" in m._fieldnames else number
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
    return out


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
        for c, want in cols.items():
            if rec is None or c not in rec.data.columns:
                assert c == "t" or not np.nan_to_num(want).any(), f"{key} {c} dropped but non-zero"
                continue
            have = rec.data[c].to_numpy()
            assert have.shape == want.shape, f"{key} {c}: {have.shape} != {want.shape}"
            np.testing.assert_array_equal(have, want, err_msg=f"{key} {c}")
            n += have.size
    return n
