"""Diagnosis of the gap between a real board and its simulation (``apmcal gap``).

Where the gap lies, which unmodelled effect causes it, and how far modelling it shrinks the gap
on data the fit did not see. The flow, one subpackage per concern:

- :mod:`~apmcal.diagnosis.session` — a log's prepared samples cut into still holds, the moves
  between them, and pieces alternating between two folds;
- :mod:`~apmcal.diagnosis.model` — the nominal model plus chosen effects fitted on one fold,
  and its residuals; the candidate effects and the tests of their parameters;
- :mod:`~apmcal.diagnosis.twin` — the session simulated by apmcal's sensor error model
  (:mod:`apmcal.sensor_model`) with the fitted parameters, and the twin written for apmcal_sim
  or as ArduPilot SITL parameters;
- :mod:`~apmcal.diagnosis.scoring` — the gap between real and twin residuals, where it lies,
  each model scored held-out, and the effects that explain it;
- :mod:`~apmcal.diagnosis.noise` — Allan deviation, noise terms and the random-walk bias track
  of the residuals (real against twin);
- :mod:`~apmcal.diagnosis.output` — the result, what to do (one sentence per selected effect),
  the summary, the report and its figures;
- :mod:`~apmcal.diagnosis.compute` — worker processes and the caches that keep it fast;
- :mod:`~apmcal.diagnosis.run` — all of it for one session; :mod:`~apmcal.diagnosis.reading`
  — the log read and cut in a forked worker meanwhile.

The benchmark of simulated sessions with one effect withheld from the twin needs the simulator,
so it lives beside it: ``python -m apmcal_sim.gap_benchmark``.
"""
