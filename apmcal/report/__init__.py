"""What the user reads: a calibration's numbers turned into words and grades.

- :mod:`~apmcal.report.verdict` — good / usable / redo per sensor, with reason and next step;
- :mod:`~apmcal.report.lines` — the solvers' findings as report lines;
- :mod:`~apmcal.report.text` — the console report: what the file holds, the verdict, numbers;
- :mod:`~apmcal.report.session` — :class:`SessionReport`, one file's summary, calibration,
  proposal and verdict, printed, saved (JSON) and written (.param) by itself, and
  :func:`~apmcal.report.session.calibrate` (``apmcal.calibrate``) that makes one;
- :mod:`~apmcal.report.tcal` — what ``apmcal tcal`` prints;
- :mod:`~apmcal.report.html` — the HTML report (``--report DIR``): one self-contained page;
- :mod:`~apmcal.report.figures` — its figures (matplotlib, embedded as PNG).
"""
