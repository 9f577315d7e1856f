"""Ellipsoid fits of accelerometer and compass samples ([Niespodziany]) and their robust
successor.

- :mod:`~apmcal.solvers.ellipsoid.fit` — the one entry point (robust, analytical, numerical),
  the sphere fit and the figure of merit;
- :mod:`~apmcal.solvers.ellipsoid.paper` — [Niespodziany]'s two estimators, as the paper gives them;
- :mod:`~apmcal.solvers.ellipsoid.robust` — the robust geometric fit with its uncertainty;
- :mod:`~apmcal.solvers.ellipsoid.lm` — its bounded Levenberg-Marquardt;
- :mod:`~apmcal.solvers.ellipsoid.debias` — its second-order bias, estimated and removed.
"""
