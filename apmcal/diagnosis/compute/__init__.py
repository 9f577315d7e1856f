"""How the diagnosis computes fast, without changing a number.

- :mod:`~apmcal.diagnosis.compute.workers` — methods run in forked worker processes;
- :mod:`~apmcal.diagnosis.compute.memo` — results of pure functions kept by their inputs' content;
- :mod:`~apmcal.diagnosis.compute.reuse` — Haar coefficients and gap cells of a residual block
  that comes back value for value.
"""
