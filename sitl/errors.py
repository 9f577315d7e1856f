"""sitl's user-facing error (sitl stands alone: it imports only apmcal.constants and
apmcal.solvers.result from apmcal). Same one-line shape as apmcal.errors.ApmcalError."""
from __future__ import annotations


class SitlError(Exception):
    """Bad input to the simulator: ``path: where: why`` on one line.

    Parameters
    ----------
    why : str
        What went wrong.
    path : str, optional
        The file or option concerned.
    where : str, optional
        The place inside it ("--set", "key effects").
    """

    def __init__(self, why: str, path=None, where: str | None = None):
        self.why, self.path, self.where = why, None if path is None else str(path), where
        super().__init__(str(self))

    def __str__(self) -> str:
        return ": ".join([p for p in (self.path, self.where) if p] + [self.why])
