"""A fleet's folder chosen on the page and measured (what ``apmcal fleet`` does): the folders of
this computer to choose from, and the job that runs :func:`apmcal.fleet.run.run_fleet` with its
progress, the flags, and the fleet's own page with each vehicle's trends.

The results go into ``apmcal-files/fleet-<folder name>-<hash of its path>/`` so that measuring
the same folder again takes the logs already measured from the cache.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

from apmcal.core.errors import ApmcalError

MAX_LISTED = 500        # folders listed at most per folder


def list_folder(path: str | None, start: Path) -> dict:
    """A folder's sub-folders and how many logs lie directly in it (JSON-ready).

    Parameters
    ----------
    path : str or None
        The folder (None or "": ``start``).
    start : Path
        Where the browsing starts (the folder ``apmcal ui`` was started in).

    Raises
    ------
    ApmcalError
        When the folder does not exist or cannot be read.
    """
    from apmcal.fleet.discover import is_log_name

    folder = Path(path).expanduser() if path else Path(start)
    try:
        folder = folder.resolve()
        entries = sorted(os.scandir(folder), key=lambda e: e.name.lower())
    except FileNotFoundError:
        raise ApmcalError("no such folder", str(folder)) from None
    except NotADirectoryError:
        raise ApmcalError("not a folder", str(folder)) from None
    except OSError as exc:
        raise ApmcalError(f"cannot read the folder ({exc.strerror or exc})", str(folder)) \
            from None
    folders, logs = [], 0
    for e in entries:
        try:
            if e.is_dir() and not e.name.startswith("."):
                folders.append(e.name)
            elif e.is_file() and is_log_name(Path(e.name)):
                logs += 1
        except OSError:          # a broken link, a folder we may not look into
            continue
    return {"path": str(folder), "parent": str(folder.parent) if folder.parent != folder
            else None, "folders": folders[:MAX_LISTED], "more": max(0, len(folders) - MAX_LISTED),
            "logs_here": logs}


def out_folder(files: Path, folder: Path) -> Path:
    """The results' folder for the fleet in ``folder``: the same folder every time."""
    digest = hashlib.sha256(str(folder).encode()).hexdigest()[:8]
    return Path(files) / f"fleet-{folder.name or 'root'}-{digest}"


def stages() -> list[str]:
    """The progress bar's stages."""
    return ["finding logs", "measuring logs", "flags and page"]


def run(job, folder: str, files: Path) -> dict:
    """The job's work: measure every log under ``folder``; the flags and the fleet's page.

    Raises
    ------
    ApmcalError
        Dask missing (with the install line), no logs found, an output folder not writable.
    """
    from apmcal.fleet.engine import require_dask
    from apmcal.fleet.run import run_fleet

    require_dask()
    where = Path(folder).expanduser().resolve()
    if not where.is_dir():
        raise ApmcalError("not a folder", str(where))
    out = out_folder(files, where)
    out.mkdir(parents=True, exist_ok=True)
    job.stage("finding logs", str(where))
    total = {"n": 0, "done": 0}

    def found(n: int) -> None:
        total["n"] = n
        job.stage("measuring logs", f"0 of {n} logs")

    def one_done() -> None:
        total["done"] += 1
        job.detail(f"{total['done']} of {total['n']} logs", total["done"] / max(total["n"], 1))
        if total["done"] == total["n"]:
            job.stage("flags and page")

    result = run_fleet([str(where)], out, on_found=found, progress=one_done)
    job.pages["fleet"] = out
    f = result.flights
    not_read = f[f["status"] != "ok"]
    return {"kind": "fleet", "folder": str(where), "out": str(out),
            "logs": int(len(f)), "read": int((f["status"] == "ok").sum()),
            "cached": int(f["cached"].fillna(False).astype(bool).sum()),
            "vehicles": int(len(result.vehicles)), "action_flags": result.action_flags,
            "flags": [{k: _plain(v) for k, v in row.items()}
                      for row in result.flags.to_dict("records")],
            "not_read": [{"path": str(r.path), "reason": str(r.reason)}
                         for r in not_read.itertuples()],
            "page": f"/api/jobs/{job.id}/pages/fleet/index.html"}


def _plain(value):
    """A table cell as JSON takes it (NaN and timestamps as text)."""
    if isinstance(value, float):
        return None if value != value else value
    if isinstance(value, (int, str, bool)) or value is None:
        return value
    return str(value)
