"""Which unmodelled effect explains the gap: each candidate scored alone, then a combination.

Each applicable effect is added to the nominal model and scored held-out
(:mod:`apmcal.diagnosis.evaluate`). Its *shrink* is 1 − gap_after / gap_before, and its
*evidence* the held-out gap it removes in total, in nats: the log of how many times better the
model with the effect predicts the held-out data than the one without (the gap is a
log-likelihood ratio, so this is a cross-validated likelihood ratio, an information criterion
that needs no parameter count: overfitting is already paid for on the held-out side). An
effect is *supported* when its evidence reaches ``MIN_EVIDENCE_NATS`` — odds of e^15, over
three million to one. On simulated sessions without any extra effect the evidence of a useless
candidate stays within a few nats (its parameters fit noise in the real data and in the twin
alike); among 12 such sessions (seeds 201-206 and 301-306, none of the benchmark's) the largest
was 13.5 nats, which is what the threshold is set against (``apmcal gap --benchmark``
measures the false alarms on other seeds); no
share of the gap is asked for, because a real effect can sit under a much larger one and
remove only a sliver of the total until that one is modelled. Greedy forward selection then
adds, round after round, the supported effect with the most evidence on top of those already
chosen, for as long as one reaches the threshold.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apmcal.diagnosis.effects import BY_NAME, NAMES, unmet

MIN_EVIDENCE_NATS = 15.0    # held-out log-likelihood ratio an effect must reach
MAX_ROUNDS = 5
MAX_POOL = 6


@dataclass
class EffectScore:
    """One candidate scored against a base model (held-out numbers are what rank it)."""

    name: str
    reason: str | None = None            # why it could not be tested (None: it was)
    gap_in: float = float("nan")
    gap_out: float = float("nan")
    shrink_in: float = float("nan")
    shrink_out: float = float("nan")
    evidence: float = float("nan")       # held-out gap removed [nats]
    significant: bool = False
    params: dict = field(default_factory=dict)

    @property
    def tested(self) -> bool:
        return self.reason is None


def shrink(before: float, after: float) -> float:
    """1 − after / before (NaN when there was no gap to shrink)."""
    return 1.0 - after / before if before > 0 else float("nan")


def score(evaluator, base: tuple, name: str) -> EffectScore:
    """Effect ``name`` added to ``base``, scored against ``base`` alone."""
    reason = unmet(BY_NAME[name], evaluator.session, evaluator.context)
    if reason:
        return EffectScore(name, reason)
    before, after = evaluator.summary(base), evaluator.summary(base + (name,))
    evidence = before.nats_out - after.nats_out
    return EffectScore(name, None, after.gap_in, after.gap_out,
                       shrink(before.gap_in, after.gap_in), shrink(before.gap_out, after.gap_out),
                       evidence, evidence >= MIN_EVIDENCE_NATS)


def rank(scores: list[EffectScore]) -> list[EffectScore]:
    """Supported effects first by held-out shrink, then the rest by shrink, untestable last."""
    def key(s: EffectScore):
        return (not s.significant, not s.tested,
                -(s.shrink_out if np.isfinite(s.shrink_out) else -np.inf))
    return sorted(scores, key=key)


def candidates(names=None) -> tuple:
    return tuple(NAMES if names is None else names)


def testable(evaluator, names) -> list[str]:
    return [n for n in names if not unmet(BY_NAME[n], evaluator.session, evaluator.context)]


def rank_effects(evaluator, names=None) -> list[EffectScore]:
    """Every candidate alone on top of the nominal model, ranked."""
    names = candidates(names)
    evaluator.prefetch([()] + [(n,) for n in testable(evaluator, names)])
    return rank([score(evaluator, (), n) for n in names])


def forward_selection(evaluator, ranked: list[EffectScore],
                      max_rounds: int = MAX_ROUNDS, max_pool: int = MAX_POOL) -> list[str]:
    """Greedy forward selection among the supported effects (module docstring), the
    ``max_pool`` with the most evidence alone (the others explain less than they do, and
    each round costs one evaluation per candidate)."""
    pool = [s.name for s in sorted((s for s in ranked if s.significant),
                                   key=lambda s: -s.evidence)][:max_pool]
    selected: list[str] = []
    for _ in range(max_rounds):
        evaluator.prefetch([tuple(selected) + (n,) for n in pool if n not in selected])
        trials = [score(evaluator, tuple(selected), n) for n in pool if n not in selected]
        trials = [s for s in trials if s.significant]
        if not trials:
            break
        selected.append(max(trials, key=lambda s: s.evidence).name)
    return selected
