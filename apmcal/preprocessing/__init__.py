"""Samples made ready for the solvers; no fitting here.

- :mod:`~apmcal.preprocessing.prepare` — the preparation every calibration shares (finite
  samples, monotonic time, truncation and firmware correction undone), which recording to use;
- :mod:`~apmcal.preprocessing.timebase`, :mod:`~apmcal.preprocessing.resolution` — the time
  base and the resolution of integer telemetry;
- :mod:`~apmcal.preprocessing.param_changes` — samples under one set of correction parameters;
- :mod:`~apmcal.preprocessing.stillness`, :mod:`~apmcal.preprocessing.static`,
  :mod:`~apmcal.preprocessing.hold_merge` — still periods and the face up in each;
- :mod:`~apmcal.preprocessing.rotations`, :mod:`~apmcal.preprocessing.ferraris_regions` — the
  turns between holds and the regions of a Ferraris session;
- :mod:`~apmcal.preprocessing.highpass` — the 0.5 Hz high-pass of [Oppong] §5;
- :mod:`~apmcal.preprocessing.decimation`, :mod:`~apmcal.preprocessing.tcal_blocks` — block
  means for the joint and temperature fits.
"""
