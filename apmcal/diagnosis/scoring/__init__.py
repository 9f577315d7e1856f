"""How much worse the real residuals fit a model than its twin's do, and which effect explains it.

- :mod:`~apmcal.diagnosis.scoring.gap` (with :mod:`~apmcal.diagnosis.scoring.haar`) — the gap
  between real and twin residuals;
- :mod:`~apmcal.diagnosis.scoring.breakdown` — where it lies (sensor, axis, segment, band, time);
- :mod:`~apmcal.diagnosis.scoring.evaluate` — a model scored in-sample and held-out, both ways;
- :mod:`~apmcal.diagnosis.scoring.select` — the candidates ranked by held-out evidence, and a
  stepwise combination;
- :mod:`~apmcal.diagnosis.scoring.null` — what chance alone gives each candidate: its evidence
  on sessions drawn from the fitted nominal model, and its p-value.
"""
