"""The candidate unmodelled effects: what each adds to the model and what it needs to be seen.

The names are sitl's canonical diagnosis names (:data:`apmcal.sensor_model.truth.DIAGNOSIS_EFFECTS` maps each
to the simulator's switches), so a selected effect with its fitted parameters is a simulator
configuration (``apmcal gap --write-twin``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_TEMPERATURE_RANGE_K = 1.0     # a smaller spread cannot separate a temperature term
MIN_DRIFT_SPAN_S = 60.0           # a shorter record cannot see a drift beside the noise
MIN_GEOMETRY_HOLDS = 6            # distinct still orientations for the geometric terms
MIN_HELD_OUT_PIECES = 3           # still pieces each half needs for its piece means to be scored
TOO_SHORT = "too short"           # how a reason of the session's length begins


@dataclass(frozen=True)
class Effect:
    """One candidate: its name, the sensors it changes, and one line on what it is."""

    name: str
    sensors: tuple
    summary: str
    needs: tuple = ()        # requirement keys, see :func:`unmet`


CATALOGUE = (
    Effect("temperature_drift", ("acc", "gyr"),
           "bias changing linearly with the board temperature", ("temperature", "pieces")),
    Effect("bias_drift", ("gyr",), "gyro bias drifting linearly in time ([Oppong] eq. 5)",
           ("duration", "pieces")),
    Effect("triangle_drift", ("gyr",),
           "ArduPilot SITL's triangle-wave gyro drift (SIM_DRIFT_SPEED, SIM_DRIFT_TIME)",
           ("duration", "pieces")),
    Effect("bias_random_walk", ("gyr",), "gyro bias wandering as a random walk",
           ("duration", "pieces")),
    Effect("g_sensitivity", ("gyr",), "gyro output proportional to specific force",
           ("orientations",)),
    Effect("earth_rate", ("gyr",), "the Earth's rotation seen by the gyro in each pose",
           ("orientations",)),
    Effect("cross_axis", ("acc",), "accelerometer axes not orthogonal ([Oppong] §2.1)",
           ("geometry",)),
    Effect("scale_nonlinearity", ("acc",), "accelerometer scale changing with the reading",
           ("geometry",)),
    Effect("local_gravity", ("acc",),
           "local gravity instead of the standard 9.80665 m/s² (needs --lat)", ("latitude",)),
    Effect("gyro_scale", ("gyr",), "gyro scale factors and axis misalignment",
           ("moves",)),
    Effect("time_offset", ("acc",), "accelerometer samples later than the gyro",
           ("moves",)),
    Effect("quantization", ("acc", "gyr"), "sensor readings rounded to a fixed step",
           ("lattice",)),
    Effect("lowpass_filter", ("acc", "gyr"), "on-chip low-pass filter correlating the noise"),
    Effect("uniform_noise", ("acc", "gyr", "mag"),
           "uniform instead of Gaussian noise (ArduPilot SITL's rand_float)"),
    Effect("motion_contamination", ("acc", "gyr"), "hand tremor and sway during the holds"),
    Effect("mag_interference", ("mag",), "compass offset proportional to battery current",
           ("compass", "current")),
)
BY_NAME = {e.name: e for e in CATALOGUE}
NAMES = tuple(e.name for e in CATALOGUE)


def unmet(effect: Effect, session, context) -> str | None:
    """Why ``effect`` cannot be tested on this session, or None when it can.

    ``context`` holds what the evaluator knows: orientation count, lattice steps.
    """
    for need in effect.needs:
        reason = _CHECKS[need](session, context)
        if reason:
            return reason
    return None


def _temperature(session, context):
    if session.temp is None:
        return "no temperature in the log"
    spread = float(np.nanmax(session.temp) - np.nanmin(session.temp))
    if spread < MIN_TEMPERATURE_RANGE_K:
        return f"temperature spans only {spread:.1f} K"
    return None


def _duration(session, context):
    if session.duration < MIN_DRIFT_SPAN_S:
        return f"{TOO_SHORT}: {session.duration:.0f} s of data (needs {MIN_DRIFT_SPAN_S:.0f} s)"
    return None


def _pieces(session, context):
    """A bias that changes in time differs from a constant one across the still pieces: the
    held-out half's piece means are its evidence (and its null sessions'), scored only when
    that half has :data:`MIN_HELD_OUT_PIECES` of them."""
    pc = session.pieces
    per_half = [int(np.sum(pc.is_hold & (pc.fold == fold))) for fold in (0, 1)]
    if min(per_half) < MIN_HELD_OUT_PIECES:
        return (f"{TOO_SHORT}: {min(per_half)} still piece(s) in a half (needs "
                f"{MIN_HELD_OUT_PIECES}: longer or more still poses)")
    return None


def _orientations(session, context):
    if context.orientations < 2:
        return "all holds in one orientation"
    return None


def _geometry(session, context):
    if context.orientations < MIN_GEOMETRY_HOLDS:
        return (f"{context.orientations} distinct still orientation(s) "
                f"(needs {MIN_GEOMETRY_HOLDS})")
    return None


def _latitude(session, context):
    return None if session.lat_deg is not None else "no latitude given (--lat)"


def _moves(session, context):
    if not np.any(~session.pieces.is_hold):
        return "no moves between holds"
    return None


def _lattice(session, context):
    floating = [s for s in ("acc", "gyr") if s not in session.integer_sensors]
    if not any(context.steps.get(s) is not None for s in floating):
        return "no sensor reading on a rounding lattice (beyond the log format's own)"
    return None


def _compass(session, context):
    return None if session.mag is not None else "no compass samples"


def _current(session, context):
    if session.current is None:
        return "no battery current in the log"
    if np.nanmax(session.current) - np.nanmin(session.current) < 0.5:
        return "battery current constant"
    return None


_CHECKS = {"temperature": _temperature, "duration": _duration, "pieces": _pieces,
           "orientations": _orientations,
           "geometry": _geometry, "latitude": _latitude, "moves": _moves,
           "lattice": _lattice, "compass": _compass, "current": _current}
