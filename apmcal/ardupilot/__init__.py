"""ArduPilot's parameters and what they mean: the firmware's side of every calibration.

Knows nothing of logs or solvers: given parameter values it says how the firmware corrects its
samples, and given a calibration which values make the firmware apply it.

- :mod:`~apmcal.ardupilot.names` — the correction parameters (INS_ACC*/INS_GYR*/COMPASS_*/
  AHRS_ORIENTATION) and which of them changed between two snapshots;
- :mod:`~apmcal.ardupilot.orientation` — board rotations (AHRS_ORIENTATION, COMPASS_ORIENT) as
  matrices;
- :mod:`~apmcal.ardupilot.firmware` — the firmware generations ("3.2", "3.3+") and their
  correction formulas, applied and undone on a recording;
- :mod:`~apmcal.ardupilot.params` — a calibration turned into INS_*/COMPASS_* values within the
  firmware's limits (:class:`ParamProposal`);
- :mod:`~apmcal.ardupilot.limits` — what of a proposal may be written: the firmware's limits
  for a generation, and values graded REDO withheld unless the user says so (:class:`Writable`);
- :mod:`~apmcal.ardupilot.tcal_params` — the temperature calibration's INS_TCALn_* values;
- :mod:`~apmcal.ardupilot.paramfile` — .param files as MAVProxy and Mission Planner write them;
- :mod:`~apmcal.ardupilot.scope` — which parameters upload and restore may write.

The facts these rely on, each with its ArduPilot source: ``docs/ardupilot-facts.md``.
"""
