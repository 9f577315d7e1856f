"""Make a recording's time base usable: strictly increasing sample times.

Telemetry logs can hold repeated samples (a message sent twice) and backward jumps (a reboot,
or SITL's clock restarting). Solvers need strictly increasing time, so duplicates are dropped
and, at a backward jump, only the longest monotonic run is kept; the caller gets a warning.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.core.recording import Recording


def longest_increasing_run(t: np.ndarray) -> slice:
    """Index range of the longest run of non-decreasing times (a run ends at a backward jump).

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].

    Returns
    -------
    slice
    """
    breaks = np.flatnonzero(np.diff(t) < 0) + 1
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks, [len(t)]])
    k = int(np.argmax(ends - starts))
    return slice(int(starts[k]), int(ends[k]))


def monotonic(recording: Recording) -> tuple[Recording, list[str]]:
    """The recording with strictly increasing, finite time, and warnings saying what was cut.

    Raises
    ------
    ApmcalError
        Fewer than two samples with a finite time.
    """
    t = recording.t
    finite = np.isfinite(t)
    if finite.sum() < 2:
        raise ApmcalError("fewer than two samples with a valid time", recording.source)
    warnings = []
    data = recording.data[finite]
    t = t[finite]
    if not finite.all():
        warnings.append(f"{int((~finite).sum())} samples without a valid time dropped")
    run = longest_increasing_run(t)
    if run.stop - run.start < len(t):
        warnings.append(f"time jumps backwards (reboot?): kept the longest run, "
                        f"{t[run.start]:.3f}-{t[run.stop - 1]:.3f} s "
                        f"({run.stop - run.start} of {len(t)} samples)")
        data, t = data.iloc[run], t[run]
    keep = np.concatenate([[True], np.diff(t) > 0])
    if not keep.all():
        warnings.append(f"{int((~keep).sum())} samples with a repeated time dropped")
        data = data[keep]
    if len(data) == len(recording.data):
        return recording, []
    return replace(recording, data=data.reset_index(drop=True)), warnings
