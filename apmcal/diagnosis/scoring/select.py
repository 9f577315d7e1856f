"""Which unmodelled effect explains the gap: each candidate scored alone, then a combination.

Each applicable effect is added to the nominal model and scored held-out
(:mod:`apmcal.diagnosis.scoring.evaluate`). Its *shrink* is 1 − gap_after / gap_before, and its
*evidence* the held-out gap it removes in total, in nats: the log of how many times better the
model with the effect predicts the held-out data than the one without (the gap is a
log-likelihood ratio, so this is a cross-validated likelihood ratio, an information criterion
that needs no parameter count: overfitting is already paid for on the held-out side). An
effect is *supported* when its evidence reaches ``MIN_EVIDENCE_NATS`` — odds of e^15, over
three million to one. On simulated sessions without any extra effect the evidence of a useless
candidate stays within a few nats (its parameters fit noise in the real data and in the twin
alike); among 12 such sessions at 100 Hz (seeds 201-212, none of the benchmark's) the largest
was 12.2 nats (a gyro random walk), which is what the threshold is set against (``python -m
apmcal_sim.gap_benchmark`` measures the false alarms on other seeds). Held-out evidence alone let a model
with many parameters through by chance (gyro scale and misalignment, 18 nats with every value
within 2σ of "off" on one benchmark seed), hence the Wald test as well. No share of the gap is
asked for, because a real effect can sit under a much larger one and remove only a sliver of
the total until that one is modelled.

Stepwise selection then adds, round after round, the supported effect with the most evidence
on top of those already chosen, for as long as one reaches the threshold, and drops an earlier
one that the later ones explain. The simplest sufficient explanation is preferred: a stochastic
effect (a random walk, which bends to any slow curve) is chosen over a deterministic one only
when it has :data:`SIMPLER_SHARE` more evidence, and is removed again when it takes a
deterministic effect's place while adding less than that share of what the deterministic one
explained; and of two confounded effects
(:data:`CONFOUNDED`: a bias following the temperature, one following time) one that adds nothing
where the two shapes part while the other does is left out (:func:`confounded_effects`).
An effect is *significant* in the end when it is in that
combination or still supported on top of it, and the combination is ranked by what it loses
without each of its effects. An effect whose fitted parameters lie beyond physical limits
(:mod:`apmcal.diagnosis.model.plausible`) is never supported, whatever its evidence: it stands in for
something else; nor is one whose parameters are all within their noise of the values that
switch it off (:mod:`apmcal.diagnosis.model.wald`). Nor, last, is one whose evidence chance gives
it on this very session: each candidate that passes the tests above is scored on sessions drawn
from the fitted nominal model (:mod:`apmcal.diagnosis.scoring.null`) when a decision first turns
on it, which set the evidence it must reach (:func:`required_evidence`, never below
``MIN_EVIDENCE_NATS``; :func:`beyond_chance` asks for it), and the effect a
round is about to add is checked against sessions drawn from the combination it would join
(the ``chance_on_top`` the caller hands :func:`forward_selection`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.diagnosis.model.effects import NAMES
from apmcal.diagnosis.model.plausible import implausible
from apmcal.diagnosis.model.wald import MAX_P_VALUE, wald_p_value

MIN_EVIDENCE_NATS = 15.0    # held-out log-likelihood ratio an effect must reach
MAX_ROUNDS = 5              # effects in a combination at most
# a stochastic effect can stand in for any slow deterministic one (a random walk bends to a
# triangle or a warm-up curve): it is chosen only when no deterministic candidate comes within
# this share of its evidence, and otherwise has to earn its place on top of that one
STOCHASTIC = frozenset({"bias_random_walk"})
SIMPLER_SHARE = 0.05
# effects whose shapes in a still recording are confounded: a bias following the temperature
# and biases following time (both rise during a warm-up); each must hold where they disagree
CONFOUNDED = ("temperature_drift", "bias_drift", "triangle_drift")


@dataclass
class EffectScore:
    """One candidate scored against a base model (held-out numbers are what rank it).

    Attributes
    ----------
    name : str
    reason : str or None
        Why it could not be tested (None: it was).
    gap_in, gap_out : float
        In-sample and held-out gap of the base model plus the effect [nats per sample].
    shrink_in, shrink_out : float
        1 − gap_after / gap_before, in-sample and held-out.
    evidence : float
        Held-out gap removed [nats].
    supported : bool
        Evidence ≥ ``MIN_EVIDENCE_NATS``, plausible, its parameters away from "off", and its
        evidence beyond its null threshold when that is known (:func:`required_evidence`).
    params : dict
        Its fitted parameters (mean of the folds).
    implausible : str or None
        Why the fitted parameters cannot be this effect.
    p_value : float or None
        Wald test of the parameters (None: not testable).
    rate_hz : float
        Sample rate it was scored at [Hz].
    null_p_value : float or None
        Probability of this much evidence by chance on this session, from the null sessions
        (:mod:`apmcal.diagnosis.scoring.null`; None: not calibrated, no decision turned on
        it — the other tests refuse it, or the selection explains it first).
    null_threshold : float or None
        The evidence it must reach [nats]: its null distribution's 1 − α/M quantile.
    null_draws : int
        Null sessions it was scored on.
    """

    name: str
    reason: str | None = None            # why it could not be tested (None: it was)
    gap_in: float = float("nan")
    gap_out: float = float("nan")
    shrink_in: float = float("nan")
    shrink_out: float = float("nan")
    evidence: float = float("nan")       # held-out gap removed [nats]
    supported: bool = False              # evidence ≥ MIN_EVIDENCE_NATS, plausible, and
                                         # its parameters away from "off" (Wald p)
    params: dict = field(default_factory=dict)
    implausible: str | None = None       # why the fitted parameters cannot be this effect
    p_value: float | None = None         # Wald test of the parameters (None: not testable)
    rate_hz: float = float("nan")        # sample rate it was scored at (the recording's, or
                                         # lower for a slow effect: apmcal.diagnosis.session.decimate)
    null_p_value: float | None = None    # P(evidence this large by chance), from null sessions
    null_threshold: float | None = None  # evidence it must reach [nats] (its null's quantile)
    null_draws: int = 0                  # null sessions it was scored on

    @property
    def tested(self) -> bool:
        """Whether it was tested (applicable to the session)."""
        return self.reason is None


def shrink(before: float, after: float) -> float:
    """1 − after / before (NaN when there was no gap to shrink).

    Parameters
    ----------
    before, after : float
        Gap without and with the effect [nats per sample].

    Returns
    -------
    float
    """
    return 1.0 - after / before if before > 0 else float("nan")


def score(evaluator, base: tuple, name: str, draw: bool = True) -> EffectScore:
    """Effect ``name`` added to ``base``, scored against ``base`` alone; ``draw`` False: its
    support judged without drawing null sessions for it (:func:`required_evidence`), as
    :func:`beyond_chance` then does for the trial a decision turns on."""
    reason = evaluator.reason(name)
    if reason:
        return EffectScore(name, reason)
    before, after = evaluator.summary(base), evaluator.summary(base + (name,))
    evidence = before.nats_out - after.nats_out
    params = after.params.get(name, {})
    why = implausible(name, params) if np.isfinite(evidence) else "its fit diverged"
    p = wald_p_value(name, params)
    # the null calibration's threshold last: it may draw null sessions, which only a candidate
    # that passes every other test needs
    supported = why is None and (p is None or p < MAX_P_VALUE) and \
        evidence >= MIN_EVIDENCE_NATS and evidence >= required_evidence(evaluator, name, draw)
    return EffectScore(name, None, after.gap_in, after.gap_out,
                       shrink(before.gap_in, after.gap_in), shrink(before.gap_out, after.gap_out),
                       evidence, bool(supported), params, why, p, evaluator.session.fs)


def required_evidence(evaluator, name: str, draw: bool = True) -> float:
    """The evidence [nats] candidate ``name`` must reach on ``evaluator``'s session:
    ``MIN_EVIDENCE_NATS``, or its null distribution's quantile when that is higher
    (:mod:`apmcal.diagnosis.scoring.null`). With ``draw``, the evaluator's null calibration
    (``evaluator.chance``, when it has one) draws the candidate's null sessions now if it has
    not yet; without, only a threshold already drawn counts."""
    if draw and evaluator.chance is not None:
        evaluator.chance.calibrated(name)
    return max(MIN_EVIDENCE_NATS, evaluator.min_evidence.get(name, -np.inf))


def beyond_chance(evaluator, trial: EffectScore) -> bool:
    """Whether ``trial`` (scored with ``draw`` False) is supported once its null threshold is
    known: drawn now when not yet (the selection asks this only of the trials a decision turns
    on)."""
    return trial.supported and trial.evidence >= required_evidence(evaluator, trial.name)


def rank(scores: list[EffectScore]) -> list[EffectScore]:
    """Supported effects first, each group by evidence, untestable last.

    On one base model evidence orders the effects as their held-out shrink does (both are the
    held-out gap removed), and it stays defined when the base gap is zero or below (the
    expectation of two draws of one process is subtracted, so a small gap can be negative)."""
    def key(s: EffectScore):
        return (not s.supported, not s.tested,
                -(s.evidence if np.isfinite(s.evidence) else -np.inf))
    return sorted(scores, key=key)


def candidates(names=None) -> tuple:
    """The candidate effects: ``names``, or every one when None."""
    return tuple(NAMES if names is None else names)


def testable(evaluator, names) -> list[str]:
    """Those of ``names`` the evaluator's session can test."""
    return [n for n in names if not evaluator.reason(n)]


def rank_effects(evaluator, names=None, base: tuple = ()) -> list[EffectScore]:
    """Every candidate alone on top of the nominal model (and of ``base``, effects already
    chosen at another rate), ranked."""
    names, base = candidates(names), tuple(base)
    evaluator.prefetch([base] + [base + (n,) for n in testable(evaluator, names)])
    return rank([score(evaluator, base, n) for n in names])


@dataclass
class Selection:
    """The stepwise combination and what each supported effect adds to it [nats].

    Attributes
    ----------
    selected : list of str
        The combination, in the order added.
    joined : dict of str to float
        Evidence of each selected effect in the round it was added [nats].
    beyond : dict of str to float
        Evidence each other supported effect still has on top of the final combination
        [nats].
    needed : dict of str to float
        Evidence of each selected effect given all the others [nats].
    confounded : dict of str to str
        Effects supported alone but left out of the selection because another effect of
        :data:`CONFOUNDED` explains them where the two disagree (:func:`confounded_effects`).
    stand_in : dict of str to str
        Stochastic effects removed because they took a deterministic effect's place instead of
        adding to it, with that effect.
    required : dict of str to float
        The evidence each candidate must reach [nats] (:func:`required_evidence`).
    chance : dict of str to float
        Effects left out because sessions drawn from the combination they were to join gave
        them as much evidence by chance, with that p-value
        (:func:`apmcal.diagnosis.scoring.null.on_top`).
    """

    selected: list[str]
    joined: dict[str, float]      # evidence of each selected effect in the round it was added
    beyond: dict[str, float]      # evidence each other supported effect still has on top of
                                  # the final combination (below the threshold unless the
                                  # rounds ran out)
    needed: dict[str, float] = field(default_factory=dict)   # evidence each selected effect
                                  # has given all the others: what the combination loses
                                  # without it
    confounded: dict[str, str] = field(default_factory=dict)  # effect -> the confounded one
                                  # that explains it where the two disagree (left out)
    stand_in: dict[str, str] = field(default_factory=dict)    # stochastic effect -> the
                                  # deterministic one whose place it took (removed)
    required: dict[str, float] = field(default_factory=dict)  # evidence each candidate must
                                  # reach, where its null set it above MIN_EVIDENCE_NATS
    chance: dict[str, float] = field(default_factory=dict)    # effect -> its p-value on top
                                  # of the combination it was to join, when chance gave as
                                  # much there (left out)

    def significant(self, name: str) -> bool:
        """Part of the combination, or still supported on top of it (a stochastic effect
        removed as a stand-in never is)."""
        if name in self.stand_in or name in self.confounded or name in self.chance:
            return name in self.selected
        return name in self.selected or \
            self.beyond.get(name, -np.inf) >= self.required.get(name, MIN_EVIDENCE_NATS)

    def order(self) -> list[str]:
        """The combination, the effect it needs most first."""
        return sorted(self.selected, key=lambda n: -self.needed.get(n, np.inf))


def forward_selection(evaluator, ranked: list[EffectScore], max_rounds: int = MAX_ROUNDS,
                      base: tuple = (), chance_on_top=None) -> Selection:
    """Stepwise selection among the effects supported alone (module docstring). Every round
    scores each remaining one on top of the current combination and adds the best; then an
    effect added earlier that the later ones explain (no longer supported given all the others:
    a random walk standing in for a temperature drift and a g-sensitivity together) is dropped
    for good. The last round says what each effect left out would still add. ``base``: effects
    already chosen (at another rate, :mod:`apmcal.diagnosis.session.decimate`), part of every model and
    not questioned here. ``chance_on_top(evaluator, model, trial)``, when given, says whether
    chance gives the effect about to join ``model`` as much evidence there (its p-value, or
    None when not: :func:`apmcal.diagnosis.scoring.null.chance_on_top`); such an effect does
    not join."""
    base = tuple(base)
    alone = {s.name: s for s in ranked}     # a null calibration drawn on the way may refuse
                                            # one of them alone: it leaves the pool
    confounded = confounded_effects(evaluator, ranked, base)
    pool = [s.name for s in sorted((s for s in ranked if s.supported and s.name not in confounded),
                                   key=lambda s: -s.evidence)]
    selected: list[str] = []
    joined: dict[str, float] = {}
    dropped: list[str] = []
    stand_in: dict[str, str] = {}
    chance: dict[str, float] = {}
    beyond: dict[str, float] = {}
    # each effect is added once and dropped at most once, or refused once by either null
    for _ in range(2 * max_rounds + 1 + 2 * len(pool)):
        others = [n for n in pool if n not in selected and alone[n].supported]
        evaluator.prefetch([base + tuple(selected) + (n,) for n in others])
        trials = [score(evaluator, base + tuple(selected), n, draw=False) for n in others]
        beyond = {s.name: s.evidence for s in trials}
        best = simplest_best([s for s in trials if s.name not in dropped],
                             lambda s: beyond_chance(evaluator, s))
        if best is not None and best.name in STOCHASTIC:
            best = drifts_together(evaluator, base + tuple(selected),
                                   [s for s in trials if s.name not in dropped], best) or best
        supported = best is not None and beyond_chance(evaluator, best)
        if any(not alone[s.name].supported for s in trials):
            continue        # refused alone by its null, drawn just now: the round again without
        if not supported or len(base) + len(selected) >= max_rounds:
            break
        p = chance_on_top(evaluator, base + tuple(selected), best) if chance_on_top else None
        if p is not None:
            chance[best.name] = p
            dropped.append(best.name)
            continue
        selected.append(best.name)
        joined[best.name] = best.evidence
        weakest = weakest_unsupported(evaluator, selected, base)
        if weakest is not None and best.name in STOCHASTIC and weakest not in STOCHASTIC \
                and best.evidence < SIMPLER_SHARE * joined[weakest]:
            # a stochastic effect that takes a deterministic one's place while adding less
            # than SIMPLER_SHARE of what that one explained is standing in for it: it goes,
            # the simpler explanation stays
            stand_in[best.name] = weakest
            weakest = best.name
        if weakest is not None:
            selected.remove(weakest)
            joined.pop(weakest)
            dropped.append(weakest)
    # an effect left out with enough evidence on top is significant only beyond its null
    required = {n: required_evidence(evaluator, n,
                                     draw=beyond.get(n, -np.inf) >= MIN_EVIDENCE_NATS)
                for n in pool}
    return Selection(selected, joined, beyond, leave_one_out(evaluator, selected, base),
                     confounded, stand_in, required, chance)


def simplest_best(trials: list[EffectScore], supported=None) -> EffectScore | None:
    """The trial with the most evidence, unless it is stochastic (:data:`STOCHASTIC`) and a
    supported deterministic trial comes within :data:`SIMPLER_SHARE` of its evidence: then the
    best of those (the simplest sufficient explanation; the stochastic one may still join on
    top of it in a later round). ``supported(trial)`` says whether a trial is supported (its
    ``supported`` by default), asked only of those deterministic trials."""
    supported = supported or (lambda s: s.supported)
    best = max(trials, key=lambda s: s.evidence, default=None)
    if best is None or best.name not in STOCHASTIC:
        return best
    simpler = [s for s in trials if s.name not in STOCHASTIC
               and s.evidence >= (1.0 - SIMPLER_SHARE) * best.evidence and supported(s)]
    return max(simpler, key=lambda s: s.evidence) if simpler else best


def drifts_together(evaluator, model: tuple, trials: list[EffectScore],
                    stochastic: EffectScore) -> EffectScore | None:
    """The drift of :data:`CONFOUNDED` to choose before the ``stochastic`` effect, when it and
    a second one on top of it explain within :data:`SIMPLER_SHARE` as much as that (None:
    none do).

    :func:`simplest_best` prefers a deterministic effect that alone comes within that share of
    the random walk; but a random walk bends to the sum of two drifts as well as to one — a
    board warming up under ArduPilot SITL's triangle drift, whose gyro bias follows neither
    the temperature nor the triangle alone — and would stand in for both. Each of ``trials``
    (candidates on top of ``model``) of :data:`CONFOUNDED` is supported alone here; the best
    of them is tried with each other one on top, and chosen when the two together reach
    (1 − SIMPLER_SHARE) of the stochastic effect's evidence: the pair then joins in two
    rounds, and the random walk only after them, on what they leave."""
    drifts = sorted((s for s in trials if s.name in CONFOUNDED and s.supported),
                    key=lambda s: -s.evidence)
    if len(drifts) < 2 or not beyond_chance(evaluator, drifts[0]):
        return None
    first = drifts[0]
    on_first = tuple(model) + (first.name,)
    evaluator.prefetch([on_first + (s.name,) for s in drifts[1:]])
    second = max((score(evaluator, on_first, s.name, draw=False) for s in drifts[1:]),
                 key=lambda s: s.evidence)
    if second.supported and first.evidence + second.evidence >= \
            (1.0 - SIMPLER_SHARE) * stochastic.evidence:
        return first
    return None


def confounded_effects(evaluator, ranked: list[EffectScore], base: tuple = ()) -> dict:
    """Supported effects of :data:`CONFOUNDED` that another one explains where they disagree.

    For each pair (X, Y) of them supported alone, X on top of Y and Y on top of X are scored:
    X is left out when it adds less than the threshold on top of Y while Y still adds at least
    the threshold on top of X — X only held where the two shapes coincide (a temperature that
    rises while a drift rises), Y also where they part.

    Returns
    -------
    dict
        {left-out effect: the effect that explains it}.
    """
    names = [s.name for s in ranked if s.supported and s.name in CONFOUNDED]
    pairs = [(x, y) for x in names for y in names if x != y]
    if not pairs:
        return {}
    base = tuple(base)
    evaluator.prefetch([base + (y,) for y in names])
    out = {}
    for x, y in pairs:
        if x in out or y in out:    # settled: its pair models are not even fitted
            continue
        evaluator.prefetch([base + tuple(sorted((x, y)))])
        if not score(evaluator, base + (y,), x).supported and \
                score(evaluator, base + (x,), y).supported:
            out[x] = y
    return out


def _without(selected: list[str], name: str, base: tuple = ()) -> tuple:
    return tuple(base) + tuple(n for n in selected if n != name)


def leave_one_out(evaluator, selected: list[str], base: tuple = ()) -> dict[str, float]:
    """Evidence of each selected effect on top of all the others (and ``base``) [nats]."""
    evaluator.prefetch([_without(selected, name, base) for name in selected])
    return {name: score(evaluator, _without(selected, name, base), name).evidence
            for name in selected}


def weakest_unsupported(evaluator, selected: list[str], base: tuple = ()) -> str | None:
    """The earlier-selected effect with the least evidence given all the others, when that
    evidence no longer supports it (the one just added is not questioned)."""
    if len(selected) < 2:
        return None
    earlier = selected[:-1]
    evaluator.prefetch([_without(selected, name, base) for name in earlier])
    scores = [score(evaluator, _without(selected, name, base), name) for name in earlier]
    worst = min(scores, key=lambda s: s.evidence)
    return None if worst.supported else worst.name


def merged(slow: Selection, fine: Selection) -> Selection:
    """One selection from the slow effects' and the fine effects' (each made at its own rate)."""
    return Selection(slow.selected + fine.selected, {**slow.joined, **fine.joined},
                     {**slow.beyond, **fine.beyond}, {**slow.needed, **fine.needed},
                     {**slow.confounded, **fine.confounded}, {**slow.stand_in, **fine.stand_in},
                     {**slow.required, **fine.required}, {**slow.chance, **fine.chance})
