"""A whole fleet run: find the logs, run the tasks, analyse per vehicle, flag, write outputs."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from apmcal.core.errors import ApmcalError


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
              on_found=None, vehicles=None) -> FleetResult:
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
    vehicles : path, optional
        The user's mapping of logs to vehicles (:class:`apmcal.fleet.identity.VehicleMap`),
        over what the logs say.

    Raises
    ------
    ApmcalError
        Bad input (nothing found, a bad vehicle mapping, output folder not writable, scheduler
        unreachable), checked before any work; or no log could be read (the tables and the
        page, which list every log with its reason, are written first).
    """
    from apmcal.fleet import engine
    from apmcal.fleet.discover import discover
    from apmcal.fleet.flags import all_flags
    from apmcal.fleet.identity import VehicleMap
    from apmcal.fleet.output import check_out_dir, write_tables
    from apmcal.fleet.page import write_page
    from apmcal.fleet.vehicles import analyse, flights_table

    out = Path(out)
    engine.require_dask()
    paths = discover(inputs)
    mapping = VehicleMap(vehicles) if vehicles is not None else None
    check_out_dir(out)
    if on_found:
        on_found(len(paths))
    cache_dir = str((out / "cache").resolve()) if cache else None
    if serial:
        records = engine.run_serial(paths, cache_dir, site, progress)
    else:
        records = engine.run_dask(paths, cache_dir, site, workers=workers, scheduler=scheduler,
                                  progress=progress)
    if mapping is not None:
        mapping.apply(records)
    flights = flights_table(records)
    table, changes, outliers = analyse(flights)
    flags = all_flags(flights, table, changes, outliers)
    write_tables(out, flights, table, flags)
    write_page(out, flights, table, flags)
    if not (flights["status"] == "ok").any():
        raise ApmcalError(f"none of the {len(flights)} log(s) could be read (every reason in "
                          f"{out / 'flights.parquet'} and {out / 'index.html'}); the first: "
                          f"{flights['reason'].iloc[0]}")
    return FleetResult(flights, table, flags, out)
