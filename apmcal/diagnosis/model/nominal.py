"""A model — the nominal one plus chosen effects — fitted on one fold, and its hold residuals.

The nominal model is the one ArduPilot's own parameters can hold: accelerometer offset and
per-axis scale (INS_ACCOFFS/INS_ACCSCAL) against standard gravity, a constant gyro offset
(INS_GYROFFS), compass offset and symmetric soft-iron matrix (COMPASS_OFS/DIA/ODI), and white
Gaussian noise on every axis. Effects add terms (see :mod:`apmcal.diagnosis.model.effects`). The order
of the fit follows what each part needs: accelerometer geometry (orientation of each hold),
magnetometer geometry (heading), then the gyro, whose g-sensitivity and Earth rate are
regressions on those orientations; the noise terms come last, from the residuals.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.core.constants import EARTH_RATE, STANDARD_GRAVITY, normal_gravity
from apmcal.diagnosis.model.blocks import Blocks, make_blocks
from apmcal.diagnosis.model.dynamics import Dynamics
from apmcal.diagnosis.model.regressors import References, columns, triangle
from apmcal.diagnosis.model.static_fit import GeometryFit, GyroFit, count_orientations, fit_geometry, fit_gyro
from apmcal.diagnosis.scoring.gap import ResidualBlock

AXES = ("x", "y", "z")
DRIFT_TIMES_MIN = np.arange(0.5, 30.01, 0.25)   # SIM_DRIFT_TIME grid of the triangle drift
SAME_RSS = 1e-6         # relative residual difference below which two drift times fit alike


@dataclass
class Reduced:
    """Block means of the hold pieces of one session's samples (both folds)."""

    acc: Blocks
    gyr: Blocks
    mag: Blocks | None


def group_of_pieces(session) -> np.ndarray:
    """(hold, fold) group of each piece, 2·hold + fold (−1 for motion pieces).

    Returns
    -------
    (p,) int array
        By session-wide piece id.
    """
    groups = np.full(len(session.pieces), -1)
    for p in session.pieces.select(hold=True):
        groups[p] = 2 * session.hold_of_piece(p) + session.pieces.fold[p]
    return groups


def reduce_session(session) -> Reduced:
    """Blocks of the hold pieces for every sensor."""
    ids = session.pieces.select(hold=True)
    groups = group_of_pieces(session)
    pc = session.pieces
    total = 2 * len(session.holds)
    common = dict(piece_ids=ids, group_of_piece=groups, fs=session.fs, temp=session.temp,
                  current=session.current, groups_total=total)
    acc = make_blocks(session.t, session.acc, pc.i0[ids], pc.i1[ids], **common)
    gyr = make_blocks(session.t, session.gyr, pc.i0[ids], pc.i1[ids], **common)
    mag = None
    if session.mag is not None:
        m = session.mag
        mag = make_blocks(m.t, m.values, m.i0[ids], m.i1[ids], ids, groups,
                          float(1.0 / np.median(np.diff(m.t))), current=m.current,
                          groups_total=total)
    return Reduced(acc, gyr, mag)


@dataclass
class ModelFit:
    """One fitted model. ``up`` and ``north`` give each (hold, fold) group's orientation in the
    sensor frame (unit vectors; NaN rows for groups without samples).

    Attributes
    ----------
    effects : frozenset of str
        The effects on top of the nominal model.
    refs : References
        Where the slow terms are zero.
    gravity : float
        Gravity the accelerometer is fitted to [m/s²].
    acc : GeometryFit
    gyr : GyroFit
    gyr_columns : list of str
        Effect of each per-axis gyro column (row of ``gyr.theta``).
    gyr_vectors : list of str
        Name of each whole-vector gyro regressor (element of ``gyr.vector_coef``).
    up : (g, 3) array
        Each group's "up" in the sensor frame (unit vectors), g = 2 · number of holds.
    acc_dirs : (g, 3) array
        :meth:`GeometryFit.directions` of every group (acc).
    mag : GeometryFit or None
    mag_dirs : (g, 3) array or None
        The same for the compass.
    field_mgauss : float or None
        Field magnitude the compass is fitted to [mGauss].
    north : (g, 3) array or None
        Each group's true north in the sensor frame (unit vectors).
    declination_rad : float
        Magnetic declination [rad].
    dynamics : Dynamics
        The move parameters.
    hold_motion : tuple or None
        The measured motion inside the holds: rate (n, 3) [rad/s] and turn (n, 3, 3).
    acc_terms_in_moves : bool
        See :func:`acc_terms_in_moves`.
    """

    effects: frozenset
    refs: References
    gravity: float
    acc: GeometryFit
    gyr: GyroFit
    gyr_columns: list
    gyr_vectors: list
    up: np.ndarray
    acc_dirs: np.ndarray                  # GeometryFit.directions of every group (acc)
    mag: GeometryFit | None = None
    mag_dirs: np.ndarray | None = None
    field_mgauss: float | None = None
    north: np.ndarray | None = None
    declination_rad: float = 0.0
    dynamics: Dynamics = field(default_factory=Dynamics)
    # the measured motion inside the holds (rate (n, 3) [rad/s], turn (n, 3, 3)), part of the
    # model when motion_contamination is (apmcal.diagnosis.session.hold_motion)
    hold_motion: tuple | None = None
    acc_terms_in_moves: bool = False      # see acc_terms_in_moves()

    def acc_columns(self, t, temp) -> np.ndarray:
        """The accelerometer's slow regressor columns (n, k) at times ``t`` (n,) [s] and
        temperatures ``temp`` (n,) [°C] or None (:func:`~apmcal.diagnosis.model.regressors.columns`)."""
        return columns(self.effects, "acc", self.refs, t, temp)[0]

    def mag_columns(self, t, current) -> np.ndarray:
        """The compass's slow regressor columns (n, k) at times ``t`` (n,) [s] and battery
        currents ``current`` (n,) [A] or None (:func:`~apmcal.diagnosis.model.regressors.columns`)."""
        return columns(self.effects, "mag", self.refs, t, current=current)[0]

    @property
    def acc_column_names(self) -> list:
        """Effect of each accelerometer column (row of ``acc.theta``)."""
        has_temp = self.acc.theta.shape[0] > 0
        return ["temperature_drift"] if has_temp else []

    @property
    def mag_column_names(self) -> list:
        """Effect of each compass column (row of ``mag.theta``)."""
        return ["mag_interference"] if self.mag is not None and self.mag.theta.shape[0] else []


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def references(session) -> References:
    """Mean time, temperature and current of the session (where slow terms are zero)."""
    temp = float(np.nanmean(session.temp)) if session.temp is not None else 0.0
    cur = float(np.nanmean(session.current)) if session.current is not None else 0.0
    return References(float(np.mean(session.t)), temp, cur)


def gravity_of(session, effects) -> float:
    """Standard gravity, or WGS-84 normal gravity at the site when local_gravity is modelled.

    Returns
    -------
    float
        Gravity [m/s²].
    """
    if "local_gravity" in effects and session.lat_deg is not None:
        return normal_gravity(session.lat_deg)
    return STANDARD_GRAVITY


def fit_model(session, reduced: Reduced, effects, fold: int | None, *,
              field_mgauss: float | None = None, declination_rad: float = 0.0,
              start: ModelFit | None = None, with_sigma: bool = False) -> ModelFit:
    """Fit the nominal model plus ``effects`` on the hold pieces of ``fold``.

    ``field_mgauss`` is the Earth field magnitude (WMM) when known; otherwise the
    magnetometer's radius is its own (the soft-iron matrix then carries the unknown scale).
    ``fold`` None fits every piece; ``with_sigma`` adds the geometric fits' uncertainties.

    Parameters
    ----------
    session : Session
    reduced : Reduced
        Its block means (:func:`reduce_session`).
    effects : collection of str
    fold : int or None
        The fold fitted on.
    field_mgauss : float, optional
        Earth field magnitude [mGauss].
    declination_rad : float
        Magnetic declination [rad].
    start : ModelFit, optional
        A fit of the same model to start the geometric fits from.
    with_sigma : bool

    Returns
    -------
    ModelFit
        Without the move parameters (``dynamics`` neutral) and hold motion.
    """
    effects = frozenset(effects)
    train = session.pieces.select(fold=fold)
    refs = references(session)
    g = gravity_of(session, effects)
    in_moves = acc_terms_in_moves(effects, count_orientations(reduced.acc, "acc"),
                                  bool(np.any(~session.pieces.is_hold)))
    acc = _fit_acc(reduced, train, effects, refs, g, start, with_sigma, in_moves)
    acc_dirs = acc.directions(reduced.acc, _acc_cols(effects, refs, reduced.acc))
    fit = ModelFit(effects, refs, g, acc, None, [], [], _unit(acc_dirs), acc_dirs,
                   declination_rad=declination_rad, acc_terms_in_moves=in_moves)
    if reduced.mag is not None:
        _fit_mag(fit, reduced, train, field_mgauss, start, with_sigma)
    _fit_gyro_part(fit, reduced, train)
    return fit


def _acc_cols(effects, refs, blocks: Blocks) -> np.ndarray:
    return columns(effects, "acc", refs, blocks.t, blocks.temp)[0]


ACC_TERM_EFFECTS = ("cross_axis", "scale_nonlinearity")    # three parameters each


def acc_terms_in_moves(effects, orientations: int, has_moves: bool) -> bool:
    """Whether the accelerometer's non-orthogonality and quadratic scale are left to the moves.

    In still holds of unknown orientation each orientation adds one constraint beyond its own
    two angles (the length of the reading), so the holds determine the accelerometer's
    parameters — offset and scale (6), plus 3 per term — only with more orientations than
    that (two to spare). Six aligned faces trade the terms for offsets and scales; turns see
    them first order, so then, if there are turns, they are fitted there
    (:func:`apmcal.diagnosis.model.dynamics.fit_dynamics`).
    """
    terms = sum(e in effects for e in ACC_TERM_EFFECTS)
    return terms > 0 and has_moves and orientations < 6 + 3 * terms + 2


def _fit_acc(reduced, train, effects, refs, g, start, with_sigma, in_moves: bool
             ) -> GeometryFit:
    blocks = reduced.acc.select(train)
    return fit_geometry(blocks, _acc_cols(effects, refs, blocks), g, kind="acc",
                        cross_axis="cross_axis" in effects and not in_moves,
                        quadratic="scale_nonlinearity" in effects and not in_moves,
                        start=start.acc if start is not None else None, with_sigma=with_sigma)


def _fit_mag(fit: ModelFit, reduced, train, field_mgauss, start, with_sigma) -> None:
    blocks = reduced.mag.select(train)
    if len(blocks.t) == 0:
        return
    cols = lambda b: columns(fit.effects, "mag", fit.refs, b.t, current=b.current)[0]  # noqa
    radius = field_mgauss or (start.field_mgauss if start is not None else None) \
        or _own_radius(blocks)
    fit.mag = fit_geometry(blocks, cols(blocks), radius, kind="mag",
                           start=start.mag if start is not None else None, with_sigma=with_sigma)
    fit.field_mgauss = radius
    fit.mag_dirs = fit.mag.directions(reduced.mag, cols(reduced.mag))
    field_dir = _unit(fit.mag_dirs) if fit.mag.geometry else None
    fit.north = north_of(fit.up, field_dir, fit.declination_rad)


def _own_radius(blocks: Blocks) -> float:
    """The magnetometer's own field magnitude: radius of a sphere through its hold means."""
    from apmcal.core.errors import ApmcalError
    from apmcal.solvers.ellipsoid.fit import sphere_fit

    means = blocks.group_means(blocks.values)
    try:
        return float(sphere_fit(means)[1]) if len(means) >= 4 else 1.0
    except ApmcalError:
        return 1.0


def north_of(up: np.ndarray, field_dir: np.ndarray | None, declination_rad: float):
    """True north in the sensor frame per group: the field's horizontal part turned by the
    declination about the vertical (magnetic north lies ``declination`` east of true north),
    or None without a calibrated magnetometer.

    Parameters
    ----------
    up : (g, 3) array
        "Up" of each group (unit vectors, sensor frame).
    field_dir : (g, 3) array or None
        Field direction of each group (unit vectors).
    declination_rad : float
        Magnetic declination [rad].

    Returns
    -------
    (g, 3) array or None
        True north of each group (unit vectors, sensor frame).
    """
    if field_dir is None:
        return None
    h = _unit(field_dir - np.sum(field_dir * up, axis=1, keepdims=True) * up)
    # true north = magnetic north turned by the declination about "up" (Rodrigues, k = up)
    c, s = np.cos(declination_rad), np.sin(declination_rad)
    return h * c + np.cross(up, h) * s


def gyro_regressors(fit: ModelFit, t, temp, groups) -> tuple[np.ndarray, np.ndarray, list, list]:
    """Per-axis columns (n, k) and whole-vector regressors (n, v, 3) of the gyro at samples or
    blocks of the given (hold, fold) ``groups``, with their names.

    Parameters
    ----------
    fit : ModelFit
        Its effects, references, gravity and group orientations.
    t : (n,) array
        Times [s].
    temp : (n,) array or None
        Temperatures [°C].
    groups : (n,) int array
        (hold, fold) group of each sample or block.

    Returns
    -------
    columns : (n, k) array
        Temperature [K], time [s] and specific-force [m/s²] columns.
    vectors : (n, v, 3) array
        Earth-rate parts [rad/s] and the triangle drift shape [min].
    names : list of str
        Effect of each column.
    vector_names : list of str
        Name of each whole-vector regressor.
    """
    effects = fit.effects
    cols, names = columns(effects, "gyr", fit.refs, t, temp)
    col_list, vectors, vnames = [cols], [], []
    if "g_sensitivity" in effects:      # sitl: w += G·f_board, f = g·up of the hold
        col_list.append(fit.gravity * fit.up[groups])
        names = names + ["g_sensitivity"] * 3
    if "earth_rate" in effects:         # Ω (cos φ·north + sin φ·up), coefficients cos φ, sin φ
        vectors.append(EARTH_RATE * fit.up[groups])
        vnames.append("earth_rate_up")
        if fit.north is not None:
            vectors.append(EARTH_RATE * fit.north[groups])
            vnames.append("earth_rate_north")
    if "triangle_drift" in effects:     # one drift on all three axes, rad/s per minute
        shape = triangle(t, fit.refs.drift_time_min)
        vectors.append(np.outer(shape, np.ones(3)))
        vnames.append("triangle_drift")
    n = len(np.atleast_1d(t))
    vec = np.stack(vectors, axis=1) if vectors else np.zeros((n, 0, 3))
    return np.column_stack(col_list), vec, names, vnames


def _fit_gyro_part(fit: ModelFit, reduced: Reduced, train) -> None:
    blocks = reduced.gyr.select(train)
    groups = reduced.gyr.group[np.isin(reduced.gyr.piece, train)]
    if "triangle_drift" in fit.effects:
        fit.refs = _best_drift_time(fit, blocks, groups)
    cols, vec, names, vnames = gyro_regressors(fit, blocks.t, blocks.temp, groups)
    fit.gyr, fit.gyr_columns, fit.gyr_vectors = fit_gyro(blocks, cols, vec), names, vnames


def _best_drift_time(fit: ModelFit, blocks: Blocks, groups) -> References:
    """SIM_DRIFT_TIME by grid search: the triangle period that leaves the least residual, the
    longest of those that leave the same (within :data:`SAME_RSS`).

    A stretch of data shorter than a turn of the wave cannot tell a triangle from one of half
    the period and the opposite speed: between 150 and 450 s after boot, rising for 5 min then
    falling is falling for 2.5 min then rising, less a constant. The fewest turns inside the
    data is the simplest reading of it, and the two folds then agree (the parameters reported
    are their mean: +0.05 and −0.05 °/s per minute made a drift of nothing)."""
    from dataclasses import replace

    best, best_rss = fit.refs, np.inf
    # a half period beyond the record's end is a plain ramp there: one such value suffices
    last = float(np.max(blocks.t)) / 60.0
    grid = [m for m in DRIFT_TIMES_MIN if m <= last] + [float(DRIFT_TIMES_MIN[-1])]
    for minutes in reversed(grid):
        fit.refs = replace(fit.refs, drift_time_min=float(minutes))
        cols, vec, _, _ = gyro_regressors(fit, blocks.t, blocks.temp, groups)
        g = fit_gyro(blocks, cols, vec)
        rss = float((((blocks.values - g.predict(cols, vec)) ** 2).sum(axis=1)
                     * blocks.count).sum())
        if rss < best_rss * (1.0 - SAME_RSS):
            best, best_rss = fit.refs, rss
    return best


def set_acc_terms(fit: ModelFit, reduced: Reduced, train, terms: dict) -> None:
    """Give the accelerometer the terms the moves found (non-orthogonality "alpha", quadratic
    scale "k2"): its offset and scales are refitted on the holds with them held fixed, and the
    holds' orientations follow.

    Parameters
    ----------
    fit : ModelFit
        Changed in place (``acc``, ``acc_dirs``, ``up`` and ``north``).
    reduced : Reduced
    train : (k,) int array
        Session-wide ids of the training pieces.
    terms : dict
        "alpha" (3,) [rad] and/or "k2" (3,) [1/(m/s²)].
    """
    blocks = reduced.acc.select(train)
    fit.acc = fit_geometry(blocks, _acc_cols(fit.effects, fit.refs, blocks), fit.gravity,
                           kind="acc", fixed=terms, with_sigma=False)
    fit.acc_dirs = fit.acc.directions(reduced.acc, _acc_cols(fit.effects, fit.refs, reduced.acc))
    fit.up = _unit(fit.acc_dirs)
    if fit.mag is not None and fit.mag.geometry:
        fit.north = north_of(fit.up, _unit(fit.mag_dirs), fit.declination_rad)


def per_hold(per_group: np.ndarray, n_holds: int) -> np.ndarray:
    """(hold, fold) group rows → one row per hold (mean of the folds that have samples).

    Parameters
    ----------
    per_group : (g, c) array
        One row per group, g ≥ 2·n_holds.
    n_holds : int

    Returns
    -------
    (n_holds, c) array
        NaN rows for holds without samples in either fold.
    """
    rows = per_group[:2 * n_holds].reshape(n_holds, 2, -1)
    with np.errstate(invalid="ignore"):
        return np.nanmean(rows, axis=1)


def hold_vectors(fit: ModelFit, n_holds: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Each hold's calibrated specific force [m/s²] and field [mGauss] (or, without geometry,
    its mean raw reading), the vectors the moves carry along.

    Returns
    -------
    f : (n_holds, 3) array
        Specific force [m/s²].
    b : (n_holds, 3) array or None
        Field [mGauss]; None without a compass fit.
    """
    f = per_hold(fit.acc_dirs, n_holds) * (fit.gravity if fit.acc.geometry else 1.0)
    b = None
    if fit.mag is not None:
        b = per_hold(fit.mag_dirs, n_holds) * (fit.field_mgauss if fit.mag.geometry else 1.0)
    return f, b


def calibrated_rate(session, fit: ModelFit, rows=None) -> np.ndarray:
    """The gyro [rad/s] minus its fitted bias terms (offset, drift, temperature, triangle) at
    every sample, before the gyro matrix: what the moves integrate.

    Parameters
    ----------
    session : Session
    fit : ModelFit
    rows : (k,) int array, optional
        The samples to compute (what the moves read, :meth:`apmcal.diagnosis.model.dynamics.Moves.
        rows`); every sample by default.

    Returns
    -------
    (n, 3) array
        [rad/s] at every session sample (NaN outside ``rows`` when given: the moves are
        about an eighth of a session, and each sample's value is the same either way).
    """
    if rows is None:
        return session.gyr - _gyro_bias(fit, session.t, session.temp)
    out = np.full_like(session.gyr, np.nan)
    temp = session.temp[rows] if session.temp is not None else None
    out[rows] = session.gyr[rows] - _gyro_bias(fit, session.t[rows], temp)
    return out


def _gyro_bias(fit: ModelFit, t, temp) -> np.ndarray:
    """The gyro's fitted bias terms at times ``t`` [s] (temperatures ``temp`` [°C]) [rad/s]."""
    groups = np.zeros(len(t), int)
    cols, vec, names, vnames = gyro_regressors(fit, t, temp, groups)
    keep = [i for i, n in enumerate(names) if n != "g_sensitivity"]
    keep_v = [i for i, n in enumerate(vnames) if n == "triangle_drift"]
    bias = fit.gyr.offset + cols[:, keep] @ fit.gyr.theta[keep]
    if keep_v:
        bias = bias + np.einsum("nvc,v->nc", vec[:, keep_v], fit.gyr.vector_coef[keep_v])
    return bias


# ----------------------------------------------------------------------------- residuals
@dataclass
class HoldSamples:
    """The samples of the hold pieces, concatenated (the residual blocks' sample axis).

    Attributes
    ----------
    index : (h,) int array
        Index of each sample on the session's (or the compass's) sample axis.
    group : (h,) int array
        (hold, fold) group of each sample.
    i0, i1 : (p,) int arrays
        Half-open ranges of the pieces on the concatenated axis.
    piece : (p,) int array
        Session-wide piece ids.
    """

    index: np.ndarray       # into the session's sample axis
    group: np.ndarray       # (hold, fold) group of each sample
    i0: np.ndarray          # pieces on the concatenated axis
    i1: np.ndarray
    piece: np.ndarray       # session-wide piece ids


def hold_samples(i0, i1, piece_ids, groups_of_piece) -> HoldSamples:
    """The samples of the pieces ``[i0, i1)`` one after the other.

    Parameters
    ----------
    i0, i1 : (p,) int arrays
        Half-open sample ranges of the pieces.
    piece_ids : (p,) int array
        Session-wide id of each piece.
    groups_of_piece : (P,) int array
        (hold, fold) group of every session-wide piece id.

    Returns
    -------
    HoldSamples
    """
    lengths = np.maximum(np.asarray(i1) - np.asarray(i0), 0)
    index = np.concatenate([np.arange(a, b) for a, b in zip(i0, i1)]) if len(i0) else \
        np.zeros(0, int)
    ends = np.cumsum(lengths)
    return HoldSamples(index, np.repeat(np.asarray(groups_of_piece)[piece_ids], lengths),
                       ends - lengths, ends, np.asarray(piece_ids))


def hold_residuals(session, fit: ModelFit) -> list[ResidualBlock]:
    """Residual blocks (acc, gyr[, mag]) of every hold piece under ``fit``.

    Returns
    -------
    list of ResidualBlock
        Residuals [m/s², rad/s, mGauss] on the concatenated hold samples.
    """
    ids = session.pieces.select(hold=True)
    groups = group_of_pieces(session)
    pc = session.pieces
    hs = hold_samples(pc.i0[ids], pc.i1[ids], ids, groups)
    t = session.t[hs.index]
    temp = session.temp[hs.index] if session.temp is not None else None
    acc_pred = _hold_prediction(fit.acc, fit.acc_dirs, hs.group, fit, lambda: hs.index,
                                fit.acc_columns(t, temp))
    cols, vec, _, _ = gyro_regressors(fit, t, temp, hs.group)
    gyr_pred = fit.gyr.predict(cols, vec)
    if fit.hold_motion is not None:
        gyr_pred = gyr_pred + np.take(fit.hold_motion[0], hs.index, axis=0)
    # rows gathered with np.take: about 3× faster than fancy indexing of (n, 3) arrays
    acc = _block("acc", np.take(session.acc, hs.index, axis=0), acc_pred, hs, t, temp, session)
    _geometric(acc, fit.acc, fit.up[groups[ids]],
               sum(len(v) for v in fit.acc.params.values()), session)
    gyr = _block("gyr", np.take(session.gyr, hs.index, axis=0), gyr_pred, hs, t, temp, session)
    gyr.mean_dof = 1 + cols.shape[1] + int(np.ceil(vec.shape[1] / 3))
    blocks = [acc, gyr]
    if session.mag is not None and fit.mag is not None:
        blocks.append(_mag_block(session, fit, ids, groups))
    return blocks


def _hold_prediction(geo: GeometryFit, dirs: np.ndarray, group: np.ndarray, fit: ModelFit,
                     imu_index, columns: np.ndarray) -> np.ndarray:
    """A geometric sensor's predicted hold samples: one direction per (hold, fold) group, or
    per sample when the measured hold motion turns it (``imu_index()``: each sample's index on
    the IMU axis, computed only then)."""
    if fit.hold_motion is None:
        return geo.predict(dirs, columns, group)
    return geo.predict(_turned(dirs[group], fit, imu_index()), columns)


def _turned(vectors: np.ndarray, fit: ModelFit, index: np.ndarray) -> np.ndarray:
    """Hold vectors (rows) seen through the measured hold motion, R(θ)ᵀ·v, when modelled."""
    if fit.hold_motion is None:
        return vectors
    return np.einsum("nji,nj->ni", fit.hold_motion[1][index], vectors)


def _geometric(block: ResidualBlock, geo: GeometryFit, directions: np.ndarray, n_params: int,
               session) -> None:
    """Score a geometric sensor's piece means along the field; count what the fit took."""
    block.radial = directions
    if geo.geometry:
        block.mean_dof = n_params
    else:       # a free mean per (hold, fold): on every fold, one per hold
        block.mean_dof = block.mean_nuisance = len(session.holds)


def _block(sensor, readings, predicted, hs: HoldSamples, t, temp, session) -> ResidualBlock:
    """The residual block of ``sensor``'s hold ``readings`` under the model's ``predicted``
    values, keeping the readings of a sensor the log stores as integers."""
    kept = readings if sensor in session.integer_sensors and session.block_length == 1 else None
    return ResidualBlock([f"{sensor}_{a}" for a in AXES], readings - predicted, hs.i0, hs.i1,
                         hs.piece, t, temp, readings=kept)


def _mag_block(session, fit: ModelFit, ids, groups) -> ResidualBlock:
    m = session.mag
    hs = hold_samples(m.i0[ids], m.i1[ids], ids, groups)
    t = m.t[hs.index]
    cur = m.current[hs.index] if m.current is not None else None
    pred = _hold_prediction(fit.mag, fit.mag_dirs, hs.group, fit,
                            lambda: np.clip(np.searchsorted(session.t, t), 0, len(session.t) - 1),
                            fit.mag_columns(t, cur))
    readings = np.take(m.values, hs.index, axis=0)
    block = ResidualBlock([f"mag_{a}" for a in AXES], readings - pred, hs.i0, hs.i1, hs.piece, t,
                          None, readings=readings if "mag" in session.integer_sensors
                          and session.block_length == 1 else None)
    n_params = sum(len(v) for v in fit.mag.params.values())
    _geometric(block, fit.mag, _unit(fit.mag_dirs)[groups[ids]], n_params, session)
    return block
