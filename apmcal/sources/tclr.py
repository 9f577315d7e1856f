"""TCLR records: what ArduPilot's own temperature-calibration learner logged.

AP_InertialSensor_tempcal.cpp ``Learn::add_sample`` (4.1+, while INS_TCALn_ENABLE = 2) writes
``TCLR: TimeUS, I (IMU instance), SType (0 accelerometer, 1 gyro), Temp [°C], X, Y, Z, NSamp``:
the mean of NSamp raw sensor-frame samples (before offsets, scales and AHRS_ORIENTATION; no
temperature correction is applied while learning) each time the filtered temperature has risen
by 0.5 °C; the accelerometer means have the first accelerometer mean subtracted.
"""
from __future__ import annotations

import numpy as np

from apmcal.core.errors import ApmcalError

TCLR_COLUMNS = ("TimeUS", "I", "SType", "Temp", "X", "Y", "Z", "NSamp")
STYPE = {0: "acc", 1: "gyr"}


def read_tclr(path, fmt: str) -> dict[int, dict[str, dict[str, np.ndarray]]]:
    """TCLR records of a dataflash log (``fmt`` "bin" or "log"; anything else has none).

    Parameters
    ----------
    path : str or Path
        The dataflash log.
    fmt : str
        Its format (:func:`apmcal.sources.sniff_format`).

    Returns
    -------
    dict
        instance → {"acc"/"gyr" → {"temp_c": (m,) [°C], "values": (m, 3), "n": (m,),
        "t_s": (m,) [s]}}; empty when the log has no TCLR record. ``values`` are in m/s²
        (accelerometer, first mean subtracted) or rad/s (gyro), sensor frame.

    Raises
    ------
    ApmcalError
        TCLR records without one of :data:`TCLR_COLUMNS`.
    """
    if fmt == "bin":
        from apmcal.sources.dataflash import read_bin_messages

        msgs, _, _ = read_bin_messages(path, want=lambda name: name == "TCLR")
    elif fmt == "log":
        from apmcal.sources._common import load_bytes
        from apmcal.sources.dataflash_text import parse_text

        msgs, _, _ = parse_text(load_bytes(path).tobytes(), want=lambda name: name == "TCLR")
    else:
        return {}
    cols = msgs.get("TCLR", {})
    if not cols or not len(next(iter(cols.values()))):
        return {}
    missing = [c for c in TCLR_COLUMNS if c not in cols]
    if missing:
        raise ApmcalError(f"TCLR records lack the column(s) {', '.join(missing)}", str(path))
    out: dict[int, dict[str, dict[str, np.ndarray]]] = {}
    inst = np.asarray(cols["I"], dtype=np.int64)
    stype = np.asarray(cols["SType"], dtype=np.int64)
    values = np.column_stack([np.asarray(cols[c], dtype=float) for c in ("X", "Y", "Z")])
    temp = np.asarray(cols["Temp"], dtype=float)
    nsamp = np.asarray(cols["NSamp"], dtype=float)
    t_s = np.asarray(cols["TimeUS"], dtype=float) * 1e-6
    ok = np.isfinite(values).all(axis=1) & np.isfinite(temp) & (nsamp > 0)
    for i in np.unique(inst):
        for code, sensor in STYPE.items():
            sel = ok & (inst == i) & (stype == code)
            if np.any(sel):
                out.setdefault(int(i), {})[sensor] = {"temp_c": temp[sel], "values": values[sel],
                                                      "n": nsamp[sel], "t_s": t_s[sel]}
    return out
