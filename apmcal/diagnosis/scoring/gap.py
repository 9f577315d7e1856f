"""The gap: how much worse the real residuals fit the model than its simulated twin's do.

Definition (the number ``apmcal gap`` reports, in nats per sample)
------------------------------------------------------------------
Real and twin go through the same fit; their residuals (measured − predicted) are cut into the
same pieces and turned into Haar coefficients (:mod:`apmcal.diagnosis.scoring.haar`). Coefficients are
grouped into *cells*: one cell per channel (sensor axis) and scale level, and one per channel
for the piece means ("across pieces"; for the accelerometer and compass only their component
along the field, the rest being each hold's fitted orientation). Under a Gaussian model a cell's
coefficients have one variance, so the cost of describing the real coefficients with the twin's
variance instead of their own is the Kullback-Leibler divergence, per coefficient
½(x − 1 − ln x) with x = V_real / V_twin (the Itakura-Saito divergence; Whittle's likelihood in
wavelet form). The finest level of the still holds, where most coefficients lie, is scored by
its whole distribution instead: the KL divergence between the real and twin histograms (bins at
the twin's quantiles), which also sees a non-Gaussian shape (quantization, uniform noise). Each
cell's sum
has its expectation under "real and twin are the same process" removed (exact for the variance
cells, x being F-distributed with the degrees of freedom the fit leaves; first order for the
histograms), so a perfect model scores 0 on average::

    gap = Σ_cells (KL_cell − E[KL_cell | same process]) / (number of residual samples)

Every coefficient carries its share of its cell's sum, so the gap splits exactly by sensor, axis,
scale (frequency band), piece (hold or rotation), time and temperature.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.special import digamma, ndtr

from apmcal.diagnosis.compute import reuse
from apmcal.diagnosis.scoring.haar import Coefficients, details, piece_means
from apmcal.diagnosis.session.facts import MEANS

LEVEL_MEANS = 0          # cell code of the piece means ("across pieces")
MIN_CELL = 8             # coarse levels are pooled until a cell has this many coefficients
SHAPE_BINS = 32          # histogram bins, at the twin's quantiles
MIN_SHAPE = 400          # fewer level-1 coefficients: no shape cell
SHAPE_SMOOTHING = 0.02   # share of the twin's histogram that is its normal distribution
_TINY = 1e-300


@dataclass
class ResidualBlock:
    """Channels that share a sample axis and pieces (e.g. acc x/y/z during holds).

    Attributes
    ----------
    names : list of str
        Channel names, e.g. ["acc_x", "acc_y", "acc_z"].
    values : (n, c) array
        Residuals (measured − predicted) on the block's sample axis, sensor units.
    i0, i1 : (p,) int arrays
        Pieces, half-open sample ranges on that axis.
    piece : (p,) int array
        Session-wide piece id of each piece (for the breakdown by segment and fold).
    t : (n,) array
        Sample times [s].
    temp : (n,) array or None
        Temperature [°C] at each sample.
    shape : bool
        Whether the block is of still holds: its finest level is scored by its distribution
        and its piece means are scored (a move's mean residual, one number per move from a
        path that differs move to move, is not a sample of one variance).
    radial : (p, 3) array or None
        For a geometric sensor (accelerometer, compass) the fit turns each hold's orientation
        to its data, so only the piece means' component along the field ("radial") is left
        to score; given here per piece. None: every channel's piece means are scored.
    mean_dof : int
        Parameters fitted to the piece means of one scored channel (they lower the degrees of
        freedom, and so raise the null expectation, of the in-sample piece-mean cell).
    mean_nuisance : int
        Of those, the ones refitted on whichever fold is scored (a free mean per hold), which
        lower the degrees of freedom held-out as well.
    readings : (n, c) array or None
        The readings themselves, for a sensor the log stores as integers (the noise below
        their step shows in how often they change: :mod:`apmcal.diagnosis.noise.dither`);
        None otherwise.
    """

    names: list
    values: np.ndarray
    i0: np.ndarray
    i1: np.ndarray
    piece: np.ndarray
    t: np.ndarray
    temp: np.ndarray | None = None
    shape: bool = True
    radial: np.ndarray | None = None     # (p, 3) unit vectors: score the piece means along them
    mean_dof: int = 0                    # parameters fitted to the piece means of a channel
    mean_nuisance: int = 0               # ... of them refitted on every fold (orientations)
    readings: np.ndarray | None = None   # (n, c) the integer-format readings themselves

    def n_samples(self, keep: np.ndarray | None = None) -> int:
        """Residual samples in the kept pieces, counted once per channel.

        Parameters
        ----------
        keep : (k,) int array, optional
            Session-wide ids of the pieces to count (None: all).

        Returns
        -------
        int
        """
        sel = self._keep(keep)
        return int((self.i1[sel] - self.i0[sel]).sum()) * len(self.names)

    def _keep(self, keep) -> np.ndarray:
        return np.ones(len(self.i0), bool) if keep is None else np.isin(self.piece, keep)


@dataclass
class BlockCoefficients:
    """A block's Haar coefficients over all its pieces, computed once and masked per fold.

    Attributes
    ----------
    block : ResidualBlock
    levels : list of Coefficients
        Detail coefficients of levels 1, 2, ... (:func:`apmcal.diagnosis.scoring.haar.details`).
    means : Coefficients
        Piece-mean coefficients (:func:`apmcal.diagnosis.scoring.haar.piece_means`).
    """

    block: ResidualBlock
    levels: list            # Coefficients per level (1, 2, ...)
    means: Coefficients     # piece means

    def masks(self, keep) -> tuple[list, np.ndarray, np.ndarray]:
        """Boolean masks of the coefficients of the kept pieces (per level, means) and pieces.

        Parameters
        ----------
        keep : (k,) int array or None
            Session-wide ids of the pieces to keep (None: all).

        Returns
        -------
        levels : list of (k_j,) bool arrays
            One mask per level.
        means : (p,) bool array
            Mask of the piece-mean coefficients.
        pieces : (p,) bool array
            Mask of the block's pieces.
        """
        pieces = self.block._keep(keep)
        return [pieces[c.piece] for c in self.levels], pieces[self.means.piece], pieces


def coefficients(blocks: list[ResidualBlock]) -> list[BlockCoefficients]:
    """Haar coefficients of every block (all pieces).

    Parameters
    ----------
    blocks : list of ResidualBlock

    Returns
    -------
    list of BlockCoefficients
        One per block, in order.
    """
    return [BlockCoefficients(b, *reuse.coefficients(b, _coefficients_of)) for b in blocks]


def _coefficients_of(b: ResidualBlock) -> tuple:
    return details(b.values, b.i0, b.i1), piece_means(b.values, b.i0, b.i1)


@dataclass
class CellShare:
    """One cell's contribution to the gap, coefficient by coefficient.

    ``nats`` are the shares [nats] of the real coefficients, ``piece`` their session-wide piece
    ids and ``center`` their sample index on ``block``'s axis (for time and temperature).

    Attributes
    ----------
    channel : str
        Channel name, e.g. "gyr_x" ("<sensor>_norm" for the piece means along the field).
    level : int
        1, 2, ... (finest level of a pooled group); LEVEL_MEANS for the piece means.
    levels : tuple of int
        Every level pooled into the cell.
    n : int
        Number of real coefficients.
    v_real, v_twin : float
        Mean square of the real and the twin's coefficients [(sensor unit)²].
    nats : (n,) array
        Share of each real coefficient [nats].
    piece : (n,) int array
        Session-wide piece id of each coefficient.
    center : (n,) int array
        Sample index of each coefficient on ``block``'s axis.
    block : ResidualBlock
    kind : str
        "variance" (Gaussian, one variance) or "histogram".
    """

    channel: str
    level: int                # 1, 2, ... (finest level of a pooled group); LEVEL_MEANS
    levels: tuple             # every level pooled into the cell
    n: int
    v_real: float
    v_twin: float
    nats: np.ndarray
    piece: np.ndarray
    center: np.ndarray
    block: ResidualBlock
    kind: str = "variance"    # "variance" (Gaussian, one variance) or "histogram"

    def on(self, block: ResidualBlock) -> "CellShare":
        """This cell's numbers on ``block``, another block of the same values (its times and
        temperatures); the share arrays are shared. (dataclasses.replace would run __init__
        again: three times as long, for thousands of cells a diagnosis reuses.)"""
        cell = object.__new__(CellShare)
        cell.__dict__.update(self.__dict__)
        cell.block = block
        return cell

    @functools.cached_property
    def total(self) -> float:
        """The cell's gap [nats]: the sum of its shares (summed once: the shares are never
        written to, and a diagnosis reads the totals of its cells again and again)."""
        return float(self.nats.sum())

    @property
    def time(self) -> np.ndarray:
        """Time of each coefficient (n,) [s]."""
        return self.block.t[np.clip(self.center, 0, len(self.block.t) - 1)]

    @property
    def temp(self) -> np.ndarray:
        """Temperature at each coefficient (n,) [°C]; NaN without one."""
        if self.block.temp is None:
            return np.full(len(self.nats), np.nan)
        return self.block.temp[np.clip(self.center, 0, len(self.block.t) - 1)]


@dataclass
class GapEstimate:
    """The gap of one comparison, cell by cell.

    Attributes
    ----------
    cells : list of CellShare
    n_samples : int
        Residual samples compared (once per channel).
    """

    cells: list
    n_samples: int

    @property
    def nats(self) -> float:
        """Total excess negative log-likelihood [nats]."""
        return float(sum(c.total for c in self.cells))

    @property
    def value(self) -> float:
        """The gap [nats per sample]."""
        return self.nats / self.n_samples if self.n_samples else 0.0


def expected_variance_kl(n: int, dof_real: float, dof_twin: float) -> float:
    """E[½ n (x − 1 − ln x)] for a cell of ``n`` coefficients when x = V_real / V_twin is
    F(ν_r, ν_t) distributed (same process; ν the degrees of freedom, n minus what the fit took).

    E[x] = ν_t / (ν_t − 2); E[ln x] = ψ(ν_r/2) − ln(ν_r/2) − ψ(ν_t/2) + ln(ν_t/2).

    Parameters
    ----------
    n : int
        Coefficients in the cell.
    dof_real, dof_twin : float
        Degrees of freedom ν_r, ν_t (ν_t > 2).

    Returns
    -------
    float
        Expected KL sum of the cell [nats].
    """
    e_x = dof_twin / (dof_twin - 2.0)
    e_log = (digamma(dof_real / 2) - np.log(dof_real / 2)) \
        - (digamma(dof_twin / 2) - np.log(dof_twin / 2))
    return 0.5 * n * (e_x - 1.0 - e_log)


def level_groups(counts: list[int], min_cell: int = MIN_CELL) -> list[list[int]]:
    """Levels (1-based) grouped into cells: coarse levels pooled until a cell has ``min_cell``
    coefficients; a coarse remainder below 3 coefficients is dropped (no variance to compare).

    Parameters
    ----------
    counts : list of int
        Coefficients at each level, element ``j - 1`` for level ``j``.
    min_cell : int
        Coefficients a cell needs.

    Returns
    -------
    list of list of int
        The levels of each cell, fine to coarse.
    """
    groups, current, n = [], [], 0
    for level in range(len(counts), 0, -1):
        current.append(level)
        n += counts[level - 1]
        if n >= min_cell:
            groups.append(sorted(current))
            current, n = [], 0
    if current and n >= 3:
        groups.append(sorted(current))
    return groups[::-1]


def variance_shares(real: np.ndarray, twin: np.ndarray, dof_loss: float = 0.0,
                    floor: float = 0.0) -> tuple[np.ndarray, float, float]:
    """Per-coefficient shares of ½Σ(x − 1 − ln x) − E[...] for one cell; V_real, V_twin.

    Parameters
    ----------
    real, twin : (n,) arrays
        The cell's real and twin coefficients (any unit, the same for both).
    dof_loss : float
        Degrees of freedom the fit took from the cell.
    floor : float
        Smallest variance the readings can resolve (their rounding, step²/12), in the
        coefficients' unit squared: both variances are raised to it.

    Returns
    -------
    shares : (n,) array
        Share of each real coefficient [nats].
    v_real, v_twin : float
        Mean squares, in the coefficients' unit squared (each at least ``floor``).
    """
    (out,) = variance_shares_by_row(real[None], twin[None], dof_loss, np.array([floor]))
    return out


def variance_shares_by_row(real: np.ndarray, twin: np.ndarray, dof_loss: float = 0.0,
                           floors: np.ndarray | None = None
                           ) -> list[tuple[np.ndarray, float, float]]:
    """:func:`variance_shares` of each row of (c, n) arrays (one cell per channel, all of n
    coefficients), the arithmetic shared by the rows done once.

    ``floors`` (c,): each row's smallest resolvable variance. Both variances are raised to it,
    x = V_real' / V_twin' (a cell where neither reaches it carries no information: shares 0);
    the shares still add up to ½n(x − 1 − ln x) minus the expectation.

    Returns
    -------
    list of (shares (n,) [nats], v_real, v_twin)
        One per row.
    """
    n = real.shape[1]
    sq = real ** 2
    v_real = np.mean(sq, axis=1)        # each row as np.mean of the row alone would
    v_twin = np.mean(twin ** 2, axis=1)
    floors = np.zeros(len(sq)) if floors is None else np.asarray(floors, float)
    dof = n - dof_loss
    expected = _expected_variance_kl(n, dof) if dof > 2 else 0.0
    out = []
    for row, v_r, v_t, floor in zip(sq, v_real, v_twin, floors):
        lowest = max(float(floor), _TINY)
        if v_r <= floor and v_t <= floor and floor > 0:
            out.append((np.zeros(n), lowest, lowest))
            continue
        raw = max(float(v_r), 0.0)
        v_r, v_t = max(float(v_r), lowest), max(float(v_t), lowest)
        share = 0.5 * (row * (1.0 / v_t - 1.0 / v_r) + np.log(v_t / v_r))
        # a floored real variance: what makes the shares add up to the floored cell's KL
        lift = 0.5 * (v_r - raw) * (1.0 / v_t - 1.0 / v_r)
        out.append((share + lift - expected / n, v_r, v_t))
    return out


@functools.lru_cache(maxsize=4096)
def _expected_variance_kl(n: int, dof: float) -> float:
    """:func:`expected_variance_kl` with equal degrees of freedom (cells recur fold after fold)."""
    return expected_variance_kl(n, dof, dof)


def shape_shares(real: np.ndarray, twin: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Per-coefficient shares of the histogram KL of the real coefficients against the twin's,
    minus its first-order expectation (B − 1)/2·(1 + n_r/n_t) under "same distribution".

    The bins are the twin's own quantiles (equally filled by the twin), so that no bin is so
    thin that a handful of coefficients moving across an edge swings the sum — fixed bins
    have near-empty tails where one coefficient is worth nats; a rounding lattice in the
    twin gives tied quantiles, which merge into fewer bins.

    The twin's histogram is smoothed: a share :data:`SHAPE_SMOOTHING` of it is the normal
    distribution of the twin's variance (at least ``floor``, the readings' rounding), so
    that a real coefficient where the twin has none (a lattice value the twin never reached,
    a twin whose reading never changes) costs a bounded amount, not the log of a count. To
    first order this leaves the null expectation as it is (the mixture moves q by
    λ(g − q), whose expectation over p = q is zero).

    Parameters
    ----------
    real : (n_r,) array
        The cell's real coefficients.
    twin : (n_t,) array
        The twin's, in the same unit.
    floor : float
        Smallest variance the readings resolve [unit²].

    Returns
    -------
    (n_r,) array
        Share of each real coefficient [nats].
    """
    twin_sorted = np.sort(twin)     # the quantiles and the twin's bin counts both read it
    edges = resolved_edges(sorted_quantiles(twin_sorted, np.arange(1, SHAPE_BINS) / SHAPE_BINS),
                           floor)
    bins = len(edges) + 1
    b_r = bin_index(edges, real)
    # twin values at or below each edge, hence per bin (the bins of searchsorted(edges, twin))
    t_counts = np.diff(np.searchsorted(twin_sorted, edges, side="right"), prepend=0,
                       append=len(twin))
    n_r, n_t = len(real), len(twin)
    p = (np.bincount(b_r, minlength=bins) + 0.5) / (n_r + 0.5 * bins)
    q = (t_counts + 0.5) / (n_t + 0.5 * bins)
    sd = np.sqrt(max(float(np.mean(twin ** 2)) if n_t else 0.0, floor, _TINY))
    g = np.diff(ndtr(np.concatenate([[-np.inf], edges / sd, [np.inf]])))
    q = (1.0 - SHAPE_SMOOTHING) * q + SHAPE_SMOOTHING * g
    expected = 0.5 * (bins - 1) * (1.0 + n_r / n_t)
    return np.log(p / q)[b_r] - expected / n_r


def resolved_edges(edges: np.ndarray, floor: float) -> np.ndarray:
    """Histogram edges no finer than the readings resolve: each moved to the middle between
    two points of the grid of half the finest coefficients' rounding step, then deduplicated.

    A reading rounded to a step Δ (``floor`` = Δ²/12) makes level-1 Haar coefficients
    (y₁ − y₀)/√2 on a grid of Δ/√2, and of Δ/(2√2) where the reader moved truncated readings
    half a step out; what the fitted model adds between two samples (a slope, a temperature
    term) shifts them by far less. Quantile edges of such a twin fall inside those clusters, at
    the model's sub-step offsets, and a histogram binned there compares how the real and twin
    residuals straddle zero by a millionth of a step — thousands of nats on an int16 gyro that
    no reading can show (an ArduPilot RAW_IMU log: 5e4 nats against a triangle drift that
    describes it). Edges between the grid points never split a cluster. On float readings
    (Δ a float32's spacing) the grid is far below any quantile spacing and nothing moves.

    Parameters
    ----------
    edges : (k,) array
        Sorted candidate edges (the twin's quantiles), in the coefficients' unit.
    floor : float
        The readings' rounding variance Δ²/12 [unit²] (0: no rounding).

    Returns
    -------
    (j,) array
        Sorted unique edges, j ≤ k.
    """
    grid = np.sqrt(12.0 * floor) / (2.0 * np.sqrt(2.0)) if floor > 0 else 0.0
    if not grid > 0:
        return np.unique(edges)
    point, ties = np.unique(np.floor(edges / grid + 0.5), return_counts=True)
    # a grid point that several quantiles fall on holds a cluster of the twin's mass: bounded
    # on both sides, so that coefficients just below it are not binned with it either
    return np.unique(np.concatenate([point + 0.5, point[ties > 1] - 0.5]) * grid)


def sorted_quantiles(x_sorted: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``np.quantile(x, q)`` (its default linear interpolation) of an already sorted ``x``,
    value for value: numpy's own steps — index (n − 1)·q, its floor and the next, the lerp
    from the nearer end — without numpy partitioning the sorted array again (as slow as the
    sort itself).

    Parameters
    ----------
    x_sorted : (n,) array
        Values in ascending order.
    q : (k,) array
        Probabilities in [0, 1].

    Returns
    -------
    (k,) array
        Quantiles, in the unit of ``x_sorted``.
    """
    n = len(x_sorted)
    if n == 0 or np.isnan(x_sorted[-1]):        # numpy: an error, or NaN for every q
        return np.quantile(x_sorted, q)
    virtual = (n - 1) * np.asarray(q, dtype=float)
    below = np.floor(virtual)
    gamma = virtual - below
    i = below.astype(np.intp)
    lo, hi = x_sorted[i], x_sorted[np.minimum(i + 1, n - 1)]
    diff = hi - lo
    return np.where(gamma >= 0.5, hi - diff * (1 - gamma), lo + diff * gamma)


def bin_index(edges: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``np.searchsorted(edges, x)`` for a few sorted edges (at most 255), bin for bin (NaN in
    the last bin, where numpy sorts it): the count of edges below each value, one comparison
    pass per edge — hand-written because numpy's binary search per value is 3-4× slower on
    tens of thousands of values and 31 edges.

    Parameters
    ----------
    edges : (e,) array
        Sorted bin edges, e ≤ 255.
    x : (n,) array
        Values.

    Returns
    -------
    (n,) uint8 array
        Bin of each value, 0 .. e.
    """
    x = np.ascontiguousarray(x)     # a column of a (k, 3) array: strided passes are 2× slower
    b = np.full(len(x), len(edges), np.uint8)
    for e in edges:
        b -= x <= e
    return b


def _dof_loss(block: ResidualBlock, in_sample: bool) -> int:
    return block.mean_dof if in_sample else block.mean_nuisance


def _floors_of(names, floors: dict | None) -> np.ndarray:
    """Variance floor of each channel [unit²] (0 where none is known)."""
    return np.array([(floors or {}).get(name, 0.0) for name in names], float)


def _block_cells(rc: BlockCoefficients, tc: BlockCoefficients, keep, in_sample, floors=None):
    """The cells of every channel of one block over the kept pieces, channel by channel.

    What the channels share (which coefficients are kept, their pieces and centres, how the
    levels pool into cells) is worked out once per block, not once per channel."""
    level_masks, mean_mask, _ = rc.masks(keep)
    block = rc.block
    kept = [np.flatnonzero(m) for m in level_masks]
    # per level (c, k): the kept coefficients channel by channel, each channel contiguous
    real_lv = [np.take(c.values.T, i, axis=1) for c, i in zip(rc.levels, kept)]
    twin_lv = [np.take(c.values.T, i, axis=1) for c, i in zip(tc.levels, kept)]
    piece_lv = [block.piece[c.piece[i]] for c, i in zip(rc.levels, kept)]
    center_lv = [c.center[i] for c, i in zip(rc.levels, kept)]
    histogram = bool(block.shape and real_lv and len(kept[0]) >= MIN_SHAPE)
    groups = []
    for group in level_groups([len(i) for i in kept]):
        if histogram and 1 in group:    # level 1 is scored by its histogram
            group = [j for j in group if j != 1]
        if group:
            groups.append((group, np.concatenate([piece_lv[j - 1] for j in group]),
                           np.concatenate([center_lv[j - 1] for j in group])))
    loss = _dof_loss(block, in_sample)
    score_means = block.shape and block.radial is None and mean_mask.sum() - loss > 2
    # every channel's variance cells at once, per group of levels
    floor = _floors_of(block.names, floors)
    means_floor = _floors_of([name + MEANS for name in block.names], floors)
    group_shares = [variance_shares_by_row(
        np.concatenate([real_lv[j - 1] for j in group], axis=1),
        np.concatenate([twin_lv[j - 1] for j in group], axis=1), floors=floor)
        for group, _, _ in groups]
    for col, name in enumerate(block.names):
        if histogram:      # level 1 scored by its whole distribution: width and shape
            real, twin = real_lv[0][col], twin_lv[0][col]
            yield CellShare(name, 1, (1,), len(real), max(float(np.mean(real ** 2)), floor[col]),
                            max(float(np.mean(twin ** 2)), floor[col]),
                            shape_shares(real, twin, floor[col]),
                            piece_lv[0], center_lv[0], block, kind="histogram")
        for (group, piece, center), shares in zip(groups, group_shares):
            share, v_r, v_t = shares[col]
            yield CellShare(name, group[0], tuple(group), len(share), v_r, v_t, share, piece,
                            center, block)
        if score_means:
            real = rc.means.values[mean_mask, col]
            share, v_r, v_t = variance_shares(real, tc.means.values[mean_mask, col], loss,
                                              means_floor[col])
            yield CellShare(name, LEVEL_MEANS, (LEVEL_MEANS,), len(real), v_r, v_t, share,
                            block.piece[rc.means.piece[mean_mask]], rc.means.center[mean_mask],
                            block)


def _radial_cell(rc: BlockCoefficients, tc: BlockCoefficients, keep, in_sample, floors=None):
    """The piece means of a geometric sensor along the field, as one channel "<sensor>_norm"."""
    block = rc.block
    _, mask, _ = rc.masks(keep)
    loss = _dof_loss(block, in_sample)
    if mask.sum() - loss <= 2:
        return
    along = block.radial[rc.means.piece[mask]]
    real = np.sum(rc.means.values[mask] * along, axis=1)
    twin = np.sum(tc.means.values[mask] * along, axis=1)
    name = block.names[0].split("_")[0] + "_norm"
    share, v_r, v_t = variance_shares(real, twin, loss, (floors or {}).get(name + MEANS, 0.0))
    yield CellShare(name, LEVEL_MEANS, (LEVEL_MEANS,), len(real), v_r, v_t, share,
                    block.piece[rc.means.piece[mask]], rc.means.center[mask], block)


def compare(real: list[BlockCoefficients], twin: list[BlockCoefficients],
            keep: np.ndarray | None = None, in_sample: bool = True,
            floors: dict | None = None) -> GapEstimate:
    """The gap between real and twin residual coefficients over the pieces ``keep`` (all if None).

    ``real`` and ``twin`` come from blocks with the same channels and pieces (the twin is
    simulated on the real session's own sample times). ``in_sample``: the pieces are the ones
    the models were fitted on (their fitted parameters then count against the piece means).

    Parameters
    ----------
    real, twin : list of BlockCoefficients
        The real and twin residual coefficients, block for block.
    keep : (k,) int array, optional
        Session-wide ids of the pieces compared.
    in_sample : bool
        Whether ``keep`` are the fitting pieces.
    floors : dict, optional
        Smallest resolvable variance of each channel's coefficients [unit²]
        (:func:`apmcal.diagnosis.session.facts.variance_floors`); none when not given.

    Returns
    -------
    GapEstimate
    """
    cells, n_samples = [], 0
    for rc, tc in zip(real, twin):
        n_samples += rc.block.n_samples(keep)
        cells.extend(reuse.cells(rc, tc, keep, in_sample,
                                 lambda rc=rc, tc=tc: _cells_of(rc, tc, keep, in_sample, floors),
                                 floors))
    return GapEstimate(cells, n_samples)


def _cells_of(rc: BlockCoefficients, tc: BlockCoefficients, keep, in_sample: bool,
              floors: dict | None = None) -> list:
    cells = list(_block_cells(rc, tc, keep, in_sample, floors))
    if rc.block.radial is not None:
        cells.extend(_radial_cell(rc, tc, keep, in_sample, floors))
    return cells
