"""The ``apmcal fleet`` command: calibration health across a fleet's logs, on Dask."""
from __future__ import annotations

import sys

EXIT_FLAGS = 1
MAX_LINES = 30          # per list in the summary; the rest is in the output files


def add_parser(sub) -> None:
    """Register ``apmcal fleet`` on the sub-command parsers ``sub``."""
    p = sub.add_parser("fleet", help="calibration health across many logs of many vehicles "
                                     "(Dask; pip install 'apmcal[fleet]')")
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help="folders (searched recursively for .bin/.log/.tlog), log files, globs "
                        "or manifest files (.txt/.lst/.manifest, one path a line)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: flights.parquet, vehicles.parquet, flags.csv, "
                        "index.html, cache/")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local worker processes (default: the core count; 0: in this process "
                        "without Dask)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="run on an existing Dask cluster (its workers must see the paths and "
                        "DIR; start them with --nthreads 1)")
    p.add_argument("--lat", type=float, default=None, help="site latitude [deg] for logs "
                   "without a GPS fix (the WMM field for the heading error)")
    p.add_argument("--lon", type=float, default=None, help="site longitude [deg]")
    p.add_argument("--vehicles", default=None, metavar="FILE",
                   help="your own mapping of logs to vehicles, one 'FOLDER_OR_GLOB = NAME' a "
                        "line, over what the logs say (for logs without a board UID or a "
                        "distinct system id)")
    p.add_argument("--no-cache", action="store_true", help="measure every log again")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")


def run(args) -> int:
    """Run ``apmcal fleet``; exit 1 when a flag needs action, 0 when none (2 on bad input, or
    when no log could be read, is the caller's: ApmcalError)."""
    from apmcal.core.errors import ApmcalError
    from apmcal.fleet.engine import require_dask
    from apmcal.fleet.run import run_fleet

    require_dask()
    if args.workers is not None and args.workers < 0:
        raise ApmcalError("--workers must be 0 or more")
    if args.scheduler and args.workers is not None:
        raise ApmcalError("--scheduler uses the cluster's workers: leave out --workers")
    if (args.lat is None) != (args.lon is None):
        raise ApmcalError("--lat and --lon go together")
    if args.lat is not None and not (-90 <= args.lat <= 90 and -180 <= args.lon <= 180):
        raise ApmcalError("--lat must lie in -90..90 and --lon in -180..180")
    site = (args.lat, args.lon, 0.0) if args.lat is not None else None
    from rich.console import Console
    from rich.progress import Progress

    with Progress(transient=True, disable=args.quiet or not sys.stderr.isatty(),
                  console=Console(stderr=True)) as bar:
        task = bar.add_task("logs", total=None)
        result = run_fleet(args.paths, args.out, workers=args.workers or None,
                           scheduler=args.scheduler, site=site, cache=not args.no_cache,
                           serial=args.workers == 0,
                           on_found=lambda n: bar.update(task, total=n),
                           progress=lambda: bar.advance(task), vehicles=args.vehicles)
    if not args.quiet:
        print_summary(result)
    return EXIT_FLAGS if result.action_flags else 0


def print_summary(result) -> None:
    """A few lines: logs read / failed / from cache, vehicles, flags, where the outputs are."""
    f = result.flights
    ok = int((f["status"] == "ok").sum())
    cached = int(f["cached"].fillna(False).astype(bool).sum())
    print(f"{len(f)} logs: {ok} read ({cached} from the cache), {len(f) - ok} not read; "
          f"{len(result.vehicles)} vehicles")
    for r in result.vehicles.head(MAX_LINES).itertuples():
        print(f"  {r.vehicle_id}: {r.flights} flight(s), identified by {r.identified_by}")
    if len(result.vehicles) > MAX_LINES:
        print(f"  ... {len(result.vehicles) - MAX_LINES} more vehicles (vehicles.parquet)")
    bad = f[f["status"] != "ok"]
    for r in bad.head(MAX_LINES).itertuples():
        print(f"  not read: {r.reason}")
    if len(bad) > MAX_LINES:
        print(f"  ... {len(bad) - MAX_LINES} more not read (flights.parquet, index.html)")
    for r in result.flags.head(MAX_LINES).itertuples():
        print(f"  [{r.level}] {r.vehicle_id}: {r.reason} -> {r.next_step}")
    if len(result.flags) > MAX_LINES:
        print(f"  ... {len(result.flags) - MAX_LINES} more flags (flags.csv, index.html)")
    print(f"{result.action_flags} action flag(s); results in {result.out}/ (index.html, "
          f"flights.parquet, vehicles.parquet, flags.csv)")
