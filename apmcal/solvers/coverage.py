"""How well samples seen from a centre cover the directions of the unit sphere: what decides
whether an ellipsoid's off-diagonal terms can be determined (:mod:`apmcal.solvers.ellipsoid.robust`)
and what the verdict says about a compass session (:mod:`apmcal.report.verdict`)."""
from __future__ import annotations

import numpy as np

# smallest eigenvalue of 3·mean(n nᵀ) below which the directions do not determine an
# ellipsoid's off-diagonal terms (the fit drops them; the report and the verdict say so)
MIN_SCATTER_FULL = 0.05


def direction_coverage(samples, offset, n_grid: int = 200, cone_deg: float = 20.0,
                       fraction: bool = True, fraction_samples: int | None = None) -> dict:
    """How well the sample directions (seen from ``offset``) cover the unit sphere.

    Returns ``scatter_eig`` — eigenvalues of ``3·mean(n nᵀ)`` (all 1 for uniform coverage, one
    near 0 when the samples lie in a plane through the offset) —, ``spread_eig`` — eigenvalues of
    the sample covariance scaled to mean 1 (0 for any planar set, whatever the offset) — and
    ``fraction`` — share of ``n_grid`` Fibonacci
    points on the sphere with a sample direction within ``cone_deg`` (NaN with
    ``fraction=False``: the one part that costs a pass over the samples per grid point; from
    every k-th sample, at most about ``fraction_samples``, when given).

    Parameters
    ----------
    samples : (n, 3) array
        Samples [sensor units].
    offset : (3,) array
        The centre the directions are seen from [sensor units].
    n_grid : int
        Number of Fibonacci points on the unit sphere.
    cone_deg : float
        Half-angle [deg] of the cone around a grid point that a sample direction must fall in.
    fraction : bool
        Compute ``fraction`` (False: NaN, no pass over the samples per grid point).
    fraction_samples : int, optional
        About how many samples (every k-th) ``fraction`` is computed from; all when None.

    Returns
    -------
    dict
        ``scatter_eig`` (3,), ``spread_eig`` (3,) (both ascending) and ``fraction`` (float, 0..1).
    """
    c = np.asarray(samples, dtype=float) - offset
    n = c / np.linalg.norm(c, axis=1, keepdims=True)
    eig = np.linalg.eigvalsh(3.0 * (n.T @ n) / len(n))
    # centre-free: shape of the sample cloud itself (a circle in a plane → 0 whatever the offset)
    C = np.cov(c.T) if len(c) > 1 else np.zeros((3, 3))
    spread = np.linalg.eigvalsh(3.0 * C / np.trace(C)) if np.trace(C) > 0 else np.zeros(3)
    step = max(1, len(n) // fraction_samples) if fraction_samples else 1
    share = (float(_grid_points_near(n[::step], n_grid, np.cos(np.radians(cone_deg))).mean())
             if fraction else float("nan"))
    return {"scatter_eig": eig, "spread_eig": spread, "fraction": share}


def fibonacci_sphere(n_grid: int) -> np.ndarray:
    """``n_grid`` points spread evenly over the unit sphere (a Fibonacci lattice), (n_grid, 3):
    the grid :func:`direction_coverage` counts covered points on."""
    k = np.arange(n_grid) + 0.5
    z = 1 - 2 * k / n_grid
    phi = np.pi * (1 + 5 ** 0.5) * k
    return np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])


def covered_points(samples, offset, n_grid: int = 200, cone_deg: float = 20.0) -> np.ndarray:
    """Which points of :func:`fibonacci_sphere` have a sample direction (seen from ``offset``)
    within ``cone_deg``: bool (n_grid,), whose mean is :func:`direction_coverage`'s
    ``fraction`` (for drawing the covered part of the sphere).

    Parameters
    ----------
    samples : (n, 3) array
        Samples [sensor units].
    offset : (3,) array
        The centre the directions are seen from [sensor units].
    n_grid : int
    cone_deg : float
        Half-angle [deg] of the cone around a grid point.
    """
    c = np.asarray(samples, dtype=float) - offset
    n = c / np.linalg.norm(c, axis=1, keepdims=True)
    return _grid_points_near(n, n_grid, np.cos(np.radians(cone_deg)))


def _grid_points_near(n: np.ndarray, n_grid: int, cos_cone: float,
                      chunk: int = 8192) -> np.ndarray:
    """Which of ``n_grid`` Fibonacci points have a unit direction of ``n`` (m, 3) within the
    cone (cos ≥ ``cos_cone``); bool (n_grid,).

    In chunks of samples, and only for the points not yet covered: the one-shot
    ``grid @ n.T`` is an n_grid × m array (400 MB for 250 000 samples), while a covered
    sphere is usually settled by the first chunk. The answer is the same.
    """
    grid = fibonacci_sphere(n_grid)
    # every k-th sample first (it spans the whole record, so it settles most points), then
    # the points still open against contiguous chunks of all samples
    near = (grid @ n[::max(1, len(n) // chunk)].T).max(axis=1) >= cos_cone
    for lo in range(0, len(n), 8 * chunk):
        todo = np.flatnonzero(~near)
        if not todo.size:
            break
        near[todo] = (grid[todo] @ n[lo:lo + 8 * chunk].T).max(axis=1) >= cos_cone
    return near
