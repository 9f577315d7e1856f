"""Diagnosis of the gap between a real board and its simulation (``apmcal gap``).

Where the gap lies, which unmodelled effect causes it, and how far modelling it shrinks the gap
on data the fit did not see. The flow, one module per step:

- :mod:`~apmcal.diagnosis.session` — a log's prepared samples cut into still holds, the moves
  between them, and pieces alternating between two folds;
- :mod:`~apmcal.diagnosis.model` (with :mod:`~apmcal.diagnosis.blocks`,
  :mod:`~apmcal.diagnosis.regressors`, :mod:`~apmcal.diagnosis.static_fit`,
  :mod:`~apmcal.diagnosis.dynamics`, :mod:`~apmcal.diagnosis.noise_fit`) — the nominal model
  plus chosen effects fitted on one fold, and its residuals;
- :mod:`~apmcal.diagnosis.twin` (with :mod:`~apmcal.diagnosis.trajectory`) — the session
  simulated by sitl's error model with the fitted parameters;
- :mod:`~apmcal.diagnosis.gap` (with :mod:`~apmcal.diagnosis.haar`) — the gap between real and
  twin residuals, and :mod:`~apmcal.diagnosis.breakdown` — where it lies;
- :mod:`~apmcal.diagnosis.evaluate` — a model scored in-sample and held-out, both ways round;
- :mod:`~apmcal.diagnosis.effects` and :mod:`~apmcal.diagnosis.select` — the candidate effects,
  ranked by held-out evidence, with :mod:`~apmcal.diagnosis.wald` (are the parameters away
  from "off"?) and :mod:`~apmcal.diagnosis.plausible` (within physical limits?), and a
  stepwise combination;
- :mod:`~apmcal.diagnosis.run` — all of it for one session; :mod:`~apmcal.diagnosis.result`,
  :mod:`~apmcal.diagnosis.summary`, :mod:`~apmcal.diagnosis.report`,
  :mod:`~apmcal.diagnosis.plots`, :mod:`~apmcal.diagnosis.twin_file` — what the user gets;
- :mod:`~apmcal.diagnosis.allan`, :mod:`~apmcal.diagnosis.noise_terms`,
  :mod:`~apmcal.diagnosis.bias_track` — Allan deviation, noise terms and the random-walk bias
  track of the residuals (real against twin);
- :mod:`~apmcal.diagnosis.benchmark` — simulated sessions with one effect withheld from the twin.
"""
