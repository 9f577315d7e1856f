"""The answer in words: what to do about each selected effect, one sentence each.

Each sentence says the cause, the evidence in physical units (the fitted parameters of the
result, mean of the two folds), the action on the vehicle, and what to set in the simulator —
``apmcal_sim`` (the truth key a ``--write-twin`` JSON file holds) and, where it has one,
ArduPilot's own SITL (the SIM_* parameter a ``--write-twin FILE.parm`` file holds; mapping and
sources in docs/sitl-twin.md). With nothing selected the answer is that there is nothing to add
— or that the session was too short to tell, when an effect could not be tested for its length.
Works from the saved result alone (:class:`~apmcal.diagnosis.output.result.GapResult`).
"""
from __future__ import annotations

import numpy as np

from apmcal.diagnosis.model.effects import TOO_SHORT

NOTHING = "Nothing to add: the simulator matches this board"
NOTHING_LEFT = "Nothing left: the recorded twin matches this board"
SHORT = "Too short to tell"
MRAD = 1e3          # rad → mrad
MG = 1e3 / 9.80665  # m/s² → mg


def _values(e: dict, key: str) -> np.ndarray | None:
    p = e.get("params", {}).get(key)
    if not p:
        return None
    v = np.asarray(p["value"], dtype=float)
    return v if np.all(np.isfinite(v)) else None


def _axes(v: np.ndarray, scale: float, fmt: str = "{:.2g}") -> str:
    """'x 0.17, y 0.0, z −0.05' of a 3-vector in the unit ``scale`` turns it to."""
    return ", ".join(f"{a} {fmt.format(float(x) * scale)}" for a, x in zip("xyz", v))


def _largest(v: np.ndarray) -> str:
    return "xyz"[int(np.argmax(np.abs(v)))]


def _temperature(e: dict, result) -> str:
    gyro, acc = _values(e, "gyro_coef"), _values(e, "acc_coef")
    span = result.session.get("temperature_c")
    over = f" over {span[0]:.0f}-{span[1]:.0f} °C" if span else ""
    parts = []
    if gyro is not None:
        parts.append(f"gyro {_axes(gyro, MRAD)} mrad/s per °C")
    if acc is not None:
        parts.append(f"accelerometer {_axes(acc, MG)} mg per °C")
    lead = "gyro" if gyro is not None and (acc is None or np.max(np.abs(gyro)) * MRAD
                                           >= np.max(np.abs(acc)) * MG / 10) else \
        "accelerometer"
    return (f"Calibrate the temperature drift with `apmcal tcal` on a warm-up log: the "
            f"{lead} bias changes with the board temperature ({'; '.join(parts) or 'fitted'}"
            f"{over}); simulator: temperature_drift (ArduPilot SITL: SIM_IMUT_*).")


def _bias_drift(e: dict, result) -> str:
    v = _values(e, "gyro_drift")
    minutes = result.session.get("duration_s", 0.0) / 60.0
    ev = f" ({_axes(v, MRAD * 60)} mrad/s per minute over {minutes:.0f} min)" \
        if v is not None else ""
    return (f"Let the board warm up and recalibrate the gyro at boot (INS_GYR_CAL=1): its bias "
            f"drifts steadily in time{ev}; simulator: gyro_bias_drift (no ArduPilot SITL "
            f"equivalent: its SIM_DRIFT_* drift is a triangle wave).")


def _triangle(e: dict, result) -> str:
    speed, half = _values(e, "speed"), _values(e, "drift_time")
    ev = ""
    if speed is not None and half is not None:
        ev = (f" ({float(speed):.3g} °/s per minute, turning back every {float(half):.3g} min, "
              f"the same on every axis)")
    return (f"This log comes from ArduPilot's SITL with its gyro drift on: the gyro bias follows "
            f"a triangle wave{ev}; set SIM_DRIFT_SPEED=0 for a drift-free simulation, or keep "
            f"it (SIM_DRIFT_SPEED, SIM_DRIFT_TIME) to reproduce this log; simulator: "
            f"triangle_drift.")


def _random_walk(e: dict, result) -> str:
    q = _values(e, "gyro_q")
    ev = f" (rate random walk {_axes(q, MRAD)} mrad/s/√s)" if q is not None else ""
    return (f"Let the EKF track the gyro bias (EK3_GBIAS_P_NSE at least this) and recalibrate "
            f"before flight: the gyro bias wanders as a random walk{ev}; simulator: "
            f"gyro_bias_random_walk (no ArduPilot SITL equivalent).")


def _g_sensitivity(e: dict, result) -> str:
    m = _values(e, "matrix")
    ev = f" (largest term {np.max(np.abs(m)) * MRAD * 9.80665:.2g} mrad/s per g)" \
        if m is not None else ""
    return (f"Isolate the board from vibration and keep it out of hard accelerations where "
            f"attitude matters: the gyro reads specific force{ev}, which no ArduPilot parameter "
            f"corrects; simulator: g_sensitivity (no ArduPilot SITL equivalent).")


def _earth_rate(e: dict, result) -> str:
    v = _values(e, "vertical")
    ev = f" (vertical {float(v) * MRAD:.3g} mrad/s)" if v is not None else ""
    return (f"Nothing to fix on the board: its gyro is good enough to see the Earth's "
            f"rotation{ev}; simulator: earth_rate (ArduPilot SITL simulates no Earth rate).")


def _cross_axis(e: dict, result) -> str:
    a = _values(e, "alpha")
    ev = f" (α_yz, α_zy, α_zx {', '.join(f'{x * MRAD:.2g}' for x in a)} mrad)" \
        if a is not None else ""
    return (f"Calibrate the accelerometer on six faces (ArduPilot's accelerometer calibration) "
            f"and check the board sits square: its axes are not orthogonal{ev}; simulator: "
            f"acc_cross_axis (no ArduPilot SITL equivalent).")


def _nonlinearity(e: dict, result) -> str:
    k2 = _values(e, "k2")
    ev = f" (k2 {_axes(k2, 1.0)} per m/s²)" if k2 is not None else ""
    return (f"Expect errors at large accelerations, which no ArduPilot parameter corrects: the "
            f"accelerometer scale changes with the reading{ev}; simulator: scale_nonlinearity.")


def _gravity(e: dict, result) -> str:
    g = _values(e, "gravity")
    ev = f" ({float(g):.5g} m/s²)" if g is not None else ""
    return (f"Nothing to fix: the accelerometer sees the local gravity{ev} rather than "
            f"9.80665 m/s²; simulator: local_gravity.")


def _gyro_scale(e: dict, result) -> str:
    s, g = _values(e, "scale"), _values(e, "misalignment")
    parts = []
    if s is not None:
        parts.append(f"scale {_axes(s - 1.0, 100.0)} %")
    if g is not None:
        parts.append(f"misalignment up to {np.max(np.abs(g)) * MRAD:.2g} mrad")
    ev = f" ({'; '.join(parts)})" if parts else ""
    return (f"Mount the board square and mind that ArduPilot has no gyro scale parameter: the "
            f"gyro's scale or axes are off{ev}; simulator: gyro_scale, gyro_misalignment "
            f"(ArduPilot SITL: SIM_GYR1_SCALE_*).")


def _time_offset(e: dict, result) -> str:
    d = _values(e, "delay")
    ev = f" by {float(d) * 1e3:.2g} ms" if d is not None else ""
    return (f"Check how the IMU is sampled (INS_FAST_SAMPLE, the driver's FIFO): the "
            f"accelerometer samples lag the gyro's{ev}; simulator: time_offset.")


def _quantization(e: dict, result) -> str:
    parts = []
    for key, unit, scale in (("acc_step", "mg", MG), ("gyr_step", "mrad/s", MRAD)):
        v = _values(e, key)
        if v is not None:
            parts.append(f"{key.split('_')[0]} {float(np.mean(v)) * scale:.3g} {unit}")
    ev = f" ({', '.join(parts)})" if parts else ""
    return (f"Use a finer sensor range if the steps matter: the readings are rounded to a "
            f"lattice{ev}; simulator: quantization.")


def _lowpass(e: dict, result) -> str:
    parts = []
    for key, sensor, param in (("gyr_cutoff", "gyro", "INS_GYRO_FILTER"),
                               ("acc_cutoff", "accelerometer", "INS_ACCEL_FILTER")):
        v = _values(e, key)
        if v is not None:
            parts.append(f"the {sensor} at {float(v):.3g} Hz ({param})")
    ev = " and ".join(parts) or "its readings"
    return (f"Set the same filters in the simulator: the board low-pass filters {ev}; "
            f"simulator: lowpass_filter (ArduPilot SITL: INS_GYRO_FILTER, INS_ACCEL_FILTER).")


def _uniform(e: dict, result) -> str:
    return ("This log comes from ArduPilot's SITL: its noise is uniform (rand_float), not a real "
            "sensor's Gaussian noise; simulator: uniform_noise (ArduPilot SITL: SIM_ACC1_RND, "
            "SIM_GYR1_RND set the width of its noise while the motors run).")


def _motion(e: dict, result) -> str:
    tremor, sway = _values(e, "tremor"), _values(e, "sway")
    ev = ""
    if tremor is not None and sway is not None:
        ev = f" (tremor {float(tremor):.2g}°, sway {float(sway):.2g}°)"
    return (f"Rest the board on a firm support during the still poses: the holds are not "
            f"still{ev}; simulator: motion_contamination.")


def _mag_interference(e: dict, result) -> str:
    k = _values(e, "per_amp")
    ev = f" ({_axes(k, 1.0)} mGauss per A)" if k is not None else ""
    return (f"Run the compass-motor calibration (COMPASS_MOTCT=2, per amp) or move the compass "
            f"away from the power wiring: the compass field follows the battery current{ev}; "
            f"simulator: mag_interference.")


SENTENCES = {"temperature_drift": _temperature, "bias_drift": _bias_drift,
             "triangle_drift": _triangle, "bias_random_walk": _random_walk,
             "g_sensitivity": _g_sensitivity, "earth_rate": _earth_rate,
             "cross_axis": _cross_axis, "scale_nonlinearity": _nonlinearity,
             "local_gravity": _gravity, "gyro_scale": _gyro_scale, "time_offset": _time_offset,
             "quantization": _quantization, "lowpass_filter": _lowpass,
             "uniform_noise": _uniform, "motion_contamination": _motion,
             "mag_interference": _mag_interference}


def advice(result) -> list[str]:
    """One sentence per selected effect, in the order of the selection (the one the model
    needs most first); :data:`NOTHING` when nothing is selected.

    Parameters
    ----------
    result : GapResult

    Returns
    -------
    list of str
    """
    out = []
    for name in result.selected:
        entry = result.effect(name) or {"name": name, "params": {}}
        out.append(SENTENCES[name](entry, result) if name in SENTENCES else
                   f"Model {name}; simulator: {name}.")
    if not out:
        out.append(_nothing(result))
    return out


def _nothing(result) -> str:
    """The answer with nothing selected: too short to tell when an effect could not be tested
    for the session's length, else nothing to add (against the simulated twin, or the
    recorded one)."""
    short = [e for e in result.effects
             if str(e.get("not_tested") or "").startswith(TOO_SHORT)]
    if short:
        names = ", ".join(e["name"] for e in short)
        why = short[0]["not_tested"][len(TOO_SHORT):].lstrip(": ")
        return (f"{SHORT}: {names} not tested — {why}. Nothing else explains the gap; record "
                f"a longer session before concluding that the simulator matches this board.")
    twin = result.session.get("twin_log")
    if twin:
        return (f"{NOTHING_LEFT} (no candidate effect explains the gap between the board and "
                f"its recorded twin {twin}).")
    return (f"{NOTHING} (no candidate effect explains the gap between it and its simulated "
            f"twin).")
