"""Physical sanity check of a log's units: is each sensor's magnitude one the Earth allows?

A message that carries a sensor in the wrong units is not noise to be fitted: fitted, it gives
offsets millions of times too large. ArduPilot firmware of about May 2024 - Feb 2026
sent HIGHRES_IMU xmag/ymag/zmag in mGauss×1000 instead of gauss (1e6 times too much), and apmcal,
which prefers HIGHRES_IMU, proposed a compass offset of 1e8 mGauss. So every sensor of every
recording of an ArduPilot log (tlog, dataflash; live links are read back as tlogs) is checked
against physics, and one that fails is dropped from that recording with a warning naming the
message, the magnitude seen and the range expected. The pipeline then takes that sensor from
another message of the same IMU (RAW_IMU / SCALED_IMU*), when the log has one, and the sensors
that passed are calibrated (and can be uploaded) as usual.

The check runs on what a reader returns, before the summary and the calibration (the readers
themselves decode faithfully, whatever the values). A CSV file's units are the user's to
declare (header ``acc_x[g]``, ``gyr_x[deg/s]``, ``mag_x[uT]``, ``acc_x[counts]``): a sensor
declared in counts is left alone, any other that fails :func:`csv_unit_problem` is refused with
the fix, since there is no other message to take it from.

The ranges are wide on purpose: they must pass any real board, however badly calibrated. They
catch the gross mix-ups (gauss or the firmware's mGauss×1000 for mGauss, g or mG for m/s², mrad/s
for rad/s); smaller ones (µT for mGauss ×0.1, deg/s for rad/s ×57 on a small bias) can pass.
"""
from __future__ import annotations

import numpy as np

from apmcal.core.constants import STANDARD_GRAVITY
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import SENSOR_COLUMNS, LogContents, Recording

# The Earth's field is 150..1000 mGauss at the surface (ArduPilot's compass calibrator
# accepts radii 150..950, ardupilot-facts.md "ArduPilot's own calibrators"). An uncalibrated
# compass adds its hard iron: offsets up to COMPASS_OFFS_MAX (default 1800 mGauss on newer
# firmware, ardupilot-facts.md) are still calibratable, so 1000 + 1800 ≈ 3000 mGauss is the top;
# a third of 150 the bottom. The median magnitude is compared.
PLAUSIBLE_MAG_MGAUSS = (50.0, 3000.0)
EARTH_FIELD_MGAUSS = (150.0, 1000.0)
# A still accelerometer reads g (ardupilot-facts.md "Frames and signs"); scale errors of a few
# per cent (INS_ACCSCAL allows 0.8..1.2) and moves by hand keep the median within half to twice g.
PLAUSIBLE_ACC_M_S2 = (0.5 * STANDARD_GRAVITY, 2.0 * STANDARD_GRAVITY)
# Still, a gyro reads its bias plus the Earth rate: an MPU-6000's zero-rate offset is at most
# ±20 °/s (0.35 rad/s, datasheet), yet a real PXF board logged 0.56 rad/s at rest
# (the real log pxf_copter_static_51.BIN of the test data). The stillest tenth of the samples must
# stay below 5 rad/s: mrad/s read as rad/s gives 1000 times the bias, tens of rad/s and more.
PLAUSIBLE_STILL_GYRO_RAD_S = 5.0
STILLEST_FRACTION_PERCENT = 10.0

# The known firmware fault: HIGHRES_IMU mag 1e6 times too large (mGauss×1000 instead of gauss)
HIGHRES_MAG_FAULT_FACTOR = 1e6


def sensor_magnitude(recording: Recording, sensor: str) -> float:
    """The statistic checked for ``sensor``: median |vector| (acc [m/s²], mag [mGauss]) or the
    10th percentile of |vector| (gyr [rad/s], its stillest samples). NaN without finite rows.

    Parameters
    ----------
    recording : Recording
    sensor : str
        "acc", "gyr" or "mag".

    Returns
    -------
    float
        In the sensor's unit: m/s², rad/s or mGauss.
    """
    xyz = recording.xyz(sensor)
    norm = np.linalg.norm(xyz[np.isfinite(xyz).all(axis=1)], axis=1)
    if len(norm) == 0:
        return float("nan")
    if sensor == "gyr":
        return float(np.percentile(norm, STILLEST_FRACTION_PERCENT))
    return float(np.median(norm))


def implausibility(recording: Recording, sensor: str) -> str | None:
    """Why ``sensor``'s units are implausible in ``recording``, or None when they are fine."""
    value = sensor_magnitude(recording, sensor)
    if not np.isfinite(value):
        return None
    label = f"{recording.message}[{recording.instance}] {sensor}"
    if sensor == "mag":
        low, high = PLAUSIBLE_MAG_MGAUSS
        if low <= value <= high:
            return None
        why = (f"{label}: median field magnitude {value:.4g} mGauss, where the Earth's is "
               f"{EARTH_FIELD_MGAUSS[0]:g}-{EARTH_FIELD_MGAUSS[1]:g} mGauss ({low:g}-{high:g} "
               f"accepted with hard iron): wrong units")
        if recording.message == "HIGHRES_IMU" and low <= value / HIGHRES_MAG_FAULT_FACTOR <= high:
            why += (" (ArduPilot firmware of about May 2024 - Feb 2026 sends HIGHRES_IMU "
                    "xmag/ymag/zmag in mGauss×1000 instead of gauss)")
        return why
    if sensor == "acc":
        low, high = PLAUSIBLE_ACC_M_S2
        if low <= value <= high:
            return None
        return (f"{label}: median magnitude {value:.4g} m/s², where gravity is "
                f"{STANDARD_GRAVITY:.2f} ({low:.2f}-{high:.2f} accepted): wrong units")
    if value <= PLAUSIBLE_STILL_GYRO_RAD_S:
        return None
    return (f"{label}: even its stillest tenth turns at {value:.4g} rad/s or more, where a gyro "
            f"at rest reads below {PLAUSIBLE_STILL_GYRO_RAD_S:g} rad/s: wrong units")


def drop_implausible_sensors(out: LogContents) -> list[str]:
    """Remove from ``out``'s recordings every sensor whose units fail :func:`implausibility`.

    Each removal adds a "warning: " line to ``out.messages``; a recording left without sensors
    is removed. Returns the reasons (for an error when nothing usable is left).
    """
    reasons = []
    kept = []
    for rec in out.recordings:
        for sensor in rec.sensors:
            why = implausibility(rec, sensor)
            if why is None:
                continue
            reasons.append(why)
            rec.data = rec.data.drop(columns=SENSOR_COLUMNS[sensor])
            out.messages.append(f"warning: {why}; not used (taken from another message of this "
                                f"IMU when the log has one)")
        if rec.sensors:
            kept.append(rec)
    out.recordings = kept
    return reasons


def require_plausible_units(contents: LogContents) -> None:
    """:func:`drop_implausible_sensors` on an ArduPilot log (not a CSV file); ApmcalError naming
    every reason when no recording is left.

    Raises
    ------
    ApmcalError
        No recording left with a sensor in plausible units.
    """
    if not contents.recordings:
        return
    if contents.format == "csv":
        require_plausible_csv_units(contents)
        return
    reasons = drop_implausible_sensors(contents)
    if not contents.recordings:
        raise ApmcalError("no IMU data in plausible units: " + "; ".join(reasons), contents.path)


# A still gyro's bias stays within ±20 °/s (MPU-6000 datasheet zero-rate offset); a CSV gyro
# whose stillest tenth reads more is in deg/s (a bias of a few °/s read as rad/s), and none
# measures beyond ±2000 °/s (35 rad/s), the widest range of the MEMS gyros ArduPilot supports.
CSV_STILL_GYRO_RAD_S = 0.35
GYRO_RANGE_RAD_S = 35.0


def csv_unit_problem(recording: Recording, sensor: str) -> str | None:
    """Why a CSV sensor's values are not in the SI units apmcal reads (m/s², rad/s, mGauss),
    with the header that declares them; None when they are plausible."""
    value = sensor_magnitude(recording, sensor)
    if not np.isfinite(value):
        return None
    col = f"{sensor}_x"
    if sensor == "acc":
        low, high = PLAUSIBLE_ACC_M_S2
        if low <= value <= high:
            return None
        if 0.5 <= value <= 2.0:
            guess = f"g (name the columns {col}[g], ...)"
        elif 500 <= value <= 2000:
            guess = f"mg (name the columns {col}[mg], ...) or raw counts ({col}[counts])"
        else:
            guess = f"raw counts? (name the columns {col}[counts], ..., to calibrate counts)"
        return (f"acc: median |a| is {value:.4g}, where a still accelerometer reads "
                f"{STANDARD_GRAVITY:.2f} m/s²: this looks like {guess}")
    if sensor == "gyr":
        norm = np.linalg.norm(recording.xyz("gyr"), axis=1)
        top = float(np.max(norm[np.isfinite(norm)]))      # nan/inf samples are dropped later
        if value <= CSV_STILL_GYRO_RAD_S and top <= GYRO_RANGE_RAD_S:
            return None
        return (f"gyr: the stillest tenth reads {value:.3g} and the fastest {top:.3g}, where a "
                f"gyro at rest reads below {CSV_STILL_GYRO_RAD_S} rad/s and none beyond "
                f"{GYRO_RANGE_RAD_S:g} rad/s: this looks like deg/s (name the columns "
                f"gyr_x[deg/s], ...) or raw counts (gyr_x[counts])")
    low, high = PLAUSIBLE_MAG_MGAUSS
    if low <= value <= high:
        return None
    if 15 <= value <= 100:
        guess = "µT (name the columns mag_x[uT], ...)"
    elif 0.15 <= value <= 1.0:
        guess = "gauss (name the columns mag_x[gauss], ...)"
    else:
        guess = "raw counts? (name the columns mag_x[counts], ...)"
    return (f"mag: median field {value:.4g}, where the Earth's is {EARTH_FIELD_MGAUSS[0]:g}-"
            f"{EARTH_FIELD_MGAUSS[1]:g} mGauss: this looks like {guess}")


def require_plausible_csv_units(contents: LogContents) -> None:
    """ApmcalError naming every CSV sensor in implausible units and the header that fixes it;
    sensors the reader kept as raw counts (noted in ``messages``) are not checked."""
    counts = {m.split(":")[0] for m in contents.messages if "raw sensor counts" in m}
    problems = [why for rec in contents.recordings for sensor in rec.sensors
                if sensor not in counts and (why := csv_unit_problem(rec, sensor))]
    if problems:
        raise ApmcalError("units not m/s², rad/s, mGauss: " + "; ".join(problems)
                          + "; or convert the file", contents.path)
