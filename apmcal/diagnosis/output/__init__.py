"""What the user gets from ``apmcal gap``.

- :mod:`~apmcal.diagnosis.output.result` — the result, which saves itself as JSON and loads back;
- :mod:`~apmcal.diagnosis.output.advice` — what to do, one sentence per selected effect;
- :mod:`~apmcal.diagnosis.output.summary` — the terminal summary;
- :mod:`~apmcal.diagnosis.output.report` and :mod:`~apmcal.diagnosis.output.plots` — the report
  with its figures (``--report DIR``);
- :mod:`~apmcal.diagnosis.output.html` — that report as one self-contained page, index.html.
"""
