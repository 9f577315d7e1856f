"""Long calculations (a log calibrated, a gap diagnosed, a fleet measured) run off the web
server's thread, one at a time, each telling the page how far it is.

A :class:`Job` has named stages; its work calls :meth:`Job.stage` as it enters each and may
say more within one (:meth:`Job.detail`, a fraction of it done). The page follows a job by its
snapshot (:meth:`Job.snapshot`: the stage names, which one runs, how far, the result or the one
line that stopped it), sent as server-sent events. An :class:`~apmcal.core.errors.ApmcalError`
ends a job with its message; anything else with "internal error" and its type and text.
"""
from __future__ import annotations

import itertools
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from apmcal.core.errors import ApmcalError


@dataclass
class Job:
    """One calculation: its stages, how far it is, and its result or error.

    Attributes
    ----------
    id : str
    kind : str
        "log", "tcal", "gap", "fleet".
    title : str
        What it works on, for the page.
    folder : Path
        Where it writes its files (downloads, report pages).
    stages : list of str
        The stage names, in order.
    """

    id: str
    kind: str
    title: str
    folder: Path
    stages: list[str]
    state: str = "waiting"           # waiting, running, done, failed
    current: int = -1                # index into stages
    fraction: float = 0.0            # of the current stage, 0..1 (None-like -1: unknown)
    text: str = ""
    result: dict | None = None
    error: str | None = None
    failed_stages: list[str] = field(default_factory=list)  # stages a file did not pass
    files: dict[str, Path] = field(default_factory=dict)    # download name → file
    pages: dict[str, Path] = field(default_factory=dict)    # report name → its folder
    version: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def stage(self, name: str, text: str = "") -> None:
        """Enter stage ``name`` (added to the stages when it is not there yet)."""
        with self._lock:
            if name not in self.stages:
                self.stages.insert(self.current + 1, name)
            self.current = self.stages.index(name)
            self.fraction, self.text = -1.0, text
            self.version += 1

    def detail(self, text: str, fraction: float | None = None) -> None:
        """Say more about the current stage; ``fraction`` of it done (None: unknown)."""
        with self._lock:
            self.text = text
            self.fraction = -1.0 if fraction is None else min(max(float(fraction), 0.0), 1.0)
            self.version += 1

    def skip(self, names: list[str]) -> None:
        """Stages not passed (a file that could not be read): shown as such, the job goes on."""
        with self._lock:
            self.failed_stages += [n for n in names if n not in self.failed_stages]
            self.version += 1

    def finish(self, result: dict) -> None:
        """The job is done with ``result`` (JSON-ready)."""
        with self._lock:
            self.result, self.state, self.current = result, "done", len(self.stages)
            self.version += 1

    def fail(self, message: str) -> None:
        """The job stopped; ``message`` says why (one line)."""
        with self._lock:
            self.error, self.state = message, "failed"
            self.version += 1

    def snapshot(self) -> dict:
        """What the page shows: stages, progress, result or error (JSON-ready)."""
        with self._lock:
            return {"id": self.id, "kind": self.kind, "title": self.title, "state": self.state,
                    "stages": list(self.stages), "current": self.current,
                    "failed_stages": list(self.failed_stages),
                    "fraction": self.fraction, "text": self.text, "result": self.result,
                    "error": self.error, "version": self.version}


class Jobs:
    """The jobs of this server; they run one at a time, in the order started (two cores and
    the diagnosis's own worker processes: side by side they would only slow each other).

    Parameters
    ----------
    folder : Path
        Each job's files go into a folder of its own under this one.
    """

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.jobs: dict[str, Job] = {}
        self._ids = itertools.count(1)
        self._one_at_a_time = threading.Lock()

    def start(self, kind: str, title: str, stages: list[str], work) -> Job:
        """A new job running ``work(job)`` (which returns the result dict) on a thread.

        Parameters
        ----------
        kind, title : str
        stages : list of str
            The stage names known in advance.
        work : callable
            ``work(job) -> dict``; raises ApmcalError for the user's mistakes.
        """
        job_id = f"{next(self._ids)}-{int(time.time())}"
        folder = self.folder / f"job-{job_id}"
        folder.mkdir(parents=True, exist_ok=True)
        job = Job(job_id, kind, title, folder, list(stages))
        self.jobs[job_id] = job
        threading.Thread(target=self._run, args=(job, work), name=f"apmcal-job-{job_id}",
                         daemon=True).start()
        return job

    def _run(self, job: Job, work) -> None:
        if self._one_at_a_time.locked():
            job.detail("waiting for the calculation before it to finish")
        with self._one_at_a_time:
            job.state = "running"
            try:
                job.finish(work(job))
            except ApmcalError as err:
                job.fail(str(err))
            except MemoryError:
                job.fail("out of memory: the file is too large for this computer")
            except Exception as exc:     # a bug of ours: one line on the page, details here
                traceback.print_exc()
                job.fail(f"internal error: {type(exc).__name__}: {exc} (the terminal that "
                         f"runs apmcal ui shows the details; please report it)")

    def get(self, job_id: str) -> Job | None:
        """The job of that id, or None."""
        return self.jobs.get(job_id)
