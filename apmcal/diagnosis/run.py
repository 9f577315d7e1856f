"""``apmcal gap`` end to end: a session in, a :class:`~apmcal.diagnosis.output.result.GapResult` out.

Steps: score the nominal model (in-sample and held-out, with the breakdown of where its gap
lies); score every candidate effect alone and rank them; select a combination greedily; score
it; report each tested effect's parameters (alone, or within the combination when selected;
the mean of the two folds' fits).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apmcal.diagnosis.compute import reuse
from apmcal.diagnosis.model.params import white_noise_of_folds
from apmcal.diagnosis.noise.structure import merged as merged_structure
from apmcal.diagnosis.noise.terms import prepare as prepare_noise_terms
from apmcal.diagnosis.output.result import GapResult
from apmcal.diagnosis.scoring import null
from apmcal.diagnosis.scoring.breakdown import gap_summary
from apmcal.diagnosis.scoring.evaluate import FOLDS, Evaluation, Evaluator
from apmcal.diagnosis.scoring.select import (
    candidates,
    forward_selection,
    merged,
    rank,
    rank_effects,
    testable,
)
from apmcal.diagnosis.session.decimate import FINE_EFFECTS, SHAPES_BLOCK_MEANS


@dataclass
class Diagnosis:
    """The result with what made it (for plots and the twin file)."""

    result: GapResult
    evaluator: Evaluator
    nominal: Evaluation
    final: Evaluation


def session_summary(session, evaluator: Evaluator) -> dict:
    """What the session holds, for the result: "duration_s" [s], "rate_hz" [Hz], counts of
    holds, moves, pieces and orientations, the sensors, those the log stores as integers, the
    ranges "temperature_c" [°C] and "current_a" [A] when logged, and "twin_log" (the recorded
    twin's file) when the twin is a recording."""
    moves = int(np.sum(~session.pieces.is_hold))
    out = {"duration_s": session.duration, "rate_hz": session.fs, "holds": len(session.holds),
           "moves": moves, "pieces": len(session.pieces),
           "orientations": evaluator.context.orientations,
           "sensors": ["acc", "gyr"] + (["mag"] if session.mag is not None else []),
           "integer_format": sorted(session.integer_sensors)}
    if session.temp is not None:
        out["temperature_c"] = [float(np.nanmin(session.temp)), float(np.nanmax(session.temp))]
    if session.current is not None:
        out["current_a"] = [float(np.nanmin(session.current)),
                            float(np.nanmax(session.current))]
    if evaluator.twin is not None:
        out["twin_log"] = str(evaluator.twin.source)
    return out


def diagnose(session, names=None, *, seed: int = 0, progress=None, twin=None) -> Diagnosis:
    """Diagnose one session (``names``: the candidate effects, default all).

    Parameters
    ----------
    session : Session
    names : list of str, optional
        Candidate effects.
    seed : int
        Seed of the twins' noise.
    progress : callable, optional
        Called with a short text at each stage.
    twin : Session, optional
        A recorded twin on the session's samples (:func:`apmcal.diagnosis.session.twin_log.
        on_samples_of`), in place of the simulated one: what is left between the board and
        that recording.

    Returns
    -------
    Diagnosis
    """
    from threadpoolctl import threadpool_limits

    # the models are spread over processes (Evaluator.map); BLAS threads on top of those only
    # contend — an (n, 3) @ (3, 3) product ran 10-25× slower with two OpenBLAS threads on a
    # busy two-core machine than with one
    reuse.forget()     # what the last session's models left can only take memory
    with threadpool_limits(limits=1):
        return _diagnose(session, names, seed, progress, twin)


def _diagnose(session, names, seed: int, progress, twin=None) -> Diagnosis:
    say = progress or (lambda _msg: None)
    ev = Evaluator(session, seed, twin=twin)
    say("nominal model")
    nominal = _score_nominal(ev)
    ranked, selection = _rank_and_select(ev, names, say)
    selected = selection.order()
    say("selected model")
    # the selected model's evaluation (fold 0 here, fold 1 in a worker) and then its
    # breakdown here; in the same workers, after its fold 1, the nominal model's breakdown and
    # its noise structure axis by axis, which need nothing more
    axes = [(sensor, axis) for sensor in ("acc", "gyr", "mag") for axis in "xyz"]
    beside = ([("gap_of", ((),))] if selected else []) + \
        [("noise_structure", ([axis],)) for axis in axes]
    (final, final_gap), results = ev.evaluate_with(
        tuple(selected), beside, then=lambda evaluation: (evaluation,
                                                          gap_summary(evaluation, session)))
    nominal_gap = results.pop(0) if selected else final_gap   # nothing selected: the same
    structure = merged_structure(results)
    params = {s.name: s.params for s in ranked if s.tested}     # each alone ...
    params.update(ev.summary(tuple(selected)).params)    # ... the selected within the combination
    # best first: the combination, then the rest as ranked
    ranked = sorted(ranked, key=lambda s: selected.index(s.name) if s.name in selected
                    else len(selected))
    effects = [_effect_entry(s, selection, params.get(s.name, {})) for s in ranked]
    white = white_noise_of_folds([f.noise for f in nominal.folds])
    result = GapResult(session.source, session_summary(session, ev),
                       nominal_gap, effects, selected, final_gap, white, structure,
                       notes=list(session.notes))
    return Diagnosis(result, ev, nominal, final)


def _score_nominal(ev: Evaluator) -> Evaluation:
    """The nominal model: fold 0 here, fold 1 in a worker, and in another worker beside them
    the two folds of the nominal model of the block means, where the slow effects start (a
    session faster than :data:`~apmcal.diagnosis.session.decimate.SLOW_RATE_HZ`; that worker makes its
    own block means). Once fold 0 is done, while fold 1 may still run, this process makes what
    the workers forked later inherit: the block means' evaluator and the noise-structure fits'
    fixed integrals."""
    jobs = [("_slow_nominal_fold", (fold,)) for fold in FOLDS] if ev.decimates else []

    def meanwhile():
        _ = ev.slow
        prepare_noise_terms()

    nominal, results = ev.evaluate_with((), jobs, meanwhile=meanwhile)
    if results:
        ev.slow.keep_nominal_folds(results)
    return nominal


def preload_imports() -> None:
    """Import scipy.signal (scipy.stats with it) and filterpy. The low-pass filter
    and motion contamination models, the random-walk smoother and the noise structure need
    them, the nominal model does not. Imported in this process once, every worker forked
    afterwards has them; a worker that imported them itself would spend 0.8 s on it, once per
    pool. ``apmcal gap`` imports them while a worker reads the log."""
    import filterpy.kalman  # noqa: F401
    import scipy.signal  # noqa: F401


def _rank_and_select(ev: Evaluator, names, say):
    """Every candidate scored alone, its significance calibrated on null sessions, and the
    stepwise combination.

    A recording faster than :data:`~apmcal.diagnosis.session.decimate.SLOW_RATE_HZ` is scored in
    stages: the fine effects alone at its own rate; the slow ones on its block means, on top of
    a low-pass filter when one was found (it colours the noise down into the slow band: left
    out, a random walk would stand in for it); then the fine effects' combination at the
    recorded rate, on top of the slow effects selected. Each stage's candidates are calibrated
    on null sessions scored in that same stage, when the selection first needs a candidate's
    (:class:`apmcal.diagnosis.scoring.null.Calibration`)."""
    preload_imports()       # before the first workers that may need them are forked
    if not ev.decimates:
        say("candidate effects")
        with ev.workers_kept():
            ranked = rank_effects(ev, names)
            say("combination")
            ev.chance = null.Calibration(ev, ranked, len(testable(ev, candidates(names))),
                                         say=say, within="combination")
            selection = forward_selection(ev, ranked, chance_on_top=null.chance_on_top)
        return rank(ranked), selection
    slow_names = [n for n in candidates(names) if n not in FINE_EFFECTS]
    fine_names = [n for n in candidates(names) if n in FINE_EFFECTS]
    family = len(testable(ev, fine_names)) + len(testable(ev.slow, slow_names))
    say("candidate effects")
    ranked_fine = rank_effects(ev, fine_names)
    ev.chance = null.Calibration(ev, ranked_fine, family, say=say, within="candidate effects")
    for s in ranked_fine:   # a low-pass filter carried under the slow effects must be beyond
        if s.supported and s.name in SHAPES_BLOCK_MEANS:    # chance itself: its null now
            ev.chance.calibrated(s.name)
    carried = tuple(s.name for s in ranked_fine if s.supported and s.name in SHAPES_BLOCK_MEANS)
    say("slow candidate effects (block means)")
    with ev.slow.workers_kept():
        ranked_slow = rank_effects(ev.slow, slow_names, base=carried)
        say("combination")
        ev.chance.within = "combination"
        ev.slow.chance = null.Calibration(ev.slow, ranked_slow, family, base=carried, say=say,
                                          within="combination")
        slow = forward_selection(ev.slow, ranked_slow, base=carried,
                                 chance_on_top=null.chance_on_top)
    fine = forward_selection(ev, ranked_fine, base=tuple(slow.order()),
                             chance_on_top=null.chance_on_top)
    return rank(ranked_slow + ranked_fine), merged(slow, fine)


def _effect_entry(s, selection, params: dict) -> dict:
    entry = {"name": s.name, "significant": selection.significant(s.name),
             "supported_alone": bool(s.supported), "not_tested": s.reason,
             "implausible": s.implausible, "parameters_p_value": s.p_value,
             "null_p_value": s.null_p_value, "null_threshold_nats": s.null_threshold,
             "null_sessions": s.null_draws, "scored_at_hz": s.rate_hz}
    if s.name in selection.joined:
        entry["evidence_when_selected_nats"] = selection.joined[s.name]
        entry["evidence_in_combination_nats"] = selection.needed[s.name]
    if s.name in selection.beyond:
        entry["evidence_beyond_selection_nats"] = selection.beyond[s.name]
    if s.name in selection.confounded:
        entry["confounded_with"] = selection.confounded[s.name]
    if s.name in selection.stand_in:
        entry["stands_in_for"] = selection.stand_in[s.name]
    if s.name in selection.chance:
        entry["chance_on_top_p_value"] = selection.chance[s.name]
    if s.tested:
        entry.update({"shrink_heldout": s.shrink_out, "shrink_in_sample": s.shrink_in,
                      "gap_heldout": s.gap_out, "gap_in_sample": s.gap_in,
                      "evidence_nats": s.evidence, "params": params})
    return entry
