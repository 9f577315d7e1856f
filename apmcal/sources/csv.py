"""CSV (and plain-text column) recordings → :class:`~apmcal.core.recording.LogContents`.

Layouts (``layout=``):

``"apmcal"``   (alias ``"si"``) header ``t, acc_x, acc_y, acc_z, gyr_x, gyr_y, gyr_z``
               [s, m/s², rad/s], optional ``mag_x..z`` [mGauss] and ``temp`` [°C]. The default
               layout.
``"imucal"``   imucal's example session (mad-lab-fau/imucal example_data): ``n_samples`` index,
               ``gyr_x..z`` [deg/s], ``acc_x..z`` [m/s²]; no time column, so t = n / rate,
               rate 102.4 Hz unless ``rate_hz`` says otherwise (imucal's example sampling rate).
``"imucal_annotated"``  imucal's ``annotated_session.csv``: ``part, samples`` then acc/gyr in
               raw sensor counts ("a.u."), 204.8 Hz (imucal's own test uses that rate). The rows are
               grouped by part, so they are sorted by sample number; ``part`` (x_p, x_a, ..., z_rot)
               is kept as an extra column.
``"mpu6050"``  tomisuarez2/ImuCalibration logger output: 4 ``key,value`` lines (Fs, Logging Type,
               Initialization time, Waiting time), then ``ax..gz`` int16 counts of an MPU-6050 at
               its power-on ranges ±2 g and ±250 °/s (the logger calls ``mpu.initialize()`` and
               never changes them): 16384 LSB/g and 131 LSB/(°/s). Converted to m/s² (g = 9.80665)
               and rad/s; that repo's reference results (ref_params_*.csv) use the same units: acc
               scale ≈ 6.0e-4 m/s² per count, gyro scale ≈ 1.34e-4 rad/s per count, biases in
               counts.
``"imu_tk"``   imu_tk's ``xsens_acc.mat`` / ``xsens_gyro.mat``: ASCII ``t x y z`` (despite the
               name), accelerometer and gyroscope in two files (see :func:`read_imu_tk`). Values
               stay raw counts unless a unit/scale is given.
``"auto"``     picks one of the above from the first lines.

Units: ``acc_unit``/``gyr_unit``/``mag_unit`` take a name ("m/s^2", "g", "mg"; "rad/s", "deg/s",
"mrad/s"; "mGauss", "Gauss", "uT"), "counts" (keep as is) or a number (SI per file unit,
e.g. 9.80665/16384). ``None`` means the layout's own unit. Counts are flagged in
``LogContents.messages``. In the ``apmcal`` layout the header may declare them instead:
``acc_x[g]``, ``gyr_x[deg/s]``, ``mag_x[uT]``, ``acc_x[counts]``, ``t[s]``, ``t[ms]``, ``t[us]``
(the same unit on the three axes of a sensor); an undeclared time column stepping by more than
0.5 (an IMU at under 2 Hz if in seconds) is refused as milliseconds or microseconds. Without a
declaration, values that no Earth-bound sensor reads in SI units (a still |a| near 1: g; gyro
rates of deg/s; a field of tens: µT; thousands: raw counts) are refused with the fix
(:func:`apmcal.sources.units.require_plausible_units`).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from apmcal.core.constants import STANDARD_GRAVITY
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import ACC, GYR, MAG, LogContents, Recording

LAYOUTS = ("auto", "apmcal", "imucal", "imucal_annotated", "mpu6050", "imu_tk")
_ALIASES = {"si": "apmcal"}         # the CLI's --layout help calls the default layout "si"
ACC_UNITS = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": STANDARD_GRAVITY,
             "mg": STANDARD_GRAVITY / 1000.0}
GYR_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180.0, "mrad/s": 1e-3}
MAG_UNITS = {"mgauss": 1.0, "gauss": 1000.0, "ut": 10.0}

IMUCAL_RATE_HZ = 102.4          # imucal example_ferraris_session.csv
IMUCAL_ANNOTATED_RATE_HZ = 204.8   # imucal tests/test_ferraris_calibration.py
MPU6050_ACC_PER_COUNT = STANDARD_GRAVITY / 16384.0     # ±2 g range
MPU6050_GYR_PER_COUNT = math.radians(1.0) / 131.0      # ±250 °/s range


# ----------------------------------------------------------------------------- public API
def read_csv(path: str | Path, layout: str = "auto", *, acc_unit=None, gyr_unit=None,
             mag_unit=None, rate_hz: float | None = None) -> LogContents:
    """Read one CSV recording (see the module doc for layouts and units).

    Parameters
    ----------
    path : str or Path
        The CSV file (for ``"imu_tk"``: either of its two files).
    layout : str, optional
        One of :data:`LAYOUTS` (or the alias ``"si"``); ``"auto"`` sniffs it.
    acc_unit, gyr_unit, mag_unit : str or float, optional
        Unit name, ``"counts"`` or SI factor per file unit (m/s², rad/s, mGauss per unit);
        None: the layout's own unit.
    rate_hz : float, optional
        Sample rate [Hz] of layouts without a time column (imucal, imucal_annotated, mpu6050);
        None: the layout's default rate.

    Returns
    -------
    LogContents
        ``format="csv"`` with one :class:`Recording` (corrected=False, frame="sensor").

    Raises
    ------
    ApmcalError
        Naming the file and line for an unknown layout, bad rows, NaN, non-increasing time.
    """
    path = Path(path)
    layout = _ALIASES.get(layout, layout)
    if layout not in LAYOUTS:
        raise ApmcalError(f"unknown CSV layout {layout!r}; choose one of {', '.join(LAYOUTS)}",
                          path)
    if layout == "auto":
        layout = sniff_layout(path)
    if layout == "imu_tk":
        acc_path, gyr_path = _imu_tk_pair(path)
        return read_imu_tk(acc_path, gyr_path, acc_unit=acc_unit, gyr_unit=gyr_unit)
    units = {"acc": acc_unit, "gyr": gyr_unit, "mag": mag_unit}
    reader = {"apmcal": _read_apmcal, "imucal": _read_imucal,
              "imucal_annotated": _read_imucal_annotated, "mpu6050": _read_mpu6050}[layout]
    data, notes = reader(path, units, rate_hz)
    _check_time(data["t"].to_numpy(), path, data.index.to_numpy())
    return _contents(path, data.reset_index(drop=True), notes)


def read_imu_tk(acc_path: str | Path, gyr_path: str | Path, *, acc_unit=None,
                gyr_unit=None) -> LogContents:
    """Join an imu_tk accelerometer file and gyroscope file (``t x y z`` each) into one recording.

    Both files must carry the same time stamps. Without ``acc_unit``/``gyr_unit`` the values stay
    raw counts (noted in ``messages``): imu_tk's Xsens test data has no published scale.

    Parameters
    ----------
    acc_path, gyr_path : str or Path
        The accelerometer and the gyroscope file.
    acc_unit, gyr_unit : str or float, optional
        Unit name or SI factor per file unit (m/s² resp. rad/s per unit); None: counts.

    Returns
    -------
    LogContents
        ``format="csv"`` with one :class:`Recording` (t [s], acc_*, gyr_*).

    Raises
    ------
    ApmcalError
        Unreadable rows, non-increasing time, different row counts or time stamps.
    """
    acc_path, gyr_path = Path(acc_path), Path(gyr_path)
    acc = _read_table(acc_path, names=["t", *ACC], sep=r"\s+", header=None)
    gyr = _read_table(gyr_path, names=["t", *GYR], sep=r"\s+", header=None)
    for frame, p in ((acc, acc_path), (gyr, gyr_path)):
        _check_time(frame["t"].to_numpy(), p, frame.index.to_numpy())
    if len(acc) != len(gyr):
        raise ApmcalError(f"{len(acc)} accelerometer rows but {len(gyr)} gyroscope rows in "
                          f"{gyr_path.name}", acc_path)
    differ = np.flatnonzero(np.abs(acc["t"].to_numpy() - gyr["t"].to_numpy()) > 1e-9)
    if differ.size:
        raise ApmcalError(f"time differs from {gyr_path.name} (same line there)", acc_path,
                          f"line {acc.index[differ[0]]}")
    notes = []
    data = acc.copy()
    for sensor, frame, unit in (("acc", acc, acc_unit), ("gyr", gyr, gyr_unit)):
        cols = ACC if sensor == "acc" else GYR
        factor, note = _factor(sensor, unit, "counts", acc_path if sensor == "acc" else gyr_path)
        data[cols] = frame[cols].to_numpy() * factor
        notes += [note] if note else []
    contents = _contents(acc_path, data.reset_index(drop=True), notes)
    contents.recordings[0].source = f"{acc_path}+{gyr_path}"
    return contents


def sniff_layout(path: str | Path) -> str:
    """The layout of ``path`` from its first non-empty line(s), or ApmcalError naming line 1.

    Returns
    -------
    str
        One of :data:`LAYOUTS` other than ``"auto"``.

    Raises
    ------
    ApmcalError
        When no layout matches.
    """
    path = Path(path)
    first = _first_line(path)
    header = [_UNIT_SUFFIX.sub("", f.strip().lower()) for f in first.split(",")]
    if header[0] == "fs" and len(header) == 2:
        return "mpu6050"
    if header[:2] == ["part", "samples"]:
        return "imucal_annotated"
    if header[0] == "n_samples" and {"gyr_x", "acc_x"} <= set(header):
        return "imucal"
    if "t" in header and set(ACC) <= set(header):
        return "apmcal"
    fields = first.split()
    if len(fields) == 4 and all(_is_number(f) for f in fields):
        return "imu_tk"
    raise ApmcalError(f"unrecognised CSV layout (header {first[:60]!r}); expected columns "
                      "t, acc_x..z, gyr_x..z or one of the layouts " + ", ".join(LAYOUTS[1:]),
                      path, "line 1")


# ----------------------------------------------------------------------------- layouts
_UNIT_SUFFIX = re.compile(r"\s*\[[^\]]*\]\s*$")      # "acc_x[g]" → "acc_x"


def header_units(data: pd.DataFrame, path) -> tuple[pd.DataFrame, dict]:
    """Columns named ``name[unit]`` renamed to ``name``, and sensor → the unit they declare.

    Raises
    ------
    ApmcalError
        When a sensor's axes declare different units.
    """
    declared: dict[str, set] = {}
    renames = {}
    for col in data.columns:
        m = re.fullmatch(r"\s*(\w+)\s*\[([^\]]*)\]\s*", str(col))
        if not m:
            continue
        name, unit = m.group(1), m.group(2).strip()
        renames[col] = name
        sensor = name.split("_")[0]
        if sensor in ("acc", "gyr", "mag"):
            declared.setdefault(sensor, set()).add(unit.replace("µ", "u"))
        elif name == "t" and unit.replace("µ", "u") not in TIME_UNITS:
            raise ApmcalError(f"time column in {unit!r}: give t in seconds (t[s]), "
                              "milliseconds (t[ms]) or microseconds (t[us])", path, "line 1")
        elif name == "t":
            declared["t"] = {unit.replace("µ", "u") or "s"}
    for sensor, units in declared.items():
        plain = [c for c in data.columns if str(c).startswith(f"{sensor}_") and c not in renames]
        if len(units) > 1 or plain:
            raise ApmcalError(f"{sensor} axes declare different units {sorted(units)} in the "
                              "header; use one unit for x, y and z", path, "line 1")
    return data.rename(columns=renames), {k: next(iter(v)) for k, v in declared.items()}


def _read_apmcal(path, units, rate_hz):
    data, declared = header_units(_read_table(path, header=0), path)
    units = {k: (declared.get(k) if v is None else v) for k, v in units.items()}
    missing = [c for c in ["t", *ACC, *GYR] if c not in data.columns]
    if missing:
        raise ApmcalError(f"missing column(s) {', '.join(missing)}", path, "line 1")
    data["t"] = data["t"] * TIME_UNITS[declared.get("t", "s")]
    if "t" not in declared:
        _require_seconds(data["t"].to_numpy(), path)
    notes = []
    for sensor, cols, default in (("acc", ACC, "m/s^2"), ("gyr", GYR, "rad/s"),
                                  ("mag", MAG, "mGauss")):
        if sensor == "mag" and not set(MAG) <= set(data.columns):
            continue
        factor, note = _factor(sensor, units[sensor], default, path)
        data[cols] = data[cols] * factor
        notes += [note] if note else []
    keep = ["t", *ACC, *GYR] + [c for c in [*MAG, "temp"] if c in data.columns]
    if rate_hz:
        notes.append("rate_hz ignored: the file has a time column")
    return data[keep], notes


def _read_imucal(path, units, rate_hz):
    data = _read_table(path, header=0)
    _require(data, ["n_samples", *ACC, *GYR], path)
    rate = rate_hz or IMUCAL_RATE_HZ
    notes = [f"imucal layout: no time column, t = n_samples / {rate:g} Hz"
             + ("" if rate_hz else " (imucal's example rate; in Python, "
                                   "read_csv(path, rate_hz=...) if different)")]
    out = pd.DataFrame({"t": data["n_samples"].to_numpy(dtype=float) / rate}, index=data.index)
    out = _scaled(out, data, units, {"acc": "m/s^2", "gyr": "deg/s"}, path, notes)
    return out, notes


def _read_imucal_annotated(path, units, rate_hz):
    data = _read_table(path, header=0, text_columns=["part"])
    _require(data, ["part", "samples", *ACC, *GYR], path)
    data = data.sort_values("samples", kind="stable")
    rate = rate_hz or IMUCAL_ANNOTATED_RATE_HZ
    notes = [f"imucal annotated layout: rows sorted by sample number, t = samples / {rate:g} Hz",
             "column 'part' labels imucal's Ferraris regions (x_p, x_a, ..., z_rot)"]
    out = pd.DataFrame({"t": data["samples"].to_numpy(dtype=float) / rate}, index=data.index)
    out = _scaled(out, data, units, {"acc": "counts", "gyr": "counts"}, path, notes)
    out["part"] = data["part"].to_numpy()
    return out, notes


def _read_mpu6050(path, units, rate_hz):
    meta = _mpu6050_header(path)
    data = _read_table(path, header=0, skiprows=4)
    _require(data, ["ax", "ay", "az", "gx", "gy", "gz"], path, line=5)
    rate = rate_hz or meta["Fs"]
    if not rate or rate <= 0:
        raise ApmcalError(f"sampling rate Fs={meta['Fs']!r} is not positive", path, "line 1")
    notes = [f"mpu6050 layout: Fs {meta['Fs']:g} Hz, logging type {meta['Logging Type']:g}, "
             f"initialization time {meta['Initialization time']:g} s, "
             f"waiting time {meta['Waiting time']:g} s"]
    if rate_hz and rate_hz != meta["Fs"]:
        notes.append(f"rate_hz {rate_hz:g} overrides the file's Fs {meta['Fs']:g}")
    renamed = data.rename(columns=dict(zip(["ax", "ay", "az", "gx", "gy", "gz"], ACC + GYR)))
    out = pd.DataFrame({"t": np.arange(len(data)) / rate}, index=data.index)
    out = _scaled(out, renamed, units, {"acc": MPU6050_ACC_PER_COUNT, "gyr": MPU6050_GYR_PER_COUNT},
                  path, notes)
    if units["acc"] is None and units["gyr"] is None:
        notes.append("MPU-6050 counts converted with ±2 g (16384 LSB/g) and ±250 °/s "
                     "(131 LSB/(°/s)), the ranges the logger leaves at power-on")
    return out, notes


def _mpu6050_header(path):
    meta = {}
    with _open(path) as f:
        for number in range(1, 5):
            parts = f.readline().strip().split(",")
            if len(parts) != 2 or not _is_number(parts[1]):
                raise ApmcalError(f"expected 'key,number' header line, got {','.join(parts)!r}",
                                  path, f"line {number}")
            meta[parts[0].strip()] = float(parts[1])
    for key in ("Fs", "Logging Type", "Initialization time", "Waiting time"):
        meta.setdefault(key, float("nan"))
    return meta


# ----------------------------------------------------------------------------- helpers
def _read_table(path: Path, *, text_columns=(), **kwargs):
    """pandas.read_csv (C parser) with every value numeric and finite; errors name the line.

    The returned frame's index is the file line number of each row. A UTF-8 byte order mark is
    skipped. Every row must have as many fields as the header (or ``names``): pandas would
    otherwise turn extra leading fields into an index, or fill missing ones with NaN, so a bad
    row gives "line 17: 9 fields, header has 7".
    """
    skip = kwargs.get("skiprows", 0)
    no_header = kwargs.get("header", 0) is None
    first_line = skip + (1 if no_header else 2)
    try:
        # nan and inf kept as text ("" alone is missing): told apart from empty fields below
        data = pd.read_csv(path, skip_blank_lines=False, engine="c", encoding="utf-8-sig",
                           keep_default_na=False, na_values=[""], **kwargs)
    except FileNotFoundError:
        raise ApmcalError("no such file", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ApmcalError(f"cannot read file ({exc})", path) from None
    except pd.errors.EmptyDataError:
        raise ApmcalError("file is empty", path) from None
    except pd.errors.ParserError as exc:
        _check_field_counts(path, kwargs, first_line)      # raises for the first bad row
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
        if m:   # pandas counts lines from the file's first line
            raise ApmcalError(f"{m.group(3)} fields, expected {m.group(1)}", path,
                              f"line {m.group(2)}") from None
        raise ApmcalError(f"not a readable CSV table ({exc})".replace("\n", " "), path) from None
    if not isinstance(data.index, pd.RangeIndex):
        _check_field_counts(path, kwargs, first_line)    # pandas made extra fields an index
    data.columns = [str(c).strip() for c in data.columns]
    data.index = np.arange(len(data)) + first_line
    data = _drop_trailing_blank(data)
    if data.empty:
        raise ApmcalError("no data rows", path)
    numeric = [c for c in data.columns if c not in text_columns]
    values = data[numeric].apply(pd.to_numeric, errors="coerce").astype(float)
    bad = ~np.isfinite(values.to_numpy())
    # a sample written as nan or inf is data (a sensor that gave none): kept, and dropped and
    # counted by the calibration's preparation (apmcal.preprocessing.prepare.drop_non_finite)
    bad &= ~_written_non_finite(data[numeric], bad)
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        line = int(data.index[row])
        _check_field_counts(path, kwargs, first_line, last_line=line)   # a short row?
        if data.iloc[row].isna().all():
            raise ApmcalError("empty line", path, f"line {line}")
        col = numeric[int(np.argmax(bad[row]))]
        raw = _raw_field(path, kwargs, line, list(data.columns).index(col))
        what = (f"{col} is empty" if raw is None or not raw.strip()
                else f"{col} = {raw.strip()!r} is not a finite number")
        raise ApmcalError(what, path, f"line {line}")
    data[numeric] = values
    return data


#: columns that place a sample (time, index): never non-finite
_PLACING_COLUMNS = ("t", "n_samples", "samples")
_NON_FINITE_WORDS = {"nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity",
                     "-infinity"}


def _written_non_finite(frame: pd.DataFrame, bad: np.ndarray) -> np.ndarray:
    """Which ``bad`` cells of ``frame`` (as read, with ``keep_default_na=False``: the text
    itself) are a value written as nan or inf in a sensor column, rather than an empty or
    unreadable field."""
    ok = np.zeros_like(bad)
    for j, col in enumerate(frame.columns):
        rows = np.flatnonzero(bad[:, j])
        if not rows.size or col in _PLACING_COLUMNS:
            continue
        cells = frame[col].to_numpy()[rows]
        ok[rows, j] = [isinstance(c, str) and c.strip().lower() in _NON_FINITE_WORDS
                       or isinstance(c, float) and not math.isnan(c) for c in cells]
    return ok


def _split(line: str, kwargs) -> list[str]:
    """Fields of one text line: whitespace-separated for the whitespace ``sep``, else commas."""
    line = line.rstrip("\r\n")
    if kwargs.get("sep") == r"\s+":
        return line.split()
    return line.split(",") if line.strip() else []


def _lines(path: Path):
    """(line number, text) of every line of a text file (UTF-8, byte order mark skipped)."""
    with open(path, encoding="utf-8-sig", errors="replace", newline="") as f:
        yield from enumerate(f, start=1)


def _check_field_counts(path: Path, kwargs, first_line: int, last_line: int | None = None):
    """ApmcalError for the first data row (up to ``last_line``) whose field count differs from
    the header's (or from ``names``); blank lines are left to the caller. Used only once
    something is already wrong, so a good file is never read twice."""
    names = kwargs.get("names")
    expected, against = (len(names), "expected") if names is not None else (None, "header has")
    for number, line in _lines(path):
        if number == first_line - 1 and expected is None:
            expected = len(_split(line, kwargs))
        if number < first_line:
            continue
        if last_line is not None and number > last_line:
            return
        n = len(_split(line, kwargs))
        if n and expected is not None and n != expected:
            raise ApmcalError(f"{n} fields, {against} {expected}", path, f"line {number}")


def _raw_field(path: Path, kwargs, line: int, index: int) -> str | None:
    """The text of field ``index`` on file line ``line`` (None when the line is shorter)."""
    for number, text in _lines(path):
        if number == line:
            fields = _split(text, kwargs)
            return fields[index] if index < len(fields) else None
    return None


def _drop_trailing_blank(data: pd.DataFrame) -> pd.DataFrame:
    blank = data.isna().all(axis=1).to_numpy()
    end = len(data)
    while end and blank[end - 1]:
        end -= 1
    return data.iloc[:end]


#: time units a header may declare (``t[ms]``), in seconds
TIME_UNITS = {"s": 1.0, "": 1.0, "ms": 1e-3, "us": 1e-6}
#: an undeclared time column whose median step is longer than this [s] (an IMU at under 2 Hz)
#: is taken for milliseconds or microseconds, and refused with the header that says so
MAX_UNDECLARED_STEP_S = 0.5


def _require_seconds(t: np.ndarray, path) -> None:
    """Refuse an undeclared time column whose steps no IMU logs in seconds: ``t[ms]`` or
    ``t[us]`` (or ``t[s]``, for a truly slow file) says what it is."""
    steps = np.diff(t[np.isfinite(t)])
    if steps.size and float(np.median(steps)) > MAX_UNDECLARED_STEP_S:
        step = float(np.median(steps))
        raise ApmcalError(f"the time column steps by {step:.4g} (median), {1 / step:.3g} Hz if "
                          "in seconds, slower than any IMU log: if t is in milliseconds name "
                          "the column t[ms] (microseconds: t[us]); t[s] keeps seconds", path,
                          "column t")


def _check_time(t: np.ndarray, path, lines: np.ndarray) -> None:
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = bad[0] + 1
        raise ApmcalError(f"time {float(t[i])!r} s does not increase (previous "
                          f"{float(t[i - 1])!r} s)", path,
                          f"line {int(lines[i])}")


def _factor(sensor: str, unit, default, path) -> tuple[float, str | None]:
    """SI factor for ``unit`` (None → ``default``) and a note when values stay raw counts."""
    unit = default if unit is None else unit
    if isinstance(unit, (int, float)) and not isinstance(unit, bool):
        if not math.isfinite(unit) or unit == 0:
            raise ApmcalError(f"{sensor} scale {unit!r} must be finite and non-zero", path)
        return float(unit), None
    if unit == "counts":
        return 1.0, (f"{sensor}: raw sensor counts, not SI units (no scale known); "
                     "the offsets are in counts too (declare the unit in the header, e.g. acc_x[g], or "
                     "give read_csv a unit or scale)")
    table = {"acc": ACC_UNITS, "gyr": GYR_UNITS, "mag": MAG_UNITS}[sensor]
    key = unit.lower() if sensor == "mag" else unit
    if key not in table:
        raise ApmcalError(f"unknown {sensor} unit {unit!r}; use one of "
                          f"{', '.join(table)}, 'counts' or a number", path)
    return table[key], None


def _scaled(out, data, units, defaults, path, notes):
    for sensor, cols in (("acc", ACC), ("gyr", GYR)):
        factor, note = _factor(sensor, units[sensor], defaults[sensor], path)
        out[cols] = data[cols].to_numpy(dtype=float) * factor
        notes += [note] if note else []
    return out


def _require(data, columns, path, line: int = 1):
    missing = [c for c in columns if c not in data.columns]
    if missing:
        raise ApmcalError(f"missing column(s) {', '.join(missing)}", path, f"line {line}")


def _contents(path: Path, data: pd.DataFrame, notes: list[str]) -> LogContents:
    rec = Recording(data=data, source=str(path), message="csv", instance=0,
                    corrected=False, frame="sensor")
    return LogContents(path=str(path), format="csv", recordings=[rec], messages=notes)


def _imu_tk_pair(path: Path) -> tuple[Path, Path]:
    """(acc file, gyro file) from either one: xsens_acc.mat <-> xsens_gyro.mat."""
    name = path.name
    if "acc" in name:
        acc, gyr = path, [path.with_name(name.replace("acc", g)) for g in ("gyro", "gyr")]
    elif "gyr" in name:
        gyr_name = name
        acc = path.with_name(re.sub(r"gyro?", "acc", gyr_name, count=1))
        gyr = [path]
    else:
        raise ApmcalError("imu_tk layout: cannot tell the accelerometer file from the gyro file "
                          "(name them *acc* and *gyro*, or use read_imu_tk)", path)
    gyr = next((g for g in gyr if g.exists()), gyr[0])
    for p in (acc, gyr):
        if not p.exists():
            raise ApmcalError(f"imu_tk layout needs its partner file {p.name}", path)
    return acc, gyr


def _first_line(path: Path) -> str:
    with _open(path) as f:
        for line in f:
            if line.strip():
                return line.strip()
    raise ApmcalError("file is empty", path)


def _open(path: Path):
    try:
        f = open(path, encoding="utf-8-sig", errors="strict")   # a byte order mark is skipped
        f.readline()
        f.seek(0)
        return f
    except FileNotFoundError:
        raise ApmcalError("no such file", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ApmcalError(f"not a text file ({exc.__class__.__name__})", path) from None


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False
