"""What ``apmcal log`` and ``apmcal live`` give for one file: its summary, the calibration, the
ArduPilot parameters proposed for it and the verdict, built once and printed, saved (JSON) and
written (.param) by itself.

The JSON file is :meth:`apmcal.solvers.result.Calibration.save`'s (schema, units, sensors,
params, report) with this report's own top-level fields: ``summary``, ``verdict``,
``rejected_params`` (when there is a proposal) and ``param_file`` or ``param_file_error`` (when a
parameter file was asked for); a summary without a calibration is saved alone.

:func:`calibrate` is the Python front door to all of it (``apmcal.calibrate``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from apmcal.core.errors import ApmcalError
from apmcal.core.json_file import write_json
from apmcal.report.text import (
    print_calibration,
    print_summary,
    raw_count_sensors,
    summarize,
    verdict_dict,
)


@dataclass
class SessionReport:
    """One file's summary, calibration, proposal and verdict (:meth:`build`).

    Attributes
    ----------
    path : str
        The file read.
    summary : dict
        :func:`apmcal.report.text.summarize` of the file.
    calibration : Calibration or None
        None with a summary only.
    proposal : ParamProposal or None
        The ArduPilot parameters proposed (None: no calibration, or a CSV file without a
        firmware generation).
    outputs : dict
        The files written so far: "param_file" (its path) or "param_file_error" (why not).
    accept_redo : bool
        Values of a sensor graded REDO are written and uploaded too (``--accept-redo``).
    """

    path: str
    summary: dict
    calibration: object = None
    proposal: object = None
    outputs: dict = field(default_factory=dict)
    accept_redo: bool = False

    @classmethod
    def build(cls, contents, calibration=None, proposal=None) -> "SessionReport":
        """The report of ``contents`` (LogContents) with its calibration and proposal."""
        return cls(contents.path, summarize(contents), calibration, proposal)

    def with_calibration(self, calibration, proposal) -> "SessionReport":
        """The same report with the file's calibration and proposal."""
        return replace(self, calibration=calibration, proposal=proposal)

    @property
    def verdict(self) -> dict:
        """Sensor name (and "overall") → :class:`apmcal.report.verdict.Verdict` (empty without a
        calibration)."""
        if self.calibration is None:
            return {}
        from apmcal.report.verdict import judge

        return judge(self.calibration, self.proposal, raw_count_sensors(self.summary),
                     self.summary.get("gyro_cal_at_boot"))

    @property
    def writable(self):
        """What of the proposal may be written to a parameter file or a vehicle
        (:class:`apmcal.ardupilot.limits.Writable`): the values of a sensor graded REDO are
        withheld unless :attr:`accept_redo`; those out of the firmware's limits always (they
        are the proposal's ``rejected``). None without a proposal."""
        if self.proposal is None:
            return None
        from apmcal.ardupilot.limits import Writable
        from apmcal.report.verdict import redo_params

        return Writable.sort(self.proposal.values, redo_params(self.verdict, self.proposal),
                             self.proposal.rejected, self.accept_redo)

    @property
    def status(self) -> int:
        """Exit status: 1 when some proposed value is withheld (graded REDO, or out of the
        firmware's limits), else 0."""
        return 0 if self.proposal is None else self.writable.status

    def print_summary(self, console, verbose: bool = True) -> None:
        """What the file holds (:func:`apmcal.report.text.print_summary`)."""
        print_summary(self.summary, console, verbose)

    def print_calibration(self, console, verbose: bool = False, link: str | None = None) -> None:
        """The verdict, how to apply it, the proposal beside the values in force, the numbers
        (:func:`apmcal.report.text.print_calibration`); ``link``: the vehicle's connection."""
        if self.calibration is not None:
            print_calibration(self.calibration, self.proposal, console, verbose,
                              summary=self.summary, link=link,
                              param_file=self.outputs.get("param_file"),
                              writable=self.writable)

    def to_dict(self) -> dict:
        """This report's own top-level JSON fields (the calibration's are added by :meth:`save`)."""
        out = {"summary": self.summary}
        if self.calibration is not None:
            out["verdict"] = verdict_dict(self.calibration, self.proposal,
                                          raw_count_sensors(self.summary),
                                          self.summary.get("gyro_cal_at_boot"))
            if self.proposal is not None:       # its values are the calibration's own "params"
                out["rejected_params"] = dict(self.proposal.rejected)
                out["withheld_params"] = self.writable.withheld
                out["firmware_generation"] = self.proposal.generation
        out.update(self.outputs)
        return out

    def save(self, path) -> None:
        """Write the JSON file (see the module docstring); one-line ApmcalError on OSError."""
        if self.calibration is None:
            write_json(path, self.to_dict())
        else:
            self.calibration.save(path, extra=self.to_dict())     # schema, units, report + ours

    def write_params(self, path, fmt: str = "param") -> None:
        """The proposed parameters as a .param file (QGroundControl's .params with
        ``fmt="qgc"``); the outcome is kept for the JSON file
        ("param_file", or "param_file_error" with the reason) and an error raised again.

        Only :attr:`writable` values are written; the file records the firmware generation
        they were made for.

        Raises
        ------
        ApmcalError
            Without a proposal (no firmware generation) or when the file cannot be written.
            With every value withheld nothing is written and nothing raised: the status says
            it.
        """
        try:
            if self.proposal is None:
                raise ApmcalError("not an ArduPilot log, so no firmware generation to write "
                                  "parameters for: add --firmware 3.2 or --firmware 3.3+",
                                  self.path)
            values = self.writable.values
            if not values:      # exit status 1 (:attr:`status`), the reasons printed
                self.outputs["param_file_error"] = "nothing written: every value is withheld"
                return
            self.proposal.write(path, f"apmcal {self.calibration.method} calibration of "
                                      f"{self.path}", fmt, values)
        except ApmcalError as err:
            self.outputs["param_file_error"] = str(err)
            raise
        self.outputs["param_file"] = str(path)



def calibrate(source, *, method: str = "auto", lat_deg: float | None = None,
              lon_deg: float | None = None, min_still_s: float = 2.0,
              instance: int | None = None, generation: str | None = None) -> SessionReport:
    """Calibrate a log file or a recording: what ``apmcal log`` does, for Python users.

    Parameters
    ----------
    source : str, Path, LogContents or Recording
        A .tlog, .bin, .log or .csv file (read with :func:`apmcal.sources.read_log`), what a
        reader returned, or one recording.
    method : {"auto", "ferraris", "static", "ellipsoid", "joint"}
    lat_deg, lon_deg : float, optional
        The site [deg]: normal gravity and Earth rate (latitude), the WMM field (both).
    min_still_s : float
        Shortest still period counted as a hold [s].
    instance : int, optional
        IMU instance (default: the first).
    generation : {"3.2", "3.3+"}, optional
        Firmware parameter generation (default: from the log; needed for a CSV file's parameters).

    Returns
    -------
    SessionReport
        ``calibration`` (:class:`~apmcal.solvers.result.Calibration`, with its report),
        ``proposal`` (the ArduPilot parameters, or None for a CSV file without ``generation``),
        ``verdict``; ``print_calibration(console)``, ``save(path)``, ``write_params(path)``.

    Raises
    ------
    ApmcalError
        For a file that cannot be read, implausible units, or nothing to calibrate.
    """
    from apmcal.calibration.log import calibrate_log
    from apmcal.core.options import Options
    from apmcal.core.recording import LogContents, Recording
    from apmcal.sources import read_log
    from apmcal.sources.units import require_plausible_units

    if isinstance(source, Recording):
        source = LogContents(path=source.source, format=source.message or "recording",
                             recordings=[source], params=dict(source.params),
                             vehicle=source.vehicle, firmware=source.firmware)
    contents = source if isinstance(source, LogContents) else read_log(source)
    require_plausible_units(contents)
    opts = Options(method, lat_deg, lon_deg, min_still_s, instance, generation)
    return SessionReport.build(contents).with_calibration(*calibrate_log(contents, opts))
