"""Per-log record cache: one Parquet file per log, keyed by a hash of the file's whole content.

The key is the SHA-256 of the bytes (read in 1 MiB blocks, never the whole file at once) plus
:data:`apmcal.fleet.extract.EXTRACT_VERSION`, so a rerun measures only new or changed files, a
renamed or copied log is found again, and a change of the extraction redoes everything. Writes
go to a temporary name first and are renamed, so an interrupted run leaves no half record.
"""
from __future__ import annotations

import hashlib
import os
import uuid
from pathlib import Path

from apmcal.fleet.extract import EXTRACT_VERSION

BLOCK = 1 << 20


def content_key(path) -> str:
    """"<sha256 of the content>-v<EXTRACT_VERSION>" of the file at ``path`` (OSError escapes)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(BLOCK), b""):
            h.update(block)
    return f"{h.hexdigest()}-v{EXTRACT_VERSION}"


class RecordCache:
    """Records in ``folder``/<key>.parquet (a one-row table each)."""

    def __init__(self, folder):
        self.folder = Path(folder)

    def _file(self, key: str) -> Path:
        return self.folder / f"{key}.parquet"

    def load(self, key: str) -> dict | None:
        """The cached record of ``key``, or None (absent or unreadable)."""
        import pandas as pd

        f = self._file(key)
        if not f.exists():
            return None
        try:
            row = pd.read_parquet(f).iloc[0].to_dict()
        except Exception:        # a damaged cache file is a miss, never a stop
            return None
        return {k: (None if _is_missing(v) else _plain(v)) for k, v in row.items()}

    def store(self, key: str, record: dict) -> None:
        """Write ``record`` under ``key`` (atomic rename)."""
        import pandas as pd

        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self.folder / f".{key}.{uuid.uuid4().hex}.tmp"
        pd.DataFrame([record]).to_parquet(tmp, engine="pyarrow", index=False)
        os.replace(tmp, self._file(key))


def _is_missing(v) -> bool:
    try:
        return v is None or (isinstance(v, float) and v != v)
    except TypeError:
        return False


def _plain(v):
    """numpy scalars as Python ones (records stay plain for Dask and JSON)."""
    return v.item() if hasattr(v, "item") else v
