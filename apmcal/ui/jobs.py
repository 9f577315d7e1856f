"""Long calculations (a log calibrated, a gap diagnosed, a fleet measured) run in a process of
their own, one at a time, each telling the page how far it is.

A process, not a thread of the web server: the gap diagnosis and the fleet start worker
processes of their own, which must not be forked from a server whose other threads may hold a
lock (the import lock, a logging lock) at that moment; the memory a diagnosis leaves behind goes
back to the system when its process ends; and stopping ``apmcal ui`` ends a calculation still
running together with the processes it started, their output kept out of the terminal.

A :class:`Job` has named stages; its work (a module-level function, run in the job's process
with a :class:`JobInProcess` standing in for the job) calls ``stage`` as it enters each and may
say more within one (``detail``, a fraction of it done). The page follows a job by its snapshot
(:meth:`Job.snapshot`: the stage names, which one runs, how far, the result or the one line that
stopped it), sent as server-sent events. An :class:`~apmcal.core.errors.ApmcalError` ends a job
with its message; anything else with "internal error" and its type and text.
"""
from __future__ import annotations

import itertools
import multiprocessing
import os
import queue
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from apmcal.core.errors import ApmcalError

STOP_WAIT_S = 10.0          # a job's process asked to stop is killed after this long [s]


@dataclass
class Job:
    """One calculation: its stages, how far it is, and its result or error.

    Attributes
    ----------
    id : str
    kind : str
        "log", "tcal", "gap", "fleet", "live".
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
    fraction: float = -1.0           # of the current stage, 0..1 (-1: unknown)
    text: str = ""
    result: dict | None = None
    error: str | None = None
    failed_stages: list[str] = field(default_factory=list)  # stages a file did not pass
    files: dict[str, Path] = field(default_factory=dict)    # download name → file
    pages: dict[str, Path] = field(default_factory=dict)    # report name → its folder
    extra: object = None             # what the work handed back beside its result (not shown)
    version: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def apply(self, what: str, *args) -> None:
        """One report of the job's process ("stage", "detail", "skip", "file", "page")."""
        with self._lock:
            if what == "stage":
                name, text = args
                if name not in self.stages:
                    self.stages.insert(self.current + 1, name)
                self.current = self.stages.index(name)
                self.fraction, self.text = -1.0, text
            elif what == "detail":
                self.text, self.fraction = args
            elif what == "skip":
                self.failed_stages += [n for n in args[0] if n not in self.failed_stages]
            elif what == "file":
                self.files[args[0]] = Path(args[1])
            elif what == "page":
                self.pages[args[0]] = Path(args[1])
            self.version += 1

    def finish(self, result: dict, extra=None) -> None:
        """The job is done with ``result`` (JSON-ready)."""
        with self._lock:
            self.result, self.extra = result, extra
            self.state, self.current = "done", len(self.stages)
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


class _Reporting(dict):
    """A dict that also tells the job's server side of every entry set."""

    def __init__(self, send, what: str):
        super().__init__()
        self._send, self._what = send, what

    def __setitem__(self, key, value):
        super().__setitem__(key, value)
        self._send(self._what, key, str(value))


class JobInProcess:
    """The job as its work sees it, in the job's process: the same ``stage``, ``detail``,
    ``skip``, ``files`` and ``pages`` as :class:`Job`, each sent to the server."""

    def __init__(self, channel, job_id: str, folder: Path, stages: list[str]):
        self._channel = channel
        self.id, self.folder, self.stages = job_id, Path(folder), list(stages)
        self.current = -1
        self.files = _Reporting(self._send, "file")
        self.pages = _Reporting(self._send, "page")

    def _send(self, *message) -> None:
        self._channel.put(message)

    def stage(self, name: str, text: str = "") -> None:
        """Enter stage ``name`` (added to the stages when it is not there yet)."""
        if name not in self.stages:
            self.stages.insert(self.current + 1, name)
        self.current = self.stages.index(name)
        self._send("stage", name, text)

    def detail(self, text: str, fraction: float | None = None) -> None:
        """Say more about the current stage; ``fraction`` of it done (None: unknown)."""
        self._send("detail", text, -1.0 if fraction is None else
                   min(max(float(fraction), 0.0), 1.0))

    def skip(self, names: list[str]) -> None:
        """Stages not passed (a file that could not be read): shown as such, the job goes on."""
        self._send("skip", list(names))


def _run_in_process(channel, job_id: str, folder: str, stages: list[str], work, args,
                    output: str) -> None:
    """The job's process: its output into ``output`` (the processes it starts inherit it),
    SIGTERM a clean exit (its own worker processes end with it), then ``work``."""
    log = open(output, "a", buffering=1)
    os.dup2(log.fileno(), 1)
    os.dup2(log.fileno(), 2)
    sys.stdout = sys.stderr = log
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # the server's Ctrl-C is the server's
    job = JobInProcess(channel, job_id, Path(folder), stages)
    try:
        result = work(job, *args)
        extra = result.pop("_extra", None) if isinstance(result, dict) else None
        channel.put(("finish", result, extra))
    except ApmcalError as err:
        channel.put(("fail", str(err)))
    except MemoryError:
        channel.put(("fail", "out of memory: the file is too large for this computer"))
    except Exception as exc:         # a bug of ours: one line on the page, details in the log
        traceback.print_exc()
        channel.put(("fail", f"internal error: {type(exc).__name__}: {exc} (details in "
                             f"{output}; please report it)"))
    channel.close()
    channel.join_thread()


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
        self._context = multiprocessing.get_context("spawn")
        self._running: multiprocessing.Process | None = None
        self._closing = False
        self._output_of_helpers()

    def _output_of_helpers(self) -> None:
        """multiprocessing's resource tracker (the process that frees the semaphores of the
        jobs' processes) started now, its output (a warning about a stopped job's semaphores)
        into the jobs' folder rather than the terminal."""
        from multiprocessing import resource_tracker

        self.folder.mkdir(parents=True, exist_ok=True)
        with open(self.folder / "helpers-output.txt", "a") as log:
            saved = os.dup(2)
            os.dup2(log.fileno(), 2)
            try:
                resource_tracker.ensure_running()
            finally:
                os.dup2(saved, 2)
                os.close(saved)

    def start(self, kind: str, title: str, stages: list[str], work, args=(),
              on_done=None) -> Job:
        """A new job running ``work(job, *args)`` in a process of its own.

        Parameters
        ----------
        kind, title : str
        stages : list of str
            The stage names known in advance.
        work : callable
            A module-level function ``work(job, *args) -> dict`` (the result the page shows;
            a ``"_extra"`` entry is handed back apart, as :attr:`Job.extra`); raises
            ApmcalError for the user's mistakes.
        args : tuple
            Its arguments (picklable).
        on_done : callable, optional
            Called with the job once it has ended (done or failed), on the server's side.
        """
        job_id = f"{next(self._ids)}-{int(time.time())}"
        folder = self.folder / f"job-{job_id}"
        folder.mkdir(parents=True, exist_ok=True)
        job = Job(job_id, kind, title, folder, list(stages))
        self.jobs[job_id] = job
        threading.Thread(target=self._run, args=(job, work, tuple(args), on_done),
                         name=f"apmcal-job-{job_id}", daemon=True).start()
        return job

    def _run(self, job: Job, work, args: tuple, on_done) -> None:
        if self._one_at_a_time.locked():
            job.apply("detail", "waiting for the calculation before it to finish", -1.0)
        with self._one_at_a_time:
            try:
                if self._closing:
                    job.fail("apmcal ui is stopping")
                    return
                job.state = "running"
                self._follow(job, work, args)
            except Exception as exc:      # the process could not even start: said, not hung
                traceback.print_exc()
                job.fail(f"internal error: the calculation could not start ({type(exc).__name__}: "
                         f"{exc})")
            finally:
                if on_done is not None:
                    on_done(job)

    def _follow(self, job: Job, work, args: tuple) -> None:
        """Start the job's process and apply what it says until it ends."""
        channel = self._context.Queue()
        output = job.folder / "output.txt"
        process = self._context.Process(
            target=_run_in_process, name=f"apmcal-job-{job.id}",
            args=(channel, job.id, str(job.folder), job.stages, work, args, str(output)))
        process.start()
        self._running = process
        try:
            while True:
                try:
                    message = channel.get(timeout=0.2)
                except queue.Empty:
                    if process.is_alive():
                        continue
                    try:                      # what it said just before it ended
                        message = channel.get(timeout=1.0)
                    except queue.Empty:
                        job.fail(self._why_ended(process))
                        return
                if message[0] == "finish":
                    job.finish(message[1], message[2])
                    return
                if message[0] == "fail":
                    job.fail(message[1])
                    return
                job.apply(*message)
        finally:
            process.join(STOP_WAIT_S)
            self._running = None

    def _why_ended(self, process) -> str:
        if self._closing:
            return "stopped: apmcal ui is stopping"
        code = process.exitcode
        if code is not None and code < 0 and -code == signal.SIGKILL:
            return "the calculation was killed (out of memory? the file may be too large)"
        return f"the calculation ended without a result (exit status {code})"

    def get(self, job_id: str) -> Job | None:
        """The job of that id, or None."""
        return self.jobs.get(job_id)

    def close(self) -> None:
        """Stop the calculation running (its process and those it started end), start no
        other."""
        self._closing = True
        process = self._running
        if process is None or not process.is_alive():
            return
        process.terminate()
        process.join(STOP_WAIT_S)
        if process.is_alive():
            process.kill()
            process.join(STOP_WAIT_S)
