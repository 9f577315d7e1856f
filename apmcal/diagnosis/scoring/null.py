"""Significance calibrated under the null, by simulation: what chance alone gives each candidate.

A candidate's held-out evidence (:mod:`apmcal.diagnosis.scoring.select`) is a cross-validated
likelihood ratio, but what it reaches by chance depends on the candidate (how many parameters
it fits, how they trade with the nominal ones) and on the session (its length, motion and
noise): one fixed threshold is too strict for some and too loose for others. The twin is a
generative model, so the null distribution can be drawn rather than assumed — a parametric
bootstrap [Efron] ch. 6:

1. *Null sessions*: the real session's sample times, poses, moves, temperatures and current,
   with the sensor readings drawn afresh from the **fitted nominal model** (its errors and
   noise, formatted as the log formats them), the two folds' nominal fits taking turns
   (:meth:`~apmcal.diagnosis.scoring.evaluate.Evaluator.model_draw`). Each is a session in which
   no candidate effect exists.
2. Each null session is scored **exactly as the real one**: a fresh evaluator fits the nominal
   model and the candidate on top of the same base, simulates their twins (with the real
   scoring's twin seeds) and scores them held-out; the evidence is a draw of that candidate's
   null distribution on this very session.
3. The p-value of the real evidence e is the upper tail of the predictive distribution of one
   more null draw, a Student t with B − 1 degrees of freedom around the draws' mean m with scale
   s·√(1 + 1/B) ([Geisser] §2.1: the prediction interval of a normal sample whose mean and
   variance are both estimated), and never below the draws' own rank p-value
   (1 + #{draws ≥ e}) / (B + 1) [Besag]. A candidate is supported only when p < α / M, the
   M candidates tested on the session sharing the family-wise false-alarm rate α = 5 %
   (Bonferroni).

Only candidates that pass the other tests (evidence ≥ 15 nats, plausible parameters, the Wald
test) need the null: the others are not supported whatever it says. And only where a decision
turns on it: :class:`Calibration` draws a candidate's null sessions when the stepwise selection
first asks for its threshold, so that a candidate the selection explains first (supported
alone, but adding nothing on top of the effects chosen) costs none. Draws stop early, per
candidate, once the decision is plain (p below α/M/``DECISIVE`` or above ``DECISIVE``·α/M
after ``MIN_DRAWS`` draws) [Besag]: an effect with thousands of nats of evidence needs the
fewest. The resulting evidence threshold of each candidate (the evidence at which p = α/M) is
also what it must reach on top of other effects in the stepwise selection; and the effect a
round of that selection is about to add to a combination is tested once more, against
sessions drawn from that combination itself (:func:`on_top`): a random walk's one realisation
can pass for a triangle drift on top of it, which the nominal model's null cannot show.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import stdtr, stdtrit

from apmcal.diagnosis.scoring.evaluate import Evaluator, prefetch_cold
from apmcal.diagnosis.scoring.select import score, testable

ALPHA = 0.05            # family-wise false-alarm rate per session
MIN_DRAWS = 3           # null sessions every calibrated candidate gets
MAX_DRAWS = 12          # ... at most
DECISIVE = 5.0          # p this far from α/M (either way) stops the draws for a candidate
MIN_SPREAD_NATS = 0.5   # floor of the null draws' standard deviation [nats]: a candidate
                        # whose draws happen to agree closely is not made infinitely sharp


@dataclass
class NullDraws:
    """One candidate's evidence in each null session [nats] and what follows from it.

    Attributes
    ----------
    name : str
    evidence : list of float
        The candidate's held-out evidence in each null session [nats] (NaN: not testable
        there).
    family : int
        Candidates tested on the session (M): the test is at level α / M.
    """

    name: str
    evidence: list = field(default_factory=list)
    family: int = 1

    @property
    def level(self) -> float:
        """α / M: the p-value a supported candidate must stay below."""
        return ALPHA / max(self.family, 1)

    def _finite(self) -> np.ndarray:
        e = np.asarray(self.evidence, float)
        return e[np.isfinite(e)]

    def _spread(self) -> tuple[float, float, int]:
        e = self._finite()
        b = len(e)
        sd = max(float(np.std(e, ddof=1)) if b > 1 else np.inf, MIN_SPREAD_NATS)
        return float(np.mean(e)) if b else np.nan, sd * np.sqrt(1.0 + 1.0 / max(b, 1)), b

    def p_value(self, real_evidence: float) -> float | None:
        """P(a null draw ≥ ``real_evidence``) (module docstring, step 3); None when fewer than
        two null sessions could test the candidate."""
        mean, scale, b = self._spread()
        if b < 2 or not np.isfinite(real_evidence):
            return None
        predictive = float(1.0 - stdtr(b - 1, (real_evidence - mean) / scale))
        reached = int(np.sum(self._finite() >= real_evidence))
        # a null draw at or above the real evidence: the draws' own rank says more than the
        # normal tail, which a skewed null would understate
        return max(predictive, (1.0 + reached) / (b + 1.0)) if reached else predictive

    def threshold(self) -> float | None:
        """The evidence [nats] at which the p-value is α / M (None: no null to go by)."""
        mean, scale, b = self._spread()
        if b < 2:
            return None
        return float(mean + scale * stdtrit(b - 1, 1.0 - self.level))

    def decided(self, real_evidence: float) -> bool:
        """Whether more draws could hardly change the decision."""
        p = self.p_value(real_evidence)
        if p is None:
            return len(self.evidence) >= MIN_DRAWS
        return len(self._finite()) >= MIN_DRAWS and (p < self.level / DECISIVE
                                                     or p > self.level * DECISIVE)


def _draw(draws: dict, real: dict, session_of, base: tuple, say=None, fetch=None) -> None:
    """Score the undecided candidates of ``draws`` ({name: NullDraws}) on null session after
    null session (``session_of(k)``: the k-th one's evaluator, the same one for the same k),
    each until its decision against its real evidence ``real[name]`` is plain.
    ``fetch(work)`` fits the models of several null sessions at once (``work``: (k, models)
    pairs); by default :func:`~apmcal.diagnosis.scoring.evaluate.prefetch_cold`."""
    def models(k: int, pending: list) -> list:
        return [base] + [base + (n,) for n in testable(session_of(k), pending)]

    fetch = fetch or (lambda work: prefetch_cold([(session_of(k), m) for k, m in work]))
    for draw in range(MAX_DRAWS):
        pending = [n for n, d in draws.items() if not d.decided(real[n])]
        if not pending:
            return
        if say:
            say(f"null session {draw + 1} ({', '.join(pending)})")
        if draw == 0 or draw >= MIN_DRAWS:     # the first MIN_DRAWS, which every candidate
            ahead = range(MIN_DRAWS) if draw == 0 else [draw]   # needs, fitted all at once
            fetch([(k, models(k, pending)) for k in ahead])
        null_ev = session_of(draw)
        names = testable(null_ev, pending)
        for n in pending:
            draws[n].evidence.append(score(null_ev, base, n).evidence if n in names
                                     else float("nan"))
        null_ev.shed()      # its summaries stay; the rest is drawn again if needed


def calibrate(evaluator, ranked: list, family: int, base: tuple = (), say=None,
              drawn_from: tuple = ()) -> dict:
    """The null draws of every candidate of ``ranked`` that is supported so far, at once.

    Parameters
    ----------
    evaluator : Evaluator
        The evaluator the candidates are scored by: the null sessions are drawn from its fit
        of the nominal model plus ``drawn_from``, at its rate.
    ranked : list of EffectScore
        The candidates scored alone on the real session (on top of ``base``).
    family : int
        Candidates tested on the session in all (M).
    base : tuple of str
        Effects every model of this stage includes (the same as on the real session).
    say : callable, optional
        Progress text.
    drawn_from : tuple of str
        The effects of the model the null sessions are drawn from, on top of the nominal
        ones (none: the nominal model).

    Returns
    -------
    dict of str to NullDraws
    """
    real = {s.name: s.evidence for s in ranked if s.supported}
    draws = {name: NullDraws(name, [], family) for name in real}
    sessions = _Sessions(evaluator, tuple(drawn_from))
    _draw(draws, real, sessions, tuple(base), say, sessions.fetch())
    return draws


class _Sessions:
    """The null sessions drawn from ``evaluator``'s model nominal + ``drawn_from``: called
    with k, the k-th one's evaluator (made on first use, the same one after)."""

    def __init__(self, evaluator, drawn_from: tuple = ()):
        self.evaluator, self.drawn_from = evaluator, drawn_from
        self._made: dict[int, Evaluator] = {}

    def __call__(self, k: int) -> Evaluator:
        if k not in self._made:
            self._made[k] = self.evaluator.null_evaluator(self.drawn_from, k)
        return self._made[k]

    def fetch(self):
        """How :func:`_draw` fits them: in the workers ``evaluator`` keeps per fold when it
        has them (:meth:`~apmcal.diagnosis.scoring.evaluate.Evaluator.prefetch_nulls`), else
        the default (None)."""
        if not self.evaluator.kept:
            return None
        return lambda work: self.evaluator.prefetch_nulls(
            [(self.drawn_from, k, self(k), models) for k, models in work])


class Calibration:
    """One stage's null calibration, drawn on first need.

    The selection (:mod:`apmcal.diagnosis.scoring.select`) asks for a candidate's threshold
    only where a decision turns on it: where the candidate's evidence reaches
    ``MIN_EVIDENCE_NATS`` with its other tests passed, in a round of the selection or on top
    of the final combination. Only then are its null sessions drawn: a candidate the selection
    explains before that never needs them (on a warm-up, the candidates supported alone are
    explained by the temperature drift: only that one is drawn for). What it gets when it does
    is what :func:`calibrate` would have given it: the same null sessions, the same draws. The null
    sessions are kept, so that a candidate calibrated later is scored on sessions whose
    nominal fits are done.

    Parameters
    ----------
    evaluator : Evaluator
        The evaluator the candidates are scored by (the session's, or its block means'
        :attr:`~apmcal.diagnosis.scoring.evaluate.Evaluator.slow`): the null sessions are drawn
        from its nominal fit, at its rate, and it keeps the thresholds
        (``evaluator.min_evidence``).
    ranked : list of EffectScore
        The candidates scored alone on the real session (on top of ``base``): each one's
        p-value, threshold and support are filled in when it is calibrated.
    family : int
        Candidates tested on the session in all (M).
    base : tuple of str
        As for :func:`calibrate`.
    say : callable, optional
        Progress text: "null sessions for NAME", each null session, then ``within`` again.
    within : str
        The stage of the diagnosis the null sessions are drawn in (announced again after
        them).
    """

    def __init__(self, evaluator, ranked: list, family: int, base: tuple = (), say=None,
                 within: str = ""):
        self.evaluator, self.family = evaluator, family
        self.alone = {s.name: s for s in ranked}
        self.base = tuple(base)
        self.say = say or (lambda _text: None)
        self.within = within
        self.draws: dict[str, NullDraws] = {}
        self._sessions = _Sessions(evaluator)

    def calibrated(self, name: str) -> NullDraws:
        """``name``'s null draws, drawn now when not yet, and its entry in ``ranked``
        updated with them (:func:`apply`)."""
        if name not in self.draws:
            alone = self.alone[name]
            draws = {name: NullDraws(name, [], self.family)}
            self.say(f"null sessions for {name}")
            _draw(draws, {name: alone.evidence}, self._sessions, self.base, self.say,
                  self._sessions.fetch())
            self.say(self.within)
            self.draws[name] = draws[name]
            apply(alone, draws[name], self.evaluator)
        return self.draws[name]


def on_top(evaluator, model: tuple, trial) -> NullDraws | None:
    """The null draws of ``trial`` (an EffectScore of a candidate scored on top of
    ``model``, a tuple of effects) on sessions drawn from ``model`` itself: what chance gives
    it where the effects already chosen exist (a random walk's one realisation can pass for a
    triangle drift on top of it; the nominal model's null cannot say so). None when the
    evaluator's candidates are not calibrated (it has no :class:`Calibration`).

    Returns
    -------
    NullDraws or None
    """
    if evaluator.chance is None:
        return None
    model = tuple(model)
    return calibrate(evaluator, [trial], evaluator.chance.family, base=model,
                     drawn_from=model)[trial.name]


def chance_on_top(evaluator, model: tuple, trial) -> float | None:
    """The p-value of ``trial`` against sessions drawn from ``model`` (:func:`on_top`) when
    chance gives it as much there — it must not join ``model`` — else None. On top of nothing
    the nominal model's null has judged it already."""
    if not model:
        return None
    draws = on_top(evaluator, model, trial)
    if draws is None:
        return None
    p = draws.p_value(trial.evidence)
    return p if p is not None and p >= draws.level else None


def apply(candidate, draws: NullDraws, evaluator) -> None:
    """Fill in ``candidate``'s (an EffectScore scored alone) p-value and threshold from its
    null ``draws``: it stays supported only when its p-value is below α / M, and its threshold
    is set on ``evaluator`` (what the stepwise selection then asks of it)."""
    candidate.null_draws = int(np.sum(np.isfinite(draws.evidence)))
    candidate.null_p_value = draws.p_value(candidate.evidence)
    candidate.null_threshold = draws.threshold()
    if candidate.null_p_value is None:     # no null session could test it: the other tests rule
        return
    candidate.supported = bool(candidate.supported and candidate.null_p_value < draws.level)
    evaluator.min_evidence[candidate.name] = candidate.null_threshold
