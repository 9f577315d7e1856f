"""The regions of a Ferraris session ([Oppong] §4): the six static faces and the full turn
about each axis, detected or taken from a hand-annotated section list (imucal's).

Detection lives here, not in the solver: :func:`apmcal.solvers.ferraris.ferraris_calibration`
receives these regions and only solves.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.rotations import Rotation, find_rotations, integrate_slice
from apmcal.preprocessing.static import (
    POSES,
    StaticSegment,
    find_static_segments,
    label_poses,
    make_segment,
)

AXES = "xyz"


@dataclass
class FerrarisRegions:
    """Where a Ferraris session's parts lie.

    Attributes
    ----------
    poses : dict
        Face name ("x_p", "x_a", … "z_a") → StaticSegment, the hold each face is calibrated from.
    rotations : dict
        Axis name ("x", "y", "z") → Rotation, the turn about it (absent: the gyro matrix stays
        identity, with a warning).
    holds : list of StaticSegment or None
        Every still period in time order, redundant holds included (they check the six-face
        model and bound the gyro bias); None when only the six faces are known (sections).
    """

    poses: dict[str, StaticSegment]
    rotations: dict[str, Rotation]
    holds: list[StaticSegment] | None = None

    def bias_holds(self) -> list[StaticSegment]:
        """The holds the gyro bias is fitted on: every hold, else the six faces."""
        return self.holds if self.holds is not None else [self.poses[p] for p in POSES]


def ferraris_regions(t, acc, gyr=None, *, segments=None, rotations=None, sections=None,
                     min_duration: float = 2.0) -> FerrarisRegions:
    """Find (or take) the six faces and the three turns of a Ferraris session.

    Parameters
    ----------
    t : (n,) array, s
    acc : (n, 3) array, sensor frame (any unit)
    gyr : (n, 3) array, rad/s, optional (no rotations without it)
    segments : list of StaticSegment or dict face -> StaticSegment, optional
        The still periods (default: :func:`find_static_segments` with ``min_duration`` [s]);
        a list is labelled by :func:`label_poses` (the longest hold per face).
    rotations : list of Rotation or dict axis -> Rotation, optional
        Default: :func:`find_rotations` between the holds.
    sections : dict, optional
        imucal-style section list (name -> start/end sample); overrides the other two.

    Returns
    -------
    FerrarisRegions
        From a list of rotations, the full turn closest to ±360° about each axis.
    """
    t, acc = np.asarray(t, dtype=float), np.asarray(acc, dtype=float)
    gyr = None if gyr is None else np.asarray(gyr, dtype=float)
    if sections is not None:
        return regions_from_sections(t, acc, gyr, sections)
    if isinstance(segments, dict):
        holds, poses = None, dict(segments)
    else:
        holds = (find_static_segments(t, acc, gyr, min_duration=min_duration)
                 if segments is None else list(segments))
        poses = label_poses(holds)
    if gyr is None:
        return FerrarisRegions(poses, {}, holds)
    if rotations is None:
        between = holds if holds is not None else sorted(poses.values(), key=lambda s: s.i0)
        rotations = find_rotations(t, gyr, between)
    return FerrarisRegions(poses, full_turns(rotations), holds)


def full_turns(rotations) -> dict[str, Rotation]:
    """Axis → the turn closest to ±360° about it, from a list of Rotation (a dict is taken as
    it is, keyed by its names' first letter)."""
    if isinstance(rotations, dict):
        return {k[0]: v for k, v in rotations.items()}
    best: dict[str, Rotation] = {}
    for r in rotations:
        if r.is_full_turn() and (r.axis_name not in best or
                                 abs(abs(r.angle_deg) - 360) < abs(abs(best[r.axis_name].angle_deg) - 360)):
            best[r.axis_name] = r
    return best


def regions_from_sections(t, acc, gyr, sections: dict) -> FerrarisRegions:
    """Hand-annotated sample ranges (imucal's section list) → the faces and rotations.

    ``sections`` maps "x_p" … "z_a", "x_rot", "y_rot", "z_rot" to ``{"start": i0, "end": i1}``
    or ``(i0, i1)`` (half-open, as imucal slices ``iloc[start:end]``).
    """
    poses, rots = {}, {}
    for name, rng in sections.items():
        i0, i1 = (rng["start"], rng["end"]) if isinstance(rng, dict) else rng
        if not 0 <= i0 < i1 <= t.size:
            raise ApmcalError(f"section {name} [{i0}, {i1}) outside the {t.size} samples")
        if name in POSES:
            poses[name] = make_segment(t, acc, gyr, i0, i1, max_tilt_deg=90.0)
        elif name.endswith("_rot") and name[0] in AXES and gyr is not None:
            ax = AXES.index(name[0])
            v = integrate_slice(t[i0:i1], gyr[i0:i1])
            rots[name[0]] = Rotation(axis=ax, angle_deg=float(np.degrees(v[ax])), integrated=v,
                                     start=float(t[i0]), end=float(t[i1 - 1]), i0=i0, i1=i1,
                                     n_steps=1, pose=None)
    return FerrarisRegions(poses, rots, None)
