"""A whole fleet run: find the logs, run the tasks, analyse per vehicle, flag, write outputs."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd


@dataclass
class FleetResult:
    """What a fleet run produced (the tables also written to ``out``)."""

    flights: pd.DataFrame
    vehicles: pd.DataFrame
    flags: pd.DataFrame
    out: Path

    @property
    def action_flags(self) -> int:
        """Number of flags that need doing (level "action")."""
        return int((self.flags["level"] == "action").sum())


def run_fleet(inputs: list[str], out, *, workers: int | None = None, scheduler: str | None = None,
              site=None, cache: bool = True, serial: bool = False, progress=None,
              on_found=None) -> FleetResult:
    """Run ``apmcal fleet`` on ``inputs`` (folders, files, globs, manifests) into ``out``.

    Parameters
    ----------
    workers, scheduler : see :func:`apmcal.fleet.engine.run_dask`
    site : (lat, lon, alt), optional
        For logs without a GPS fix.
    cache : bool
        Use ``out``/cache (records keyed by content hash).
    serial : bool
        Run in this process without Dask (debugging, the benchmark's baseline).
    progress : callable, optional
        Called once per finished log.
    on_found : callable, optional
        Called with the number of logs found, before any is processed.

    Raises
    ------
    ApmcalError
        Bad input (nothing found, output folder not writable, scheduler unreachable).
    """
    from apmcal.fleet import engine
    from apmcal.fleet.discover import discover
    from apmcal.fleet.flags import all_flags
    from apmcal.fleet.output import check_out_dir, write_tables
    from apmcal.fleet.page import write_page
    from apmcal.fleet.vehicles import analyse, flights_table

    out = Path(out)
    engine.require_dask()
    paths = discover(inputs)
    check_out_dir(out)
    if on_found:
        on_found(len(paths))
    cache_dir = str((out / "cache").resolve()) if cache else None
    if serial:
        records = engine.run_serial(paths, cache_dir, site, progress)
    else:
        records = engine.run_dask(paths, cache_dir, site, workers=workers, scheduler=scheduler,
                                  progress=progress)
    flights = flights_table(records)
    vehicles, changes, outliers = analyse(flights)
    flags = all_flags(flights, vehicles, changes, outliers)
    write_tables(out, flights, vehicles, flags)
    write_page(out, flights, vehicles, flags)
    return FleetResult(flights, vehicles, flags, out)
