"""Diagnosis of the gap between a real board and its simulation (``apmcal gap``).

Where the gap lies, which unmodelled effect causes it, and how far modelling it shrinks the gap
on data the fit did not see. The flow, one module per step:

- :mod:`~apmcal.diagnosis.session.log` — a log's prepared samples cut into still holds, the moves
  between them, and pieces alternating between two folds;
- :mod:`~apmcal.diagnosis.model.nominal` (with :mod:`~apmcal.diagnosis.model.blocks`,
  :mod:`~apmcal.diagnosis.model.regressors`, :mod:`~apmcal.diagnosis.model.static_fit`,
  :mod:`~apmcal.diagnosis.model.dynamics`, :mod:`~apmcal.diagnosis.noise.fit`) — the nominal model
  plus chosen effects fitted on one fold, and its residuals;
- :mod:`~apmcal.diagnosis.twin.simulate` (with :mod:`~apmcal.diagnosis.session.trajectory`) — the session
  simulated by sitl's error model with the fitted parameters;
- :mod:`~apmcal.diagnosis.scoring.gap` (with :mod:`~apmcal.diagnosis.scoring.haar`) — the gap between real and
  twin residuals, and :mod:`~apmcal.diagnosis.scoring.breakdown` — where it lies;
- :mod:`~apmcal.diagnosis.scoring.evaluate` — a model scored in-sample and held-out, both ways round;
- :mod:`~apmcal.diagnosis.model.effects` and :mod:`~apmcal.diagnosis.scoring.select` — the candidate effects,
  ranked by held-out evidence, with :mod:`~apmcal.diagnosis.model.wald` (are the parameters away
  from "off"?) and :mod:`~apmcal.diagnosis.model.plausible` (within physical limits?), and a
  stepwise combination;
- :mod:`~apmcal.diagnosis.run` — all of it for one session; :mod:`~apmcal.diagnosis.output.result`,
  :mod:`~apmcal.diagnosis.output.advice` (what to do, one sentence per selected effect),
  :mod:`~apmcal.diagnosis.output.summary`, :mod:`~apmcal.diagnosis.output.report`,
  :mod:`~apmcal.diagnosis.output.plots`, :mod:`~apmcal.diagnosis.twin.file` (with
  :mod:`~apmcal.diagnosis.twin.sitl_params`, the twin as ArduPilot SITL parameters) — what the
  user gets;
- :mod:`~apmcal.diagnosis.noise.allan`, :mod:`~apmcal.diagnosis.noise.terms`,
  :mod:`~apmcal.diagnosis.noise.bias_track` — Allan deviation, noise terms and the random-walk bias
  track of the residuals (real against twin);
- :mod:`~apmcal_sim.gap_benchmark` — simulated sessions with one effect withheld from the twin.
"""
