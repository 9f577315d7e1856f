"""The compass turn, live: which directions the compass has seen so far, and whether they are
enough for the fit.

The directions are seen from the centre of the samples (a least-squares sphere through them,
:func:`apmcal.solvers.ellipsoid.fit.sphere_fit`; before it can be fitted, from zero, the centre
of the field the firmware corrects to). Enough means what the compass's verdict asks of a good
session (:mod:`apmcal.report.verdict`): at least :data:`~apmcal.report.verdict.MIN_MAG_FRACTION`
of the sphere within 20° of a sample, no direction left flat (the smallest scatter eigenvalue
at least :data:`~apmcal.solvers.coverage.MIN_SCATTER_FULL`), and the fit's own refusals
passed (:func:`apmcal.solvers.magnetometer.check_coverage`, ``check_distinct_directions``).
"""
from __future__ import annotations

import numpy as np

from apmcal.core.errors import ApmcalError

N_GRID = 200            # the sphere's points, as the verdict's coverage counts them
CONE_DEG = 20.0
MAX_SAMPLES = 6000      # judged from at most this many (every k-th): a few ms a look


class CompassTurn:
    """The compass samples [mGauss] of one turn, and their coverage of the sphere."""

    def __init__(self):
        self.samples: list[np.ndarray] = []

    def add(self, mag_mgauss) -> None:
        """One compass sample (3,) [mGauss]; all-zero samples (no compass) are left out."""
        m = np.asarray(mag_mgauss, dtype=float)
        if np.all(np.isfinite(m)) and np.any(m != 0):
            self.samples.append(m)

    def coverage(self) -> dict:
        """How far the turn is (JSON-ready).

        Returns
        -------
        dict
            ``samples`` (count), ``fraction`` (of the sphere within 20° of a sample),
            ``min_eig`` (smallest scatter eigenvalue, 0 flat .. 1 even), ``covered`` (a string
            of "0"/"1", one per point of :func:`apmcal.solvers.coverage.fibonacci_sphere`),
            ``done`` (enough for the fit), ``missing`` (why not yet, in words), and the
            thresholds ``need_fraction`` and ``need_eig``.
        """
        from apmcal.report.verdict import MIN_MAG_FRACTION
        from apmcal.solvers.coverage import MIN_SCATTER_FULL, covered_points, direction_coverage

        out = {"samples": len(self.samples), "fraction": 0.0, "min_eig": 0.0,
               "covered": "0" * N_GRID, "done": False, "need_fraction": MIN_MAG_FRACTION,
               "need_eig": MIN_SCATTER_FULL, "missing": "turn the vehicle"}
        if len(self.samples) < 10:
            return out
        s = np.array(self.samples[::max(1, len(self.samples) // MAX_SAMPLES)])
        centre = self.centre(s)
        cov = direction_coverage(s, centre, n_grid=N_GRID, cone_deg=CONE_DEG)
        covered = covered_points(s, centre, N_GRID, CONE_DEG)
        out.update(fraction=float(cov["fraction"]), min_eig=float(np.min(cov["scatter_eig"])),
                   covered="".join("1" if c else "0" for c in covered))
        if out["fraction"] < MIN_MAG_FRACTION:
            out["missing"] = (f"{100 * out['fraction']:.0f} % of the directions seen, "
                              f"{100 * MIN_MAG_FRACTION:.0f} % needed: keep turning, toward "
                              "the grey parts")
        elif out["min_eig"] < MIN_SCATTER_FULL:
            out["missing"] = "the directions lie nearly in one plane: tip it over too"
        else:
            out["missing"] = self.refusal(s)
        out["done"] = out["missing"] == ""
        return out

    @staticmethod
    def centre(s: np.ndarray) -> np.ndarray:
        """The samples' sphere centre [mGauss], zero while no sphere fits them."""
        from apmcal.solvers.ellipsoid.fit import sphere_fit

        try:
            centre, radius = sphere_fit(s)
        except ApmcalError:
            return np.zeros(3)
        typical = float(np.median(np.linalg.norm(s, axis=1)))
        # an arc fits any sphere: a centre far beyond the samples' own size is not one yet
        return centre if np.isfinite(radius) and radius < 3 * typical else np.zeros(3)

    @staticmethod
    def refusal(s: np.ndarray) -> str:
        """What the compass fit would still refuse these samples for ("" when nothing)."""
        from apmcal.solvers.magnetometer import check_coverage, check_distinct_directions

        try:
            check_coverage(s)
            check_distinct_directions(s)
        except ApmcalError as err:
            return err.why
        return ""
