"""The one exception type the command line turns into a one-line message."""
from __future__ import annotations


class ApmcalError(Exception):
    """A user-facing error: which file, where in it, and why.

    The CLI prints ``str(err)`` on one line of stderr and exits non-zero, never a traceback.

    Parameters
    ----------
    why : str
        What went wrong, in plain words.
    path : str, optional
        The file (or connection string) concerned.
    where : str, optional
        The place inside it: "byte 1234", "line 17", "record 55", "param INS_ACCOFFS_X".
    """

    def __init__(self, why: str, path: str | None = None, where: str | None = None):
        self.why = why
        self.path = None if path is None else str(path)
        self.where = where
        super().__init__(str(self))

    def __str__(self) -> str:
        parts = [p for p in (self.path, self.where) if p]
        return ": ".join(parts + [self.why])
