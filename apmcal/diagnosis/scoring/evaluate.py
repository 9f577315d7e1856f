"""Scoring one model: fitted on a fold of the real session and of its twin, compared in-sample
(the fitting fold) and held-out (the other fold), both ways round.

Real and twin go through exactly the same fit, so what a fit absorbs (nuisance orientations,
parameters fitted to noise) it absorbs in both, and a correct model scores a gap of zero on
average in-sample as well as held-out.
"""
from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from apmcal.diagnosis.compute import workers
from apmcal.diagnosis.model.dynamics import Moves, fit_dynamics, move_residuals
from apmcal.diagnosis.model.effects import BY_NAME, NAMES, unmet
from apmcal.diagnosis.model.nominal import (
    ModelFit,
    calibrated_rate,
    fit_model,
    hold_residuals,
    hold_vectors,
    reduce_session,
    set_acc_terms,
)
from apmcal.diagnosis.model.params import effect_params, mean_of_folds
from apmcal.diagnosis.model.static_fit import count_orientations
from apmcal.diagnosis.noise.fit import NoiseModel, fit_noise
from apmcal.diagnosis.scoring.gap import GapEstimate, coefficients, compare
from apmcal.diagnosis.session.decimate import block_factor, decimated
from apmcal.diagnosis.session.facts import earth_field, lattice_steps, sample_sigma, variance_floors
from apmcal.diagnosis.session.hold_motion import (
    amplitudes,
    confirmed,
    confirmed_by_accelerometer,
    extract_motion,
    hold_rotations,
)
from apmcal.diagnosis.twin.simulate import motion_of, simulate

FOLDS = (0, 1)
# effects whose models take about twice as long as the others' to fit (moves integrated in
# every least-squares step, or the holds' own motion extracted): scheduled first
SLOW_TO_FIT = frozenset({"gyro_scale", "motion_contamination", "time_offset"})
ACC_TERM_ROUNDS = 2     # hold/move alternations of the accelerometer terms the moves fit
# effects that change only the noise model and the twin, not the fit of the real data
NOISE_ONLY = frozenset({"quantization", "lowpass_filter", "uniform_noise", "bias_random_walk"})
NULL_SEEDS = 1 << 24    # noise seeds of the null sessions (the twins' are the evaluator's seed
                        # plus the fold: small numbers)
TWIN_DRAWS = 1 << 20    # with a recorded twin: draw k's twin is draw k + TWIN_DRAWS
REAL_MODELS_KEPT = 2    # real fits kept per process (each holds all its residuals: 44 MB
                        # for a 10-minute 400 Hz session), the two folds of one model


@dataclass
class FoldResult:
    """One direction of the cross-validation: fitted on ``fold``, held out on the other.

    Attributes
    ----------
    fold : int
        The fitting fold, 0 or 1.
    fit : ModelFit
    noise : NoiseModel
    real : list of BlockCoefficients or None
        Haar coefficients of the real residuals (all pieces); None once dropped (a result
        sent back from a worker).
    twin : list of BlockCoefficients or None
        The same of the twin's residuals.
    gap_in, gap_out : GapEstimate
        In-sample (on ``fold``) and held-out (on the other fold) gap.
    params : dict
        Each effect's fitted parameters (:mod:`apmcal.diagnosis.model.params`).
    """

    fold: int
    fit: ModelFit
    noise: NoiseModel
    real: list          # BlockCoefficients of the real residuals (all pieces)
    twin: list          # ... of the twin's
    gap_in: GapEstimate
    gap_out: GapEstimate
    params: dict        # each effect's fitted parameters (apmcal.diagnosis.model.params)


@dataclass
class Evaluation:
    """A model's gaps, in-sample and held-out, over both folds."""

    effects: frozenset
    folds: list

    @staticmethod
    def _pooled(parts: list[GapEstimate]) -> float:
        n = sum(p.n_samples for p in parts)
        return sum(p.nats for p in parts) / n if n else 0.0

    @property
    def gap_in(self) -> float:
        """In-sample gap [nats per sample]."""
        return self._pooled([f.gap_in for f in self.folds])

    @property
    def gap_out(self) -> float:
        """Held-out gap [nats per sample]."""
        return self._pooled([f.gap_out for f in self.folds])

    @property
    def nats_out(self) -> float:
        """Held-out gap in total [nats], both folds."""
        return float(sum(f.gap_out.nats for f in self.folds))

    def held_out_cells(self) -> list:
        """Every held-out cell of both folds (CellShare)."""
        return [c for f in self.folds for c in f.gap_out.cells]

    def piece_nats(self, n_pieces: int, held_out: bool = True) -> np.ndarray:
        """Gap [nats] attributed to each piece (held-out, or in-sample).

        Parameters
        ----------
        n_pieces : int
            Number of pieces of the session.
        held_out : bool
            The held-out cells (True) or the in-sample ones.

        Returns
        -------
        (n_pieces,) array
            Gap [nats] by session-wide piece id, both folds.
        """
        out = np.zeros(n_pieces)
        for f in self.folds:
            for c in (f.gap_out if held_out else f.gap_in).cells:
                np.add.at(out, c.piece, c.nats)
        return out


@dataclass
class Context:
    """What the session offers the candidate effects (see :func:`effects.unmet`).

    Attributes
    ----------
    orientations : int
        Distinct still orientations.
    steps : dict
        Quantization step per axis of each sensor, (3,) in its unit (None: no lattice).
    """

    orientations: int       # distinct still orientations
    steps: dict             # quantization step per axis of each sensor (None: no lattice)


@dataclass(frozen=True)
class FoldSummary:
    """What ranking needs of one fold's result: its gaps [nats] over so many samples, and the
    effects' fitted parameters (small enough to send back from a worker).

    Attributes
    ----------
    nats_in, nats_out : float
        In-sample and held-out gap [nats].
    n_in, n_out : int
        Residual samples they are over.
    params : dict
        Each effect's fitted parameters.
    """

    nats_in: float
    n_in: int
    nats_out: float
    n_out: int
    params: dict

    @classmethod
    def of(cls, fold: FoldResult) -> "FoldSummary":
        """The summary of one fold's result."""
        return cls(fold.gap_in.nats, fold.gap_in.n_samples, fold.gap_out.nats,
                   fold.gap_out.n_samples, fold.params)


@dataclass(frozen=True)
class Summary:
    """The numbers of an evaluation that ranking and selection need [nats per sample; nats],
    and the effects' parameters, averaged over the two folds' fits.

    Attributes
    ----------
    gap_in, gap_out : float
        In-sample and held-out gap [nats per sample].
    nats_out : float
        Held-out gap in total [nats].
    params : dict
        Each effect's parameters, mean of the folds (:func:`apmcal.diagnosis.model.params.
        mean_of_folds`).
    """

    gap_in: float
    gap_out: float
    nats_out: float
    params: dict

    @classmethod
    def of(cls, evaluation: Evaluation) -> "Summary":
        """The summary of a whole evaluation."""
        return cls.of_folds(evaluation.effects, [FoldSummary.of(f) for f in evaluation.folds])

    @classmethod
    def of_folds(cls, effects, folds: list[FoldSummary]) -> "Summary":
        """Pooled over the folds, as :class:`Evaluation` pools them."""
        n_in, n_out = sum(f.n_in for f in folds), sum(f.n_out for f in folds)
        nats_in, nats_out = sum(f.nats_in for f in folds), sum(f.nats_out for f in folds)
        params = {name: mean_of_folds([f.params[name] for f in folds]) for name in effects}
        return cls(nats_in / n_in if n_in else 0.0, nats_out / n_out if n_out else 0.0,
                   float(nats_out), params)


class Evaluator:
    """Fits and scores models of one session; evaluations are cached by effect set.

    Parameters
    ----------
    session : Session
        The real session.
    seed : int
        Seed of the twins' noise (fold f uses ``seed + f``).
    twin : Session, optional
        A recorded twin on the real session's samples (:func:`apmcal.diagnosis.session.
        twin_log.on_samples_of`): every model's twin is then this one recording, fitted with
        the model as the real session is, instead of a session simulated from the model's fit;
        its null sessions are pairs of sessions drawn from the nominal model, one as the real
        session and one as the twin.
    """

    def __init__(self, session, seed: int = 0, twin=None, redraw=None):
        self._session = session
        self._redraw = redraw       # a null session's: (session, twin) drawn again on demand
        self.seed = seed
        self.twin = twin
        self._reasons: dict[str, str | None] = {}   # why each candidate is not testable here
        # evidence [nats] each candidate must reach, where the null calibration set one
        # (apmcal.diagnosis.scoring.null); MIN_EVIDENCE_NATS elsewhere
        self.min_evidence: dict[str, float] = {}
        self.chance = None      # the null calibration that sets min_evidence on first need
                                # (apmcal.diagnosis.scoring.null.Calibration), once made
        self._drawn_from: dict = {}     # (effects, fold) -> the fit and noise null sessions
                                        # are drawn from (model_draw)
        self._cache: dict[frozenset, Evaluation] = {}
        self._summaries: dict[frozenset, Summary] = {}
        self._motion: dict = {}     # per fold: the real motion (poses, moves, hold motion)
        self._real_models: dict = {}    # (effects but the noise's, fold, σ) -> _model's result
        self._kept = None               # workers kept per fold (workers_kept), while kept
        self._nulls_here: dict = {}     # in such a worker: the null sessions it drew

    @property
    def session(self):
        """The session (a null session shed after use is drawn again here: :meth:`shed`)."""
        if self._session is None:
            self._session, self.twin = self._redraw()
        return self._session

    def reason(self, name: str) -> str | None:
        """Why candidate ``name`` cannot be tested on this session (None: it can), found once
        (:func:`apmcal.diagnosis.model.effects.unmet`)."""
        if name not in self._reasons:
            self._reasons[name] = unmet(BY_NAME[name], self.session, self.context)
        return self._reasons[name]

    def reasons(self) -> dict:
        """:meth:`reason` of every candidate (what a worker sends back with a null session's
        summaries, so that the process keeping them need not draw the session itself)."""
        return {name: self.reason(name) for name in NAMES}

    def shed(self) -> None:
        """Forget everything of a null session but its summaries, its testability and its
        nominal fits: its samples, block means, motion paths, fitted residuals and cached
        evaluations, all found again from the model it is drawn from when a later candidate
        needs them (the null sessions of a long 400 Hz session are a few hundred MB each).
        The real session keeps everything."""
        if self._redraw is None:
            return
        self._session = self.twin = None
        for name in ("reduced", "_twin_reduced", "_earth", "steps", "floors", "context",
                     "sample_sigma", "fs_of", "move_rows", "slow"):
            self.__dict__.pop(name, None)
        self._cache.clear()
        self._real_models.clear()
        self._nulls_here.clear()
        self._motion = {key: value for key, value in self._motion.items()
                        if isinstance(key, tuple) and key[0] == "nominal"}

    # What the session offers every model, each found from the session alone on first use: an
    # evaluator made only for its block means (:attr:`slow`, e.g. a null session's scored on
    # them) never needs those of the recorded rate. :meth:`facts` finds them all before work
    # is spread over forked workers, which would otherwise each find them anew.

    @cached_property
    def reduced(self):
        """The session's hold blocks (:func:`apmcal.diagnosis.model.nominal.reduce_session`)."""
        return reduce_session(self.session)

    @cached_property
    def _twin_reduced(self):
        """The recorded twin's hold blocks (with a recorded twin only)."""
        return reduce_session(self.twin)

    @cached_property
    def _earth(self) -> tuple:
        return earth_field(self.session)

    @property
    def field_mgauss(self) -> float | None:
        """WMM field magnitude at the site [mGauss] (None: not known)."""
        return self._earth[0]

    @property
    def declination_rad(self) -> float:
        """Magnetic declination at the site [rad] (0 when the field is not known)."""
        return self._earth[1]

    @cached_property
    def steps(self) -> dict:
        """Quantization step per axis of each sensor (:func:`~apmcal.diagnosis.session.facts.
        lattice_steps`)."""
        return lattice_steps(self.session)

    @cached_property
    def floors(self) -> dict:
        """Variance floor of each channel [unit²] (:func:`~apmcal.diagnosis.session.facts.
        variance_floors`)."""
        return variance_floors(self.session, self.steps)

    @cached_property
    def context(self) -> Context:
        """What the session offers the candidate effects."""
        return Context(count_orientations(self.reduced.acc, "acc"), self.steps)

    @cached_property
    def sample_sigma(self) -> dict:
        """Per-sample noise of the accelerometer [m/s²] and compass [mGauss] in the holds."""
        return sample_sigma(self.session)

    @cached_property
    def fs_of(self) -> dict:
        """Sample rate of each sensor [Hz]."""
        session = self.session
        out = {"acc": session.fs, "gyr": session.fs}
        if session.mag is not None:
            out["mag"] = float(1.0 / np.median(np.diff(session.mag.t)))
        return out

    @cached_property
    def move_rows(self) -> np.ndarray:
        """The samples the moves' integration reads: the same for the session and its twins
        (simulated on its sample axis), so found once."""
        return Moves.of(self.session).rows()

    def facts(self) -> "Evaluator":
        """Find everything above now (before models are spread over forked workers)."""
        for name in ("reduced", "_earth", "steps", "floors", "context", "sample_sigma",
                     "fs_of", "move_rows"):
            getattr(self, name)
        return self

    def steps_for(self, effects) -> dict:
        """Quantization steps the model reproduces: the log format's always, the sensors'
        own (a lattice in floating-point samples) with the quantization effect."""
        return {s: step for s, step in self.steps.items()
                if s in self.session.integer_sensors or "quantization" in effects}

    def fit(self, session, reduced, effects, train_fold, start=None, with_sigma=None,
            with_noise=True):
        """Model and noise fitted on ``train_fold`` (None: every piece), and the Haar
        coefficients of all residuals (``with_sigma``: the fits' uncertainties too; by
        default when fitting every piece; ``with_noise`` False: no noise model, None in its
        place — a twin's, which nothing reads).

        Parameters
        ----------
        session : Session
            The real session or a twin.
        reduced : Reduced
            Its block means (:func:`apmcal.diagnosis.model.nominal.reduce_session`).
        effects : collection of str
            The effects on top of the nominal model.
        train_fold : int or None
            Fold fitted on (None: every piece).
        start : ModelFit, optional
            A fit to start from (the real one, for its twin).

        Returns
        -------
        fit : ModelFit
        noise : NoiseModel or None
        coefficients : list of BlockCoefficients
            Of the hold residuals, then of the move residuals, over all pieces.
        """
        effects = frozenset(effects)
        with_sigma = train_fold is None if with_sigma is None else with_sigma
        if session is self.session and start is None:
            fit, holds, moves = self._real_model(effects, train_fold, with_sigma)
        else:
            fit, holds, moves = self._model(session, reduced, effects, train_fold, start,
                                            with_sigma)
        noise = None
        if with_noise:
            train = session.pieces.select(fold=train_fold)
            noise = fit_noise(holds, train, effects, self.fs_of, self.steps_for(effects),
                              truncated=self.session.truncated,
                              origins={s: o for s, (o, _) in self.session.lattice.items()})
            if fit.hold_motion is not None:
                kappa = self._hold_motion(train_fold if train_fold is not None else 0)[2]
                noise["gyr"].tremor_deg, noise["gyr"].sway_deg = amplitudes(fit.hold_motion[0],
                                                                            self.session)
                noise["gyr"].motion_confirmed = tuple(kappa)
        return fit, noise, holds + moves

    def _real_model(self, effects: frozenset, train_fold, with_sigma: bool) -> tuple:
        """:meth:`_model` of the real session, kept for the models that differ from it only in
        effects of the noise (:data:`NOISE_ONLY`): those leave the fit and its residuals as
        they are (a low-pass filter scored at 400 Hz refits nothing the nominal model has not
        fitted already)."""
        key = (effects - NOISE_ONLY, train_fold, with_sigma)
        if key not in self._real_models:
            self._real_models[key] = self._model(self.session, self.reduced, key[0], train_fold,
                                                 None, with_sigma)
            while len(self._real_models) > REAL_MODELS_KEPT:
                self._real_models.pop(next(iter(self._real_models)))
        fit, holds, moves = self._real_models[key]
        return replace(fit, effects=effects), holds, moves

    def _model(self, session, reduced, effects: frozenset, train_fold, start,
               with_sigma: bool) -> tuple:
        """The model fitted on ``train_fold`` without its noise: (fit, hold coefficients, move
        coefficients)."""
        fit = fit_model(session, reduced, effects, train_fold, field_mgauss=self.field_mgauss,
                        declination_rad=self.declination_rad, start=start, with_sigma=with_sigma)
        train = session.pieces.select(fold=train_fold)
        rate = calibrated_rate(session, fit, self.move_rows)    # the moves read it only
        f_hold, b_hold = hold_vectors(fit, len(session.holds))
        fit.dynamics = fit_dynamics(session, fit, effects, train, rate, f_hold, b_hold,
                                    self.sample_sigma)
        for _ in range(ACC_TERM_ROUNDS):
            if fit.dynamics.acc_terms is None:
                break
            # the moves' accelerometer terms and the holds' offsets and scales depend on each
            # other: alternate (each round refits the holds with them, then the moves)
            set_acc_terms(fit, reduced, train, fit.dynamics.acc_terms)
            f_hold, b_hold = hold_vectors(fit, len(session.holds))
            fit.dynamics = fit_dynamics(session, fit, effects, train, rate, f_hold, b_hold,
                                        self.sample_sigma)
        if fit.dynamics.acc_terms is not None:
            set_acc_terms(fit, reduced, train, fit.dynamics.acc_terms)
            fit.dynamics.acc_terms = None           # now part of the accelerometer itself
            f_hold, b_hold = hold_vectors(fit, len(session.holds))
        if "motion_contamination" in effects:
            # the real motion in the holds, measured by the gyro, is part of the model (and so
            # of the twin); its size is what gets reported
            motion, turn, _ = self._hold_motion(train_fold if train_fold is not None else 0)
            fit.hold_motion = (motion, turn)
        holds = coefficients(hold_residuals(session, fit))
        moves = coefficients(move_residuals(session, fit, fit.dynamics, rate, f_hold, b_hold))
        return fit, holds, moves

    def _nominal(self, fold: int):
        """The nominal fit and noise of ``fold`` (with σ: the very fit the nominal model's own
        evaluation makes, :meth:`_fold`)."""
        if ("nominal", fold) not in self._motion:
            self._motion[("nominal", fold)] = self.fit(self.session, self.reduced, (), fold,
                                                       with_sigma=True)[:2]
        return self._motion[("nominal", fold)]

    def model_draw(self, effects, draw: int):
        """A session drawn from the fitted model nominal + ``effects``: this session's times,
        poses, moves, temperatures and current, its readings simulated afresh from that model's
        fit on fold ``draw % 2`` with noise seed ``NULL_SEEDS + draw`` (none of the twins'
        seeds) — a session in which exactly those effects exist, no other candidate
        (:mod:`apmcal.diagnosis.scoring.null`)."""
        fold, key = draw % 2, frozenset(effects)
        if not key:
            fit, noise = self._nominal(fold)
        else:
            if (key, fold) not in self._drawn_from:
                self._drawn_from[(key, fold)] = self.fit(self.session, self.reduced, key, fold,
                                                         with_sigma=False)[:2]
            fit, noise = self._drawn_from[(key, fold)]
        session, _ = simulate(self.session, fit, noise, seed=NULL_SEEDS + draw,
                              motion_path=self._motion_path(fold))
        return session

    def null_evaluator(self, effects, draw: int) -> "Evaluator":
        """The evaluator of null session ``draw`` drawn from the model nominal + ``effects``
        (:meth:`model_draw`), drawn when first read (and again after :meth:`shed`); with a
        recorded twin, its twin is another session drawn from that model (seeds
        :data:`TWIN_DRAWS` apart): two recordings of one process."""
        effects, recorded = tuple(effects), self.twin is not None

        def redraw():
            twin = self.model_draw(effects, draw + TWIN_DRAWS) if recorded else None
            return self.model_draw(effects, draw), twin

        return Evaluator(None, self.seed, redraw=redraw)

    def _motion_path(self, fold: int):
        """The real poses and moves as the nominal model sees them: one path for all models."""
        if fold not in self._motion:
            self._motion[fold] = motion_of(self.session, self._nominal(fold)[0])
        return self._motion[fold]

    def _hold_motion(self, fold: int) -> tuple:
        """The real motion inside the holds, rate and turn, each band as far as the
        accelerometer confirms it on the training pieces (for motion contamination)."""
        key = ("hold_motion", fold)
        if key not in self._motion:
            fit, _ = self._nominal(fold)
            s = self.session
            f_hold, _ = hold_vectors(fit, len(s.holds))
            train = s.pieces.select(fold=fold, hold=True)
            bands = extract_motion(calibrated_rate(s, fit), s)
            kappa = [confirmed_by_accelerometer(s, band, f_hold, train) for band in bands]
            rate = sum(band for k, band in zip(kappa, bands) if confirmed(k)) \
                if any(confirmed(k) for k in kappa) else np.zeros_like(bands[0])
            self._motion[key] = (rate, hold_rotations(s, rate), kappa)
        return self._motion[key]

    def summary(self, effects) -> Summary:
        """The model's gaps (cached; computed here unless :meth:`prefetch` did it)."""
        key = frozenset(effects)
        if key not in self._summaries:
            self._summaries[key] = Summary.of(self.evaluate(key))
        return self._summaries[key]

    def _known(self, key: frozenset) -> bool:
        return key in self._summaries or key in self._cache

    def prefetch(self, models) -> None:
        """Summaries of several models at once, on every core. The jobs are single folds (each
        fold of each model is independent of the others), so that an odd number of models
        still keeps both cores busy to the end."""
        todo = _slowest_first(m for m in models if not self._known(frozenset(m)))
        if not todo:
            return
        if frozenset() in todo and self._cold():
            # the nominal model's folds warm the evaluator: its fit is each fold's nominal fit
            todo.remove(frozenset())
            if todo and workers.parallel() and (os.cpu_count() or 1) <= len(FOLDS):
                self._prefetch_by_fold(todo)
                return
            self.keep_nominal_folds(self.map([("_nominal_fold", (fold, True)) for fold in FOLDS]))
        self.warm()
        parts = self.map([("fold_summary", (key, fold)) for key in todo for fold in FOLDS])
        for i, key in enumerate(todo):
            self._summaries[key] = Summary.of_folds(key, parts[i * len(FOLDS):
                                                               (i + 1) * len(FOLDS)])

    def _cold_lane(self, fold: int, todo: list) -> list:
        """Fold ``fold`` of the nominal model (summary and state, :meth:`_nominal_fold`) and
        then of every model of ``todo``, in this process: what one worker of
        :meth:`_prefetch_by_fold` does. A null session (one that can be drawn again) sends
        back no state but its nominal fit and its candidates' testability, and is shed."""
        nominal = self._nominal_fold(fold, True)
        lane = [nominal] + [self.fold_summary(key, fold) for key in todo]
        if self._redraw is not None:
            summary, (motion, _) = nominal
            kept = {key: value for key, value in motion.items() if key == ("nominal", fold)}
            lane[0] = (summary, (kept, {}))
            lane.append(self.reasons())
            self.shed()
        return lane

    def prefetch_nulls(self, work: list) -> None:
        """:meth:`prefetch` on null sessions drawn from this evaluator's models, in the
        workers kept per fold (:meth:`workers_kept`), each of which draws the session itself
        (:meth:`model_draw`: the same readings, bit for bit, wherever drawn) and keeps it for
        its next jobs: no workers forked per null session.

        Parameters
        ----------
        work : list of (effects, draw, Evaluator, models)
            ``effects`` and ``draw`` as for :meth:`model_draw`; the evaluator of that session
            in this process (the summaries are kept there); the models to prefetch on it.
        """
        jobs, kept = [], []
        for effects, draw, null, models in work:
            todo = [key for key in dict.fromkeys(frozenset(m) for m in models)
                    if key and not null._known(key)]
            if not todo and null._known(frozenset()):
                continue
            kept.append((null, todo))
            jobs += [("_null_fold", (tuple(sorted(effects)), draw, fold, todo))
                     for fold in FOLDS]
        results = iter(self.map(jobs))
        for null, todo in kept:
            folds = [next(results) for _ in FOLDS]
            null._summaries.setdefault(frozenset(),
                                       Summary.of_folds(frozenset(), [n for n, _, _ in folds]))
            null._reasons.update(folds[0][2])
            for i, key in enumerate(todo):
                null._summaries[key] = Summary.of_folds(key, [parts[i] for _, parts, _ in folds])

    def _null_fold(self, effects: tuple, draw: int, fold: int, todo: list) -> tuple:
        """A job of a worker kept per fold (:meth:`prefetch_nulls`): fold ``fold`` of the
        null session ``model_draw(effects, draw)``, drawn in this worker on first use and
        shed after each job (:meth:`shed`); (its nominal model's FoldSummary, the
        FoldSummaries of ``todo``, its candidates' testability)."""
        key = (effects, draw)
        if key not in self._nulls_here:
            self._nulls_here[key] = (self.null_evaluator(effects, draw), {})
        null, nominal = self._nulls_here[key]
        if fold not in nominal:
            nominal[fold] = null._nominal_fold(fold, True)[0]
        out = nominal[fold], [null.fold_summary(k, fold) for k in todo], null.reasons()
        null.shed()
        return out

    def _keep_lanes(self, todo: list, lanes: list) -> None:
        """Keep what :meth:`_cold_lane` gave for each fold (``lanes``, in fold order)."""
        self.keep_nominal_folds([lane[0] for lane in lanes])
        for i, key in enumerate(todo):
            self._summaries[key] = Summary.of_folds(key, [lane[1 + i] for lane in lanes])
        if self._redraw is not None:
            self._reasons.update(lanes[0][-1])

    def _prefetch_by_fold(self, todo: list) -> None:
        """:meth:`prefetch` on a cold evaluator with no more cores than folds: one worker per
        fold fits that fold's nominal model and then, building on it, the fold of every model
        of ``todo`` (:func:`_by_fold`) — one set of workers instead of one for the nominal
        folds and another, forked once their state has come back, for the models."""
        _by_fold([self], [todo])

    def fold_summary(self, key: frozenset, fold: int) -> FoldSummary:
        """One fold of one model, summarised (a :meth:`map` job)."""
        if key in self._cache:
            return FoldSummary.of(self._cache[key].folds[fold])
        return FoldSummary.of(self._fold(key, fold))

    def warm(self) -> None:
        """Each fold's nominal fit and real motion path, which every model of that fold
        starts from, computed once (both folds at once) before models are spread over
        workers — a worker's own cache dies with it."""
        missing = [fold for fold in FOLDS if fold not in self._motion]
        for entries in self.map([("_warm_fold", (fold,)) for fold in missing]):
            self._motion.update(entries)

    def _warm_fold(self, fold: int) -> dict:
        self._motion_path(fold)
        return {key: self._motion[key] for key in (fold, ("nominal", fold))}

    def _cold(self) -> bool:
        return all(fold not in self._motion for fold in FOLDS)

    def keep_nominal_folds(self, results: list) -> None:
        """Keep the nominal model's summary and each fold's state from the results of
        :meth:`_nominal_fold` jobs (with ``summary`` True), one per fold in order."""
        self._summaries[frozenset()] = Summary.of_folds(frozenset(), [r for r, _ in results])
        for _, state in results:
            self._keep_fold_state(state)

    def _keep_fold_state(self, state: tuple) -> None:
        motion, real_models = state
        self._motion.update(motion)
        self._real_models.update(real_models)

    @property
    def decimates(self) -> bool:
        """Whether the slow effects are scored on block means (a session faster than
        :data:`~apmcal.diagnosis.session.decimate.SLOW_RATE_HZ`), by :attr:`slow`."""
        return block_factor(self.session.fs) > 1

    @cached_property
    def slow(self) -> "Evaluator":
        """The evaluator of this session's block means, where the slow effects are scored
        (:mod:`apmcal.diagnosis.session.decimate`); this one itself when the session is not faster
        than that. Made once, in this process, so that forked workers inherit it."""
        if not self.decimates:
            return self
        k = block_factor(self.session.fs)
        twin = decimated(self.twin, k) if self.twin is not None else None
        return Evaluator(decimated(self.session, k), self.seed, twin=twin).facts()

    def _slow_nominal_fold(self, fold: int) -> tuple:
        """:meth:`_nominal_fold` of :attr:`slow` (a job: workers call methods of this one)."""
        return self.slow._nominal_fold(fold, True)

    def _nominal_fold(self, fold: int, summary: bool) -> tuple:
        """Fold ``fold`` of the nominal model (its summary, or all of it but the residual
        coefficients) and the fold's state its fit gives on the way: what warming the fold
        keeps, and the real data's fit (:meth:`_real_model`), which the models of the noise
        alone reuse — made in a worker, both would otherwise die with it."""
        result = self._fold(frozenset(), fold)
        result = FoldSummary.of(result) if summary else replace(result, real=None, twin=None)
        real_models = {key: value for key, value in self._real_models.items()
                       if not key[0] and key[1] == fold}
        return result, (self._warm_fold(fold), real_models)

    def map(self, jobs: list[tuple[str, tuple]]) -> list:
        """``[self.method(*args) for method, args in jobs]``, spread over every core
        (:func:`apmcal.diagnosis.compute.workers.run`), or over the workers kept per fold
        (:meth:`workers_kept`) when every job is one fold's."""
        self.facts()
        if not jobs:
            return []
        if self._kept is not None and all(_fold_of(job) is not None for job in jobs):
            return self._kept.run(jobs, _fold_of)
        return workers.run(self, jobs)

    @property
    def kept(self) -> bool:
        """Whether workers are kept per fold for this evaluator now (:meth:`workers_kept`)."""
        return self._kept is not None

    @contextlib.contextmanager
    def workers_kept(self):
        """Within it, :meth:`map` runs each fold's jobs in a worker of that fold forked once
        (:func:`apmcal.diagnosis.compute.workers.per_fold`), not in workers forked anew for
        each call: for an evaluator whose many models are each a little work (the block
        means'), where workers forked per call spent as much on starting cold as on the
        models."""
        self.facts()
        self.warm()
        with workers.per_fold(self, FOLDS) as kept:
            self._kept = kept
            try:
                yield self
            finally:
                self._kept = None

    def gap_of(self, effects) -> dict:
        """The model's gaps with their breakdowns (:func:`apmcal.diagnosis.scoring.breakdown.
        gap_summary`; small enough to send back from a worker, unlike the evaluation)."""
        from apmcal.diagnosis.scoring.breakdown import gap_summary

        return gap_summary(self.evaluate(effects), self.session)

    def noise_structure(self, parts=None) -> dict:
        """White noise, bias instability and random walk of the nominal model's hold
        residuals, real and twin (:mod:`apmcal.diagnosis.noise.structure`; of the (sensor,
        axis) pairs ``parts`` only, when given)."""
        from apmcal.diagnosis.noise.structure import noise_structure

        return noise_structure(self.evaluate(()), self.fs_of, parts)

    def evaluate(self, effects) -> Evaluation:
        """The model nominal + ``effects`` scored both ways round (cached): fold 0 here, fold 1
        beside it in a worker, which sends back all of it but the residual coefficients (the
        plots and the noise structure read fold 0's only)."""
        return self.evaluate_with(effects, [])[0]

    def evaluate_with(self, effects, jobs: list, then=None, meanwhile=None) -> tuple:
        """:meth:`evaluate`, with ``jobs`` (as for :meth:`map`) in the same workers, queued
        behind its fold 1; returns (``then(evaluation)``, here as soon as the evaluation is
        complete while the jobs may still run — the evaluation itself by default —, the jobs'
        results). ``meanwhile()`` is called here once fold 0 is done, while fold 1 may still
        run."""
        then = then or (lambda evaluation: evaluation)
        meanwhile = meanwhile or (lambda: None)
        key = frozenset(effects)
        self.facts()
        if key in self._cache:
            def done():
                meanwhile()
                return then(self._cache[key])

            return workers.beside(self, jobs, done) if jobs else (done(), [])
        # on a cold evaluator the nominal model's folds are what warm it (one fit for both)
        cold_nominal = not key and self._cold()
        if not cold_nominal:
            self.warm()
        fold_1 = ("_nominal_fold", (1, False)) if cold_nominal else \
            ("_fold_without_coefficients", (key, 1))

        def both_folds(result):
            first = self._fold(key, 0)
            meanwhile()
            second = result(0)
            if cold_nominal:
                second, state = second
                self._keep_fold_state(state)
            self._cache[key] = Evaluation(key, [first, second])
            return then(self._cache[key])

        out, results = workers.beside(self, [fold_1] + list(jobs), both_folds, hand_over=True)
        return out, results[1:]

    def _fold_without_coefficients(self, key: frozenset, fold: int) -> FoldResult:
        result = self._fold(key, fold)
        return replace(result, real=None, twin=None)

    def _fold(self, effects, fold: int) -> FoldResult:
        s = self.session
        fit, noise, real = self.fit(s, self.reduced, effects, fold, with_sigma=True)
        if not effects:     # the fold's nominal fit: its motion path starts here (no refit)
            self._motion.setdefault(("nominal", fold), (fit, noise))
        if self.twin is not None:       # a recording: the same one for every model
            _, _, tw = self.fit(self.twin, self._twin_reduced, effects, fold, start=fit,
                                with_noise=False)
        else:
            # the same twin noise for every model (common random numbers): differences between
            # models are not drowned in differences between noise draws
            twin, _ = simulate(s, fit, noise, seed=self.seed + fold,
                               motion_path=self._motion_path(fold))
            _, _, tw = self.fit(twin, reduce_session(twin), effects, fold, start=fit,
                                with_noise=False)
        train, test = s.pieces.select(fold=fold), s.pieces.select(fold=1 - fold)
        return FoldResult(fold, fit, noise, real, tw,
                          compare(real, tw, train, in_sample=True, floors=self.floors),
                          compare(real, tw, test, in_sample=False, floors=self.floors),
                          {name: effect_params(name, fit, noise) for name in effects})


_FOLD_ARGUMENT = {"fold_summary": 1, "_nominal_fold": 0, "_warm_fold": 0, "_null_fold": 2}


def _fold_of(job: tuple) -> int | None:
    """The fold a job of :meth:`Evaluator.map` computes (None: not one fold's)."""
    method, args = job
    at = _FOLD_ARGUMENT.get(method)
    return None if at is None else args[at]


class _Cold:
    """Several cold evaluators, each with the models to prefetch on it, as one target of
    forked workers (:func:`prefetch_cold`)."""

    def __init__(self, evaluators: list, todos: list):
        self.evaluators, self.todos = evaluators, todos

    def lane(self, fold: int) -> list:
        """Each evaluator's :meth:`Evaluator._cold_lane` of ``fold``, one after the other."""
        return [ev._cold_lane(fold, todo) for ev, todo in zip(self.evaluators, self.todos)]


def prefetch_cold(work: list) -> None:
    """:meth:`Evaluator.prefetch` of several cold evaluators — null sessions
    (:mod:`apmcal.diagnosis.scoring.null`) — at once; ``work``: (evaluator, models) pairs, the
    nominal model among each one's models.

    On no more cores than folds, one worker per fold fits that fold of every evaluator, one
    evaluator after the other (:meth:`Evaluator._cold_lane`): one pair of workers for all of
    them instead of a pair per evaluator, each of which would start cold again (a forked
    worker faults its memory in and fills its caches anew). The same numbers: every fold's
    computation is the same wherever it runs."""
    work = [(ev, [frozenset(m) for m in models]) for ev, models in work]
    if len(work) < 2 or not workers.parallel() or (os.cpu_count() or 1) > len(FOLDS) or \
            any(not ev._cold() or frozenset() not in models for ev, models in work):
        for ev, models in work:     # one at a time: a null session shed before the next
            ev.prefetch(models)
            if ev._redraw is not None:
                ev.reasons()
                ev.shed()
        return
    _by_fold([ev for ev, _ in work], [_slowest_first(m for m in models if m)
                                      for _, models in work])


def _by_fold(evaluators: list, todos: list) -> None:
    """Cold ``evaluators`` each warmed by its nominal model and then given the summaries of
    its models ``todos[i]``, by one worker per fold: each worker fits its fold of every
    evaluator, one after the other (:meth:`Evaluator._cold_lane`). The same numbers: every
    fold's computation is the same wherever it runs."""
    for ev in evaluators:
        if ev._redraw is None:      # a null session is drawn in the workers, not here
            ev.facts()
    lanes = workers.run_lanes(_Cold(evaluators, todos), [[("lane", (fold,))] for fold in FOLDS])
    for i, (ev, todo) in enumerate(zip(evaluators, todos)):
        ev._keep_lanes(todo, [lane[0][i] for lane in lanes])


def _slowest_first(models) -> list:
    """The distinct models (frozensets of effects), the slowest to fit first: then the last
    jobs are short ones and no core waits long for the other (longest-processing-time-first
    scheduling)."""
    todo = list(dict.fromkeys(frozenset(m) for m in models))
    todo.sort(key=lambda key: -len(key & SLOW_TO_FIT))
    return todo
