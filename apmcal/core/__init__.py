"""The vocabulary every layer shares, and nothing above it.

- :mod:`~apmcal.core.recording` — :class:`Recording` (one sensor instance's samples in SI
  columns) and :class:`LogContents` (everything a reader found in one file);
- :mod:`~apmcal.core.options` — :class:`Options`, what the user chose (method, site, holds);
- :mod:`~apmcal.core.constants` — physical constants, unit conversions, frame conventions;
- :mod:`~apmcal.core.errors` — :class:`ApmcalError`, the one-line user-facing error;
- :mod:`~apmcal.core.geomag` — the World Magnetic Model's field at a site and date;
- :mod:`~apmcal.core.json_file` — results as JSON files (numpy values made plain);
- :mod:`~apmcal.core.blas_threads` — single-threaded BLAS for solvers of small products.
"""
