"""The run's tables on disk: flights.parquet (one row per log, failures with their reason),
vehicles.parquet (one row per vehicle) and flags.csv (one row per flag)."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from apmcal.core.errors import ApmcalError


def check_out_dir(out: Path) -> None:
    """Create the output folder, or raise ApmcalError before any work when it cannot be."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".apmcal-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise ApmcalError(f"cannot write the output folder: {e.strerror or e}; stopped before "
                          "any work", str(out)) from None


def _parquet_ready(df: pd.DataFrame) -> pd.DataFrame:
    """Object columns of mixed Python types as strings (Parquet needs one type per column)."""
    df = df.copy()
    for col in df.columns:
        if df[col].dtype == object:
            kinds = {type(v) for v in df[col] if v is not None and not (isinstance(v, float) and v != v)}
            if len(kinds) > 1 or (kinds and not kinds <= {str, bool}):
                df[col] = df[col].map(lambda v: None if v is None or (isinstance(v, float)
                                                                      and v != v) else str(v))
    return df


def write_tables(out: Path, flights: pd.DataFrame, vehicles: pd.DataFrame,
                 flags: pd.DataFrame) -> list[Path]:
    """Write the three tables into ``out``; the paths written."""
    paths = [out / "flights.parquet", out / "vehicles.parquet", out / "flags.csv"]
    try:
        _parquet_ready(flights).to_parquet(paths[0], engine="pyarrow", index=False)
        _parquet_ready(vehicles).to_parquet(paths[1], engine="pyarrow", index=False)
        flags.to_csv(paths[2], index=False)
    except OSError as e:
        raise ApmcalError(f"cannot write the results: {e.strerror or e}", str(out)) from None
    return paths
