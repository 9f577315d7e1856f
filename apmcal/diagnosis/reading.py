"""A log read and cut into a diagnosis session in a forked worker, while the main process imports
the diagnosis (:func:`apmcal.diagnosis.compute.workers.beside`): reading needs none of the
diagnosis's packages (scipy's optimize, signal and stats), the diagnosis none of the readers'
(pandas), and the second core would otherwise be idle then.
"""
from __future__ import annotations

from dataclasses import dataclass

from apmcal.core.errors import ApmcalError
from apmcal.core.options import Options


def import_diagnosis():
    """The diagnosis, imported (with what it loads on first use) while the log is read."""
    from apmcal.diagnosis.run import diagnose, preload_imports

    preload_imports()
    return diagnose


@dataclass(frozen=True)
class LogReading:
    """One log to read and cut into a diagnosis session (a job for a forked worker).

    Attributes
    ----------
    file : str
        The log.
    options : Options
        Site and session options.
    """

    file: str
    options: Options

    def session(self) -> tuple:
        """(session or None, the log's warning lines, the ApmcalError that stopped the reading
        or None): the warnings are printed even when the log is then refused."""
        from apmcal.diagnosis.session.log import session_from_log
        from apmcal.sources import read_log
        from apmcal.sources.units import require_plausible_units

        warnings: list[str] = []
        try:
            contents = read_log(self.file)
            require_plausible_units(contents)   # a sensor in impossible units is not data
            warnings = [line for line in contents.messages if line.startswith("warning: ")]
            return session_from_log(contents, self.options), warnings, None
        except ApmcalError as err:
            return None, warnings, err
