"""The nominal model plus chosen effects, fitted on one fold, and its residuals.

- :mod:`~apmcal.diagnosis.model.nominal` — a model fitted on one fold (:class:`ModelFit`);
- :mod:`~apmcal.diagnosis.model.effects` — the candidate unmodelled effects;
- :mod:`~apmcal.diagnosis.model.static_fit`, :mod:`~apmcal.diagnosis.model.dynamics` — fits of
  the holds and of the moves between them;
- :mod:`~apmcal.diagnosis.model.blocks`, :mod:`~apmcal.diagnosis.model.regressors` — block
  means and slow regressors of the deterministic effects;
- :mod:`~apmcal.diagnosis.model.params`, :mod:`~apmcal.diagnosis.model.wald`,
  :mod:`~apmcal.diagnosis.model.plausible` — the fitted parameters with σ, whether they differ
  from "off", whether they are physically plausible.
"""
