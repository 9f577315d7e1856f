"""The log files a fleet run processes: folders (searched recursively), globs, manifest files.

A manifest is a text file ending in .txt, .lst or .manifest with one path (or glob) per line,
relative to the manifest's folder; blank lines and lines starting with ``#`` are skipped.
"""
from __future__ import annotations

import glob
from pathlib import Path

from apmcal.core.errors import ApmcalError

LOG_SUFFIXES = (".bin", ".log", ".tlog")
MANIFEST_SUFFIXES = (".txt", ".lst", ".manifest")


def is_log_name(path: Path) -> bool:
    """True when the file name ends in a log suffix (.bin, .log, .tlog; any case)."""
    return path.suffix.lower() in LOG_SUFFIXES


def _in_folder(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file() and is_log_name(p)]


def _manifest(path: Path, seen: set) -> list[Path]:
    if path in seen:
        raise ApmcalError("manifest includes itself", str(path))
    seen.add(path)
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as e:
        raise ApmcalError(f"cannot read manifest: {e.strerror or e}", str(path)) from None
    found: list[Path] = []
    for n, line in enumerate(lines, 1):
        item = line.strip()
        if not item or item.startswith("#"):
            continue
        target = Path(item) if Path(item).is_absolute() else path.parent / item
        try:
            found += _expand(str(target), seen)
        except ApmcalError as err:
            raise ApmcalError(f"{err.why} (manifest line {n}: {item!r})", str(path)) from None
    return found


def _expand(item: str, seen: set) -> list[Path]:
    path = Path(item)
    if path.is_dir():
        return _in_folder(path)
    if path.is_file():
        if path.suffix.lower() in MANIFEST_SUFFIXES:
            return _manifest(path.resolve(), seen)
        return [path]
    matches = sorted(glob.glob(item, recursive=True))
    if not matches:
        raise ApmcalError("no such file or folder, and no file matches it as a glob", item)
    out: list[Path] = []
    for m in matches:
        p = Path(m)
        out += _in_folder(p) if p.is_dir() else ([p] if p.is_file() else [])
    return out


def discover(inputs: list[str]) -> list[Path]:
    """The log files named by ``inputs``, absolute, sorted, each once.

    Files named directly are taken whatever their suffix (a file that is no log becomes a row
    with its reason later); folders and globs that name folders contribute their .bin, .log and
    .tlog files, recursively.

    Parameters
    ----------
    inputs : list of str
        Folders, files, globs (``**`` recursive) or manifest files.

    Returns
    -------
    list of Path

    Raises
    ------
    ApmcalError
        When an input names nothing, or nothing at all is found.
    """
    seen: set = set()
    found: list[Path] = []
    for item in inputs:
        found += _expand(item, seen)
    unique = sorted({p.resolve() for p in found})
    if not unique:
        raise ApmcalError("no log files (.bin, .log, .tlog) found", ", ".join(inputs))
    return unique
