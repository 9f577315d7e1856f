"""``apmcal gap --write-twin FILE.parm``: the fitted board as ArduPilot SITL parameters.

ArduPilot's own simulator (SITL) reads its sensor errors from SIM_* parameters; this module
turns the twin (a :class:`~apmcal.sensor_model.truth.Truth`, as ``--write-twin FILE.json``
writes it) into those parameters, so that ArduPilot's SITL behaves like the board as far as its
sensor model can. Every line's model, unit and sign is in docs/ardupilot-facts.md "ArduPilot
SITL (its own simulator) and its SIM_* parameters"; the mapping, what cannot be mapped and why,
is docs/sitl-twin.md. In short, with the twin's sensor = F·x + b (sensor frame = board frame):

- accelerometer: SITL reads f ⊘ SIM_ACC1_SCAL + SIM_ACC1_BIAS, so SIM_ACC1_SCAL = 1 / F_ii,
  SIM_ACC1_BIAS = b [m/s²];
- gyro: SITL reads (ω + drift + T-term)·(1 + SIM_GYR1_SCALE/100) + SIM_GYR1_BIAS, so
  SIM_GYR1_SCALE = 100·(F_ii − 1) [%], SIM_GYR1_BIAS = b [rad/s], and the temperature
  coefficients are divided by 1 + SCALE/100 (SITL scales its temperature term, the twin does not);
- temperature: SITL's curve T = END − (END − START)·e^(−t/TCONST) is the twin's warm-up curve
  (START = ambient, END = ambient + rise, TCONST = τ); its error 1e-6·SIM_IMUT1_ACC1·(T − tmid),
  tmid = (TMIN + TMAX)/2, is the twin's coefficient·(T − ambient) with TMIN/TMAX centred on the
  ambient temperature and ACC1/GYR1 = 1e6·coefficient;
- triangle drift: SIM_DRIFT_SPEED [°/s per minute] and SIM_DRIFT_TIME [min, half the cycle] are
  the twin's own; without the effect SIM_DRIFT_SPEED = 0 (ArduPilot's default, 0.05, is a drift);
- compass: SITL reads M⁻¹·(B + SIM_MAG_MOT·I) − SIM_MAG1_OFS, M from SIM_MAG1_DIA/ODI, so with
  the twin's m = S·B + h + k·I: M = S⁻¹ (DIA its diagonal, ODI its xy, xz, yz), SIM_MAG1_OFS = −h,
  SIM_MAG_MOT = S⁻¹·k [mGauss/A], SIM_MAG_RND = √3·σ (SITL's compass noise is uniform);
- a low-pass filter: INS_GYRO_FILTER, INS_ACCEL_FILTER [Hz] (the firmware's own filters, which
  run in SITL as on a board).

What SITL has no parameter for is written as a comment line naming it, never approximated.
"""
from __future__ import annotations

import numpy as np

from apmcal.sensor_model.truth import FULL_THROTTLE_CURRENT_A

TCAL_SCALE = 1.0e6          # SIM_IMUT1_ACC1 = 1e6 × coefficient (INV_SCALE_FACTOR 1e-6)
TCAL_HALF_SPAN_K = 30.0     # SIM_IMUT1_TMIN/TMAX = ambient ∓ this (TMAX ≥ TMIN + 10)
TCAL_LIMITS_C = (-70.0, 80.0)   # @Range of SIM_IMUTn_TMIN / TMAX
AXES = "XYZ"
# SITL's noise at rest, fixed in its code: accel 0.01·rand_float(), gyro two draws of
# radians(0.04)·rand_float() (rand_float uniform on [−1, 1): σ = amplitude/√3)
REST_ACC_SIGMA = 0.01 / np.sqrt(3.0)                     # m/s²
REST_GYR_SIGMA = np.radians(0.04) * np.sqrt(2.0 / 3.0)  # rad/s

# the effects SITL has no parameter for, and why (one comment line each in the file)
UNMAPPED = {
    "gyro_bias_drift": "a linear gyro drift per axis (SITL's only drift, SIM_DRIFT_*, is a "
                       "triangle wave, the same on every axis)",
    "gyro_bias_random_walk": "a gyro bias random walk",
    "g_sensitivity": "gyro g-sensitivity",
    "earth_rate": "the Earth's rotation (SITL's gyro sees none)",
    "acc_cross_axis": "accelerometer cross-axis terms (SIM_ACC1_SCAL is diagonal)",
    "acc_misalignment": "accelerometer misalignment",
    "gyro_misalignment": "gyro misalignment (SIM_GYR1_SCALE is diagonal)",
    "scale_nonlinearity": "scale non-linearity",
    "local_gravity": "local gravity (SITL's physics uses a fixed gravity)",
    "time_offset": "an accelerometer-gyro time offset",
    "quantization": "rounding to an ADC step",
    "motion_contamination": "hand tremor and sway",
}


def _vector(values: dict, name: str, v) -> None:
    for axis, x in zip(AXES, np.asarray(v, float)):
        values[f"{name}_{axis}"] = float(x) + 0.0     # no "-0" in the file


def sitl_parameters(truth, *, compass: bool, sigma: dict) -> tuple[dict, list[str]]:
    """The twin as SIM_* (and INS_*_FILTER) parameters, and the comment lines.

    Parameters
    ----------
    truth : apmcal.sensor_model.truth.Truth
        The twin (:func:`apmcal.diagnosis.twin.file.standalone_truth`): biases at the start of
        its warm-up curve, sensor frame = board frame.
    compass : bool
        Whether the session had a compass (the SIM_MAG* lines).
    sigma : dict
        White noise per sample of each sensor, "acc" [m/s²], "gyr" [rad/s], "mag" [mGauss],
        (3,) each (for the noise lines).

    Returns
    -------
    values : dict
        {parameter name: value} in ArduPilot's units.
    comments : list of str
        What could not be mapped, and how the noise compares.
    """
    on = truth.on
    values: dict = {}
    comments: list[str] = []
    acc_f = truth.acc_forward()
    gyr_f = truth.gyro_forward()
    _vector(values, "SIM_ACC1_BIAS", truth.acc_bias if on("acc_bias") else np.zeros(3))
    _vector(values, "SIM_ACC1_SCAL", 1.0 / np.diag(acc_f))
    gyro_scale = np.diag(gyr_f)
    _vector(values, "SIM_GYR1_SCALE", 100.0 * (gyro_scale - 1.0))
    _vector(values, "SIM_GYR1_BIAS", truth.gyro_bias if on("gyro_bias") else np.zeros(3))
    _drift(values, truth)
    _temperature(values, truth, gyro_scale)
    if compass:
        _compass(values, comments, truth, sigma.get("mag"))
    if on("lowpass_filter"):
        values["INS_GYRO_FILTER"] = float(truth.lowpass_cutoff("gyro"))
        values["INS_ACCEL_FILTER"] = float(truth.lowpass_cutoff("acc"))
    comments.extend(_noise_comments(sigma))
    for effect, what in UNMAPPED.items():
        if on(effect) and not (effect == "gyro_bias_drift" and not np.any(truth.gyro_bias_drift)):
            comments.append(f"not mapped: {what} — SITL has no parameter for it")
    return values, comments


def _drift(values: dict, truth) -> None:
    p = truth.triangle_drift
    values["SIM_DRIFT_SPEED"] = float(p["speed_dps_per_min"]) if truth.on("triangle_drift") \
        else 0.0
    values["SIM_DRIFT_TIME"] = float(p["time_min"])


def _temperature(values: dict, truth, gyro_scale: np.ndarray) -> None:
    t = truth.temperature
    ambient = float(t["ambient_c"])
    values["SIM_IMUT_START"] = ambient
    values["SIM_IMUT_END"] = ambient + float(t["rise_k"])
    values["SIM_IMUT_TCONST"] = float(t["tau_s"])
    values["SIM_IMUT_FIXED"] = 0.0
    half = min(TCAL_HALF_SPAN_K, ambient - TCAL_LIMITS_C[0], TCAL_LIMITS_C[1] - ambient)
    drift = truth.on("temperature_drift")
    values["SIM_IMUT1_ENABLE"] = 1.0 if drift else 0.0
    values["SIM_IMUT1_TMIN"] = ambient - half
    values["SIM_IMUT1_TMAX"] = ambient + half
    acc = np.asarray(t["acc_coef"], float) if drift else np.zeros(3)
    # SITL multiplies its temperature term by 1 + SIM_GYR1_SCALE/100, the twin does not
    gyr = np.asarray(t["gyro_coef"], float) / gyro_scale if drift else np.zeros(3)
    for order in (1, 2, 3):
        _vector(values, f"SIM_IMUT1_ACC{order}", TCAL_SCALE * acc if order == 1 else np.zeros(3))
        _vector(values, f"SIM_IMUT1_GYR{order}", TCAL_SCALE * gyr if order == 1 else np.zeros(3))


def _compass(values: dict, comments: list, truth, mag_sigma) -> None:
    s = truth.mag_forward() if truth.on("mag_soft_iron") else np.eye(3)
    sym = 0.5 * (s + s.T)
    if not np.allclose(s, sym, atol=1e-9):
        comments.append("not mapped: the antisymmetric part of the soft-iron matrix (SIM_MAG1_DIA/"
                        "ODI make a symmetric one)")
    m = np.linalg.inv(sym)
    _vector(values, "SIM_MAG1_DIA", np.diag(m))
    _vector(values, "SIM_MAG1_ODI", [m[0, 1], m[0, 2], m[1, 2]])
    hard = np.asarray(truth.mag_hard_iron, float) if truth.on("mag_hard_iron") else np.zeros(3)
    _vector(values, "SIM_MAG1_OFS", -hard)
    per_amp = np.asarray(truth.mag_interference, float) / FULL_THROTTLE_CURRENT_A \
        if truth.on("mag_interference") else np.zeros(3)
    _vector(values, "SIM_MAG_MOT", m @ per_amp)
    if mag_sigma is not None:
        values["SIM_MAG_RND"] = float(np.sqrt(3.0) * np.mean(mag_sigma))


def _noise_comments(sigma: dict) -> list[str]:
    """The board's white noise against SITL's fixed noise at rest (no parameter sets it: the
    SIM_ACC1_RND / SIM_GYR1_RND amplitudes act only while the motors run)."""
    out = []
    for sensor, rest, unit in (("acc", REST_ACC_SIGMA, "m/s²"), ("gyr", REST_GYR_SIGMA, "rad/s")):
        if sigma.get(sensor) is None:
            continue
        board = float(np.mean(sigma[sensor]))
        out.append(f"not mapped: {sensor} white noise σ {board:.3g} {unit} per sample; SITL's at "
                   f"rest is fixed at {rest:.3g} {unit} (this board's is {board / rest:.2g}× "
                   f"SITL's); SIM_{'ACC' if sensor == 'acc' else 'GYR'}1_RND only scales the "
                   f"noise while the motors run")
    return out


def write_sitl_params(path, truth, *, compass: bool, sigma: dict, source: str,
                      selected: list) -> None:
    """Write the parameter file (NAME VALUE lines, # comments first).

    Raises
    ------
    ApmcalError
        When the file cannot be written.
    """
    from apmcal.ardupilot.paramfile import write_param_file

    values, comments = sitl_parameters(truth, compass=compass, sigma=sigma)
    header = "\n".join([f"ArduPilot SITL twin of {source} (apmcal gap --write-twin)",
                        f"selected effects: {', '.join(selected) or 'none'}",
                        "load into SITL (e.g. sim_vehicle.py --add-param-file); mapping and "
                        "sources: docs/sitl-twin.md", *comments])
    write_param_file(path, values, header)
