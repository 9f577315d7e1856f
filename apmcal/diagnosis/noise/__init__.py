"""The noise of the hold residuals, real against twin.

- :mod:`~apmcal.diagnosis.noise.allan` — Haar wavelet variance and Allan deviation;
- :mod:`~apmcal.diagnosis.noise.terms` — white noise, bias instability and rate random walk;
- :mod:`~apmcal.diagnosis.noise.fit`, :mod:`~apmcal.diagnosis.noise.structure` — the noise terms
  of a model fitted to the wavelet variances, and the structure real against twin;
- :mod:`~apmcal.diagnosis.noise.bias_track` — the random-walk bias by a Kalman filter;
- :mod:`~apmcal.diagnosis.noise.dither` — white noise below an integer format's step, from how
  often the readings change.
"""
