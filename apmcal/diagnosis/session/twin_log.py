"""A recorded twin — the same session recorded again by a simulator set up as the board's twin
(ArduPilot SITL booted with ``apmcal gap --write-twin FILE.parm``) — put on the real session's
samples, so that it takes the place of the simulated twin (``apmcal gap REAL --twin-log
TWIN``).

Each real sample takes the twin's sample nearest to it in time: time since the start of each
log, warped piecewise so that the still holds of the two coincide when both have as many (a
replay of the same script runs on nearly the same schedule, but each command to the simulator
can shift what follows by a fraction of a second — enough to put a turn inside a real hold);
a hold's start at its log's start, or end at its log's end, is where a recording began or
stopped, not part of the schedule, and sets no knot.
At the same rate this is one-to-one. The twin must be as fast as the real log, cover it, and be
written in its format (integers where the real log has integers: the rounding is part of what
is compared).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from apmcal.core.errors import ApmcalError

MIN_RATE_SHARE = 0.95   # the twin's sample rate at least this share of the real one's
MAX_STRETCH = 0.05      # a hold or move of the twin at most this share (or 1 s) longer or
                        # shorter than the real one's, for the two to be warped onto each other


def on_samples_of(real, twin, path: str = ""):
    """``twin`` (a Session) on the samples of ``real``: its readings, temperature, current and
    compass at the real session's sample times (since the start of each log), with the real
    session's holds, moves and pieces.

    Parameters
    ----------
    real, twin : Session
        The real session and the recorded twin's, each cut from its own log.
    path : str
        The twin log (for the error messages).

    Returns
    -------
    Session

    Raises
    ------
    ApmcalError
        When the twin is slower than the real log, shorter, in another format, or without a
        compass where the real log has one.
    """
    where = path or twin.source
    if twin.fs < MIN_RATE_SHARE * real.fs:
        raise ApmcalError(f"the twin log's IMU runs at {twin.fs:.3g} Hz, the real log's at "
                          f"{real.fs:.3g} Hz: record the twin at the real log's rate", where)
    at = twin_times(real, twin)
    if at[-1] > twin.t[-1] - twin.t[0] + 2.0 / real.fs or at[0] < -2.0 / real.fs:
        raise ApmcalError(f"the twin log covers {twin.t[-1] - twin.t[0]:.0f} s, the real log "
                          f"{real.t[-1] - real.t[0]:.0f} s: record the whole session again",
                          where)
    if set(twin.integer_sensors) != set(real.integer_sensors):
        raise ApmcalError("the twin log stores "
                          f"{', '.join(sorted(twin.integer_sensors)) or 'no sensor'} as "
                          "integers, the real log "
                          f"{', '.join(sorted(real.integer_sensors)) or 'none'}: record the "
                          "twin in the real log's format (.tlog or dataflash)", where)
    if real.mag is not None and twin.mag is None:
        raise ApmcalError("the twin log has no compass samples, the real log has", where)
    i = nearest(twin.t - twin.t[0], at)
    out = replace(real, source=twin.source, acc=twin.acc[i], gyr=twin.gyr[i],
                  temp=_column(twin.temp, real.temp, i),
                  current=_column(twin.current, real.current, i), notes=list(twin.notes))
    if real.mag is not None:
        m = nearest(twin.mag.t - twin.t[0], np.interp(real.mag.t, real.t, at))
        current = None if real.mag.current is None else \
            _column(twin.mag.current, real.mag.current, m)
        out.mag = replace(real.mag, values=twin.mag.values[m], current=current)
    return out


def twin_times(real, twin) -> np.ndarray:
    """For each real sample, the time since the twin log's start it corresponds to: the time
    since the real log's start, warped linearly between the starts and ends of the holds when
    the two sessions have as many holds of about the same lengths (else unwarped)."""
    t = real.t - real.t[0]
    if len(real.holds) != len(twin.holds) or not real.holds:
        return t
    # a hold that ends where its log ends was cut by the recording's end, not by the script:
    # the twin is recorded a little longer, and that end as a knot stretched a still warm-up
    # by 2-3 % (and put its start before the twin's); likewise a hold from the log's start
    ends = [(h.i0 > 0 and g.i0 > 0, h.i1 < len(real.t) and g.i1 < len(twin.t))
            for h, g in zip(real.holds, twin.holds)]
    keep = np.array(ends).ravel()
    x = np.concatenate([real.t[[h.i0, h.i1 - 1]] - real.t[0] for h in real.holds])[keep]
    y = np.concatenate([twin.t[[h.i0, h.i1 - 1]] - twin.t[0] for h in twin.holds])[keep]
    if len(x) < 2:
        return t        # no schedule to warp by: a still session is one hold from boot on
    dx, dy = np.diff(x), np.diff(y)
    if np.any(dx <= 0) or np.any(dy <= 0) or \
            np.any(np.abs(dy - dx) > np.maximum(MAX_STRETCH * dx, 1.0)):
        return t        # not the same schedule: no warp (and a shorter twin is refused)
    # before the first hold and after the last: the offset of the nearest knot
    return np.where(t < x[0], t + (y[0] - x[0]),
                 np.where(t > x[-1], t + (y[-1] - x[-1]), np.interp(t, x, y)))


def nearest(t_from: np.ndarray, t_at: np.ndarray) -> np.ndarray:
    """Index into ``t_from`` (increasing) of the time nearest to each of ``t_at``."""
    j = np.clip(np.searchsorted(t_from, t_at), 1, len(t_from) - 1)
    return np.where(np.abs(t_from[j - 1] - t_at) <= np.abs(t_from[j] - t_at), j - 1, j)


def _column(twin_values, real_values, index):
    """A twin's optional column at the real samples; the real one where the twin has none."""
    if twin_values is None:
        return real_values
    return np.asarray(twin_values)[index]
