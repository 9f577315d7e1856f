"""Fleet: calibration health across many logs of many vehicles (``apmcal fleet``).

A layer above calibration/report: each log is read and measured with the same library code the
single-log commands use (the per-log health figures are :mod:`apmcal.calibration.health`'s,
which ``apmcal log`` prints too), the per-log records are cached, grouped by vehicle and turned into
change points, drift rates, outliers and flags with a next step.

Modules:

- discover: the log files named by folders (searched recursively), globs and manifest files
- identity: a log's vehicle identity (board UID, MAVLink system id from the parameters or a
  .tlog's frame headers, the user's --vehicles mapping, and how it was found), firmware, frame,
  the calibration in force and the sensors' DEV_IDs
- extract: one log → one flat record: identity, calibration in force, health figures (never
  raises: a bad file becomes a row with its reason)
- cache: per-log Parquet cache keyed by a streamed hash of the file's content
- engine: the Dask (dask.distributed) run: a LocalCluster or an existing scheduler
- vehicles: per-vehicle time series, change points, drift rates with σ, robust outliers
- flags: flags with the reason and the next step
- output: flights.parquet, vehicles.parquet, flags.csv
- page: the self-contained DIR/index.html (embedded PNG trends, flag table)
- run: a whole run (discover, engine, analyse, flag, write), :func:`run_fleet`
"""
