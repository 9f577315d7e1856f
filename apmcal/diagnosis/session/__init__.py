"""The session the diagnosis works on: a log's prepared samples cut into still holds, the moves
between them, and pieces alternating between two folds.

- :mod:`~apmcal.diagnosis.session.log` — the cut (:func:`session_from_log`);
- :mod:`~apmcal.diagnosis.session.decimate` — the same session averaged over blocks;
- :mod:`~apmcal.diagnosis.session.facts` — what a session offers the models (Earth field, ...);
- :mod:`~apmcal.diagnosis.session.hold_motion` — the tremor and sway inside the holds;
- :mod:`~apmcal.diagnosis.session.trajectory` — the motion reconstructed for the twin;
- :mod:`~apmcal.diagnosis.session.twin_log` — a recorded twin put on the real session's samples.
"""
