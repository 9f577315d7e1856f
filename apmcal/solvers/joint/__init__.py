"""The joint self-calibration of accelerometer, gyroscope and magnetometer ([Chow]).

- :mod:`~apmcal.solvers.joint.solve` — :func:`joint_calibration`, the Gauss-Helmert solution;
- :mod:`~apmcal.solvers.joint.model` — the 42-parameter sensor model ([Chow] §3.1);
- :mod:`~apmcal.solvers.joint.residuals` — the implicit conditions f(X, Y) = 0 ([Chow] §3.2);
- :mod:`~apmcal.solvers.joint.jacobian` — their design matrix, by hand;
- :mod:`~apmcal.solvers.joint.covariance` — the misclosures' covariance and whitening;
- :mod:`~apmcal.solvers.joint.trajectory` — the calibrated signals and the session's attitude,
  integrated once for all windows.
"""
