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
        import pyarrow.parquet as pq

        f = self._file(key)
        if not f.exists():
            return None
        try:
            return pq.read_table(f).to_pylist()[0]
        except Exception:        # a damaged cache file is a miss, never a stop
            return None

    def store(self, key: str, record: dict) -> None:
        """Write ``record`` under ``key`` (atomic rename).

        pyarrow directly, without the pandas schema metadata, column statistics or the stored
        Arrow schema, all of which a one-row file does not need: 9 kB a log instead of 40 kB.
        """
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self.folder / f".{key}.{uuid.uuid4().hex}.tmp"
        pq.write_table(pa.Table.from_pylist([record]), tmp, write_statistics=False,
                       compression="none", store_schema=False)
        os.replace(tmp, self._file(key))
