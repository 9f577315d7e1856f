"""``apmcal ui``: the whole tool in the browser, for people who never open a terminal.

A layer on top of the library, beside the command line (:mod:`apmcal.cli`): it calls the
library's own functions — readers, calibration, the report package's verdict and figures, the
guided six-face session, the verified upload and restore, the gap diagnosis, the fleet run —
and never the command line's printing. The page itself is plain HTML, CSS and JavaScript in
``static/`` (no build step, nothing loaded from the network).

- :mod:`~apmcal.ui.server` — ``apmcal ui`` running: the port on 127.0.0.1, the token, the
  browser, the clean stop;
- :mod:`~apmcal.ui.security` — the token, Host and Origin checks every request passes;
- :mod:`~apmcal.ui.app` — the web application: the page and the requests it makes;
- :mod:`~apmcal.ui.jobs` — long calculations off the server's thread, with named stages;
- :mod:`~apmcal.ui.logs` — logs dropped on the page: calibrated, temperature-calibrated or
  diagnosed, each with its verdict, figures and parameter files;
- :mod:`~apmcal.ui.vehicle` — the live vehicle: connection, pose, guided six faces, compass
  turn, calibration, upload and undo;
- :mod:`~apmcal.ui.compass_turn` — the compass turn's coverage of the sphere, and when it is
  enough;
- :mod:`~apmcal.ui.simulator` — the bundled simulated vehicle, run as its own program, to try
  the live calibration without a vehicle;
- :mod:`~apmcal.ui.fleet` — a fleet's folder chosen and measured.
"""
