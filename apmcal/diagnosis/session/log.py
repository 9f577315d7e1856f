"""A recording cut into what the diagnosis fits and scores: holds, motions, pieces and folds.

The samples come out of :func:`apmcal.preprocessing.prepare.prepare` (firmware correction and board rotation
undone: raw sensor frame, SI units). Still periods are the calibration's own static holds
(:func:`apmcal.preprocessing.static.find_static_segments`); a *motion* is the short move between
two consecutive holds. Each hold is cut into an even number of equal *pieces* of at most
``max_piece_s`` that alternate between fold 0 and fold 1, so that both folds see every
orientation and every stretch of time: a model fitted on one fold is scored on the other
(held-out). Motions are single pieces alternating between the folds.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field

import numpy as np

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.stillness import GAP_FACTOR

MAX_PIECE_S = 30.0      # longest piece [s]: longer holds are cut into several
MIN_PIECE_S = 2.0       # shortest piece [s] worth scoring
MAX_MOTION_S = 15.0     # a longer stretch between holds is not a move but handling or a flight
MAX_LINEAR_G = 0.1      # a move whose specific force departs from the holds' magnitude by more
                        # than this (RMS, in units of it) is carried, not turned: sitl's moves
                        # are pure rotations about the IMU, so it is left out
MIN_MOTION_SAMPLES = 8
INTEGER_MAG = re.compile(r"^MAG\d?$")     # dataflash MAG: MagX..Z int16 mGauss (format 'h')


@dataclass(frozen=True)
class Segment:
    """A hold or a motion, in time order.

    ``i0, i1`` is the half-open sample range; for a motion ``before``/``after`` are the indices of
    the holds around it (into ``Session.holds``).

    Attributes
    ----------
    kind : str
        "hold" or "motion".
    index : int
        Index among the holds, or among the motions.
    i0, i1 : int
        Half-open sample range.
    label : str
        E.g. "hold 3" (with its pose, when known), "move 2 (hold 2 → 3)".
    before, after : int or None
        For a motion, the holds around it.
    """

    kind: str
    index: int
    i0: int
    i1: int
    label: str
    before: int | None = None
    after: int | None = None


@dataclass
class Pieces:
    """Contiguous sample ranges that are scored, with their segment and fold (arrays of length p).

    Attributes
    ----------
    i0, i1 : (p,) int arrays
        Half-open sample ranges.
    segment : (p,) int array
        Index into ``Session.segments``.
    fold : (p,) int array
        0 or 1.
    is_hold : (p,) bool array
        Whether the piece is part of a hold (else a motion).
    """

    i0: np.ndarray
    i1: np.ndarray
    segment: np.ndarray     # index into Session.segments
    fold: np.ndarray        # 0 or 1
    is_hold: np.ndarray     # bool

    def select(self, fold: int | None = None, hold: bool | None = None) -> np.ndarray:
        """Ids of the pieces in ``fold`` (both when None) of holds / motions / both.

        Parameters
        ----------
        fold : int, optional
            0 or 1 (None: both).
        hold : bool, optional
            True: hold pieces, False: motion pieces, None: both.

        Returns
        -------
        (k,) int array
            Piece ids, ascending.
        """
        ok = np.ones(len(self.i0), bool)
        if fold is not None:
            ok &= self.fold == fold
        if hold is not None:
            ok &= self.is_hold == hold
        return np.flatnonzero(ok)

    def __len__(self) -> int:
        return len(self.i0)


@dataclass
class MagAxis:
    """Magnetometer samples on their own time axis and the pieces mapped onto it.

    Attributes
    ----------
    t : (m,) array
        Sample times [s].
    values : (m, 3) array
        Field [mGauss], raw sensor frame.
    i0, i1 : (p,) int arrays
        Each piece's half-open sample range on this axis (i0 == i1: no sample in it).
    current : (m,) array or None
        Battery current [A] at the compass sample times.
    """

    t: np.ndarray           # [s]
    values: np.ndarray      # (m, 3) [mGauss], raw sensor frame
    i0: np.ndarray          # per piece, on this axis (i0 == i1: no sample in the piece)
    i1: np.ndarray
    current: np.ndarray | None = None    # [A] at the mag sample times


@dataclass
class Session:
    """Everything the diagnosis needs from one recording (sensor frame, SI units).

    Attributes
    ----------
    source : str
        The log file.
    t : (n,) array
        IMU sample times [s].
    acc : (n, 3) array
        Accelerometer [m/s²].
    gyr : (n, 3) array
        Gyroscope [rad/s].
    holds : list of StaticSegment
        The still periods.
    segments : list of Segment
        Holds and motions, in time order.
    pieces : Pieces
    temp : (n,) array or None
        IMU temperature [°C].
    current : (n,) array or None
        Battery current [A].
    mag : MagAxis or None
    lat_deg, lon_deg : float or None
        Site [deg].
    date : datetime.date or None
        Date of the recording (WMM epoch).
    notes : list of str
    integer_sensors : frozenset of str
        Sensors whose log format stores integers.
    resolution : dict
        The step [m/s², rad/s, mGauss] of each sensor the log format stores as integers (in
        block means: that step over the block length).
    truncated : bool
        Whether those integers are the format's truncation toward zero, undone by half a step
        (RAW_IMU, SCALED_IMU*: :func:`apmcal.preprocessing.resolution.undo_truncation`); the
        twin then truncates and undoes the same way.
    block_length : int
        Samples of the recording averaged into each of this session's (1: the recording's own
        samples; more in block means, :func:`apmcal.diagnosis.session.decimate.decimated`).
    lattice : dict
        For a sensor the log stores as integers: (origin, step), each (3,) [unit], the raw
        value of a count of 0 and the raw size of one count per axis — the firmware rounds
        its *corrected* output, so with offsets and scales in force the raw readings sit on a
        lattice shifted by the offsets (a gyro offset of −2.98 mrad/s puts the count 0 at
        −2.98). Absent: origin 0, step ``resolution``.
    """

    source: str
    t: np.ndarray                       # [s]
    acc: np.ndarray                     # (n, 3) [m/s²]
    gyr: np.ndarray                     # (n, 3) [rad/s]
    holds: list                         # StaticSegment
    segments: list                      # Segment, time order
    pieces: Pieces
    temp: np.ndarray | None = None      # (n,) [°C]
    current: np.ndarray | None = None   # (n,) [A]
    mag: MagAxis | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    date: object = None                 # datetime.date of the recording (WMM epoch)
    notes: list = field(default_factory=list)
    # sensors whose log format stores integers (RAW_IMU's mG / mrad/s / mGauss, dataflash
    # MAG's int16 mGauss): their rounding is the recording's, part of every twin
    integer_sensors: frozenset = frozenset()
    resolution: dict = field(default_factory=dict)     # sensor -> step of its integers
    truncated: bool = False     # integers truncated toward zero, then moved half a step out
    block_length: int = 1       # recorded samples averaged into each sample (block means)
    lattice: dict = field(default_factory=dict)    # sensor -> (origin (3,), step (3,)) raw

    def format_of(self, sensor: str) -> tuple[np.ndarray, np.ndarray]:
        """(origin, step), each (3,) [unit]: the raw value of a count of 0 and of one count
        of ``sensor``'s integer format (:attr:`lattice`; origin 0 and ``resolution`` when the
        lattice is not known)."""
        if sensor in self.lattice:
            return self.lattice[sensor]
        return np.zeros(3), np.full(3, float(self.resolution[sensor]))

    @property
    def fs(self) -> float:
        """Median sample rate [Hz] (found once per time axis: a model reads it hundreds of
        times, and a median of a 10-minute 400 Hz session's intervals takes 0.6 ms; kept with
        the very array it was found from, so a session given another ``t`` finds it anew)."""
        known = self.__dict__.get("_fs_of_t")
        if known is None or known[0] is not self.t:
            known = (self.t, float(1.0 / np.median(np.diff(self.t))))
            self.__dict__["_fs_of_t"] = known
        return known[1]

    @property
    def duration(self) -> float:
        """Time from the first sample to the last [s]."""
        return float(self.t[-1] - self.t[0])

    def hold_of_piece(self, piece: int) -> int | None:
        """Index into ``holds`` of a hold piece, None for a motion piece."""
        seg = self.segments[self.pieces.segment[piece]]
        return seg.index if seg.kind == "hold" else None


def contiguous_runs(indices: np.ndarray) -> list[tuple[int, int]]:
    """Half-open ranges of consecutive integers in a sorted index array.

    Parameters
    ----------
    indices : (k,) int array
        Sorted sample indices.

    Returns
    -------
    list of (int, int)
    """
    if len(indices) == 0:
        return []
    breaks = np.flatnonzero(np.diff(indices) != 1) + 1
    starts = np.concatenate(([0], breaks))
    ends = np.concatenate((breaks, [len(indices)]))
    return [(int(indices[a]), int(indices[b - 1]) + 1) for a, b in zip(starts, ends)]


def split_evenly(i0: int, i1: int, fs: float, max_piece_s: float,
                 min_piece_s: float) -> list[tuple[int, int]]:
    """``[i0, i1)`` cut into equal pieces of at most ``max_piece_s``, an even number of them when
    two pieces of ``min_piece_s`` fit (one otherwise; none when even one does not fit).

    Parameters
    ----------
    i0, i1 : int
        Half-open sample range.
    fs : float
        Sample rate [Hz].
    max_piece_s, min_piece_s : float
        Longest and shortest piece [s].

    Returns
    -------
    list of (int, int)
        Half-open sample ranges of the pieces.
    """
    n = i1 - i0
    if n < min_piece_s * fs:
        return []
    count = int(np.ceil(n / (max_piece_s * fs)))
    if n >= 2 * min_piece_s * fs:
        count = max(2, count + count % 2)
    edges = np.round(np.linspace(i0, i1, count + 1)).astype(int)
    return list(zip(edges[:-1].tolist(), edges[1:].tolist()))


def scorable_holds(t: np.ndarray, holds: list,
                   min_piece_s: float = MIN_PIECE_S) -> tuple[list, int]:
    """The holds with at least one piece to score, and how many were too short: a hold
    without pieces has no fitted orientation, so it belongs to the move it interrupts.

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    holds : list of StaticSegment
    min_piece_s : float
        Shortest piece [s].

    Returns
    -------
    kept : list of StaticSegment
    too_short : int
    """
    fs = float(1.0 / np.median(np.diff(t)))
    kept = [h for h in holds if any(split_evenly(a, b, fs, MAX_PIECE_S, min_piece_s)
                                    for a, b in contiguous_runs(h.kept()))]
    return kept, len(holds) - len(kept)


def _hold_label(k: int, seg) -> str:
    return f"hold {k + 1}" + (f" ({seg.pose})" if seg.pose else "")


def cut_session(t: np.ndarray, holds: list, acc: np.ndarray | None = None, *,
                max_piece_s: float = MAX_PIECE_S, min_piece_s: float = MIN_PIECE_S,
                max_motion_s: float = MAX_MOTION_S) -> tuple[list[Segment], Pieces]:
    """Segments (holds and the moves between them) and their pieces with alternating folds;
    with ``acc`` (n, 3), moves that carry linear acceleration are left out.

    Parameters
    ----------
    t : (n,) array
        Sample times [s].
    holds : list of StaticSegment
    acc : (n, 3) array, optional
        Accelerometer [m/s²].
    max_piece_s, min_piece_s : float
        Longest and shortest piece [s].
    max_motion_s : float
        Longest move [s].

    Returns
    -------
    segments : list of Segment
    pieces : Pieces

    Raises
    ------
    ApmcalError
        When no hold has a piece of ``min_piece_s``.
    """
    fs = float(1.0 / np.median(np.diff(t)))
    segments: list[Segment] = []
    rows: list[tuple[int, int, int, int, bool]] = []      # i0, i1, segment, fold, is_hold
    single_fold = 0
    for k, hold in enumerate(holds):
        if k > 0:
            _add_motion(t, acc, holds, k, segments, rows, max_motion_s)
        segments.append(Segment("hold", k, hold.i0, hold.i1, _hold_label(k, hold)))
        ranges = [r for a, b in contiguous_runs(hold.kept())
                  for r in split_evenly(a, b, fs, max_piece_s, min_piece_s)]
        if len(ranges) == 1:
            rows.append((*ranges[0], len(segments) - 1, single_fold, True))
            single_fold ^= 1
            continue
        for j, (a, b) in enumerate(ranges):
            rows.append((a, b, len(segments) - 1, (j + k) % 2, True))
    if not rows:
        raise ApmcalError(f"no still period of {min_piece_s:g} s or more to analyse")
    arr = np.array(rows, dtype=object)
    pieces = Pieces(arr[:, 0].astype(int), arr[:, 1].astype(int), arr[:, 2].astype(int),
                    arr[:, 3].astype(int), arr[:, 4].astype(bool))
    return segments, pieces


def _add_motion(t, acc, holds, k, segments, rows, max_motion_s) -> None:
    """The move from hold k−1 to hold k, when it is short, has no logging hole and is a turn
    (no linear acceleration to speak of)."""
    a, b = holds[k - 1].i1, holds[k].i0
    if b - a < MIN_MOTION_SAMPLES or t[b - 1] - t[a] > max_motion_s:
        return
    dt = np.diff(t[a - 1:b + 1])
    if np.any(dt > GAP_FACTOR * np.median(np.diff(t))):
        return
    if acc is not None and linear_acceleration(acc[a:b], holds[k - 1], holds[k]) > MAX_LINEAR_G:
        return
    index = sum(s.kind == "motion" for s in segments)
    segments.append(Segment("motion", index, a, b, f"move {index + 1} (hold {k} → {k + 1})",
                            before=k - 1, after=k))
    rows.append((a, b, len(segments) - 1, index % 2, False))


def linear_acceleration(acc: np.ndarray, before, after) -> float:
    """RMS departure of |acc| from the two holds' mean magnitude, in units of it.

    Parameters
    ----------
    acc : (k, 3) array
        Accelerometer samples of the move [m/s²].
    before, after : StaticSegment
        The holds around it.

    Returns
    -------
    float
        Dimensionless (0.1: a tenth of the holds' magnitude).
    """
    level = 0.5 * (np.linalg.norm(before.acc_mean) + np.linalg.norm(after.acc_mean))
    return float(np.sqrt(np.mean((np.linalg.norm(acc, axis=1) - level) ** 2)) / level)


def map_pieces(t_imu: np.ndarray, t_other: np.ndarray, pieces: Pieces) -> tuple[np.ndarray,
                                                                                np.ndarray]:
    """Each piece's sample range on another time axis (same clock), by its first and last time.

    Parameters
    ----------
    t_imu : (n,) array
        IMU sample times [s].
    t_other : (m,) array
        The other axis's sample times [s], ascending.
    pieces : Pieces

    Returns
    -------
    i0, i1 : (p,) int arrays
        Half-open ranges on the other axis (i0 == i1: no sample in the piece).
    """
    i0 = np.searchsorted(t_other, t_imu[pieces.i0], side="left")
    i1 = np.searchsorted(t_other, t_imu[pieces.i1 - 1], side="right")
    return i0, np.maximum(i1, i0)


def session_from_log(contents, opts) -> Session:
    """The diagnosis session of one IMU instance of a log (``opts``: pipeline.Options).

    The samples are prepared exactly as for a calibration (firmware correction undone, only
    the samples after a calibration-parameter change kept); the holds are the calibration's.

    Raises
    ------
    ApmcalError
        Without gyroscope samples, without a still period long enough to score, or when one
        fold would have no still piece.
    """
    # here, not at the top: they load pandas, which the diagnosis itself never needs (a session
    # is read in a worker while the main process imports the diagnosis, apmcal.cli.gap)
    from apmcal.preprocessing.param_changes import split_at_param_changes
    from apmcal.preprocessing.prepare import has_live_magnetometer, pick_recording, prepare, recording_date
    from apmcal.preprocessing.resolution import INT16_TELEMETRY
    from apmcal.preprocessing.static import find_static_segments

    recording, mag_recording = pick_recording(contents, opts.instance)
    recording, mag_recording, notes = split_at_param_changes(
        recording, mag_recording, contents.param_changes, contents.path)
    prepared = prepare(recording, opts.generation)
    raw = prepared.raw
    if not raw.has("gyr"):
        raise ApmcalError(f"{recording.message} has no gyroscope samples: the diagnosis needs "
                          "accelerometer and gyroscope", contents.path)
    t, acc, gyr = raw.t, raw.xyz("acc"), raw.xyz("gyr")
    holds = find_static_segments(t, acc, gyr, min_duration=opts.min_still_s)
    if not holds:
        raise ApmcalError(f"no still period of {opts.min_still_s:g} s or more: the diagnosis "
                          "compares still periods (or lower --min-still)", contents.path)
    holds, short = scorable_holds(t, holds)
    if short:
        notes = list(notes) + [f"{short} still period(s) shorter than {MIN_PIECE_S:g} s taken "
                               "as part of the moves around them"]
    if not holds:
        raise ApmcalError(f"no still period of {MIN_PIECE_S:g} s or more to analyse",
                          contents.path)
    segments, pieces = cut_session(t, holds, acc)
    for fold in (0, 1):
        if not np.any(pieces.is_hold & (pieces.fold == fold)):
            still = sum(h.end - h.start for h in holds)
            raise ApmcalError(f"only {still:.0f} s still in {len(holds)} period(s): the "
                              "diagnosis fits on one half of the still data and scores on the "
                              "other, and needs at least two still pieces (record longer "
                              "still poses)", contents.path)
    left_out = max(len(holds) - 1 - sum(s.kind == "motion" for s in segments), 0)
    if left_out:
        notes = list(notes) + [f"{left_out} stretch(es) between holds not scored as moves: "
                               f"longer than {MAX_MOTION_S:g} s, across a logging hole, or "
                               "carried rather than turned (linear acceleration)"]
    session = Session(contents.path, t, acc, gyr, holds, segments, pieces,
                      temp=_column(raw, "temp"), current=_column(raw, "current"),
                      lat_deg=opts.lat_deg, lon_deg=opts.lon_deg,
                      date=recording_date(contents), notes=notes + prepared.warnings)
    integer = set(raw.sensors) if recording.message in INT16_TELEMETRY else set()
    session.resolution = {s: float(prepared.steps[s]) for s in integer if s in prepared.steps}
    session.truncated = bool(integer)
    session.lattice = format_lattice(recording, session.resolution, opts.generation)
    if has_live_magnetometer(raw):
        session.mag = MagAxis(t, raw.xyz("mag"), pieces.i0, pieces.i1, session.current)
    elif mag_recording is not None and has_live_magnetometer(mag_recording):
        m = prepare(mag_recording, opts.generation).raw
        i0, i1 = map_pieces(t, m.t, pieces)
        cur = None if session.current is None else np.interp(m.t, t, session.current)
        session.mag = MagAxis(m.t, m.xyz("mag"), i0, i1, cur)
        if INTEGER_MAG.match(mag_recording.message):
            integer.add("mag")
            session.resolution["mag"] = 1.0     # int16 mGauss
    session.integer_sensors = frozenset(integer)
    return session


def format_lattice(recording, resolution: dict, generation) -> dict:
    """Where the counts of each integer sensor of ``recording`` sit in raw units: {sensor:
    (origin, step)}, each (3,), for the sensors whose correction is one offset and one scale
    per axis (a board rotation that mixes axes leaves a lattice that is not per axis: left
    out). The firmware's correction undone on a count of 0 and on one count per axis, exactly
    as the reader undoes it on the readings (:func:`apmcal.ardupilot.firmware.uncorrect`)."""
    if not resolution or not (recording.corrected or recording.frame == "body"):
        return {}
    import pandas as pd

    from apmcal.ardupilot.firmware import uncorrect
    from apmcal.core.recording import SENSOR_COLUMNS

    sensors = [s for s in resolution if s in ("acc", "gyr")]
    probe = {"t": np.arange(4.0)}
    for sensor in sensors:
        for k, col in enumerate(SENSOR_COLUMNS[sensor]):
            probe[col] = np.r_[0.0, np.eye(3)[k] * resolution[sensor]]
    try:
        raw = uncorrect(dataclasses.replace(recording, data=pd.DataFrame(probe)),
                        generation=generation)
    except ApmcalError:
        return {}
    out = {}
    for sensor in sensors:
        x = raw.data[SENSOR_COLUMNS[sensor]].to_numpy(dtype=float)
        origin, m = x[0], x[1:] - x[0]      # row k: one count on axis k
        if np.all(np.abs(m - np.diag(np.diag(m))) <= 1e-9 * np.abs(np.diag(m)).max()):
            out[sensor] = (origin, np.abs(np.diag(m)))
    return out


def _column(recording, name: str) -> np.ndarray | None:
    """An optional column with its gaps filled by interpolation; None when mostly missing."""
    if name not in recording.data.columns:
        return None
    x = recording.data[name].to_numpy(dtype=float)
    ok = np.isfinite(x)
    if ok.mean() < 0.5:
        return None
    if ok.all():
        return x
    t = recording.t
    return np.interp(t, t[ok], x[ok])
