"""Logs dropped on the page: calibrated (what ``apmcal log`` does), temperature-calibrated
(``apmcal tcal``) or diagnosed (``apmcal gap``), one job for all the files dropped together.

Each file gives one entry for the page: the verdict first (the report package's own words and
HTML), the parameters in force → proposed, the downloads (.param for Mission Planner and
MAVProxy, .params for QGroundControl), then the figures and the full text report; tcal and gap
entries carry their report page (their figures) instead. A file that cannot be read or
calibrated gives an entry with its one-line error; the other files go on.
"""
from __future__ import annotations

import base64
import io
from dataclasses import replace
from pathlib import Path

from apmcal.core.errors import ApmcalError

#: what may be dropped: the formats the readers take (read_log sniffs the bytes in any case)
LOG_SUFFIXES = (".tlog", ".bin", ".log", ".csv")
#: the most one drop may upload [bytes]: a 400 Hz dataflash log of an hour is about 120 MB;
#: beyond this the browser and this computer hold the whole file in memory for little gain
MAX_UPLOAD_BYTES = 512 * 1024 * 1024
KINDS = ("log", "tcal", "gap")
#: the two parameter file formats offered: suffix → (format, who reads it)
PARAM_FORMATS = {".param": ("param", "Mission Planner, MAVProxy"),
                 ".params": ("qgc", "QGroundControl")}


def check_site(lat: float | None, lon: float | None) -> tuple[float | None, float | None]:
    """The site [deg] as given, or ApmcalError naming what is wrong (one line)."""
    if lat is not None and not -90 <= lat <= 90:
        raise ApmcalError(f"latitude {lat:g} is not in -90..90 [deg]")
    if lon is not None and not -180 <= lon <= 180:
        raise ApmcalError(f"longitude {lon:g} is not in -180..180 [deg]")
    if lon is not None and lat is None:
        raise ApmcalError("a longitude needs the latitude too (the magnetic field model needs "
                          "both; the latitude alone is fine)")
    return lat, lon


def safe_name(name: str) -> str:
    """A dropped file's name without any folder part (never a path out of the job's folder)."""
    base = Path(name.replace("\\", "/")).name.strip() or "log"
    return "".join(c if c.isprintable() and c not in '/\0' else "_" for c in base)[:200]


def console_text(render) -> str:
    """What ``render(console)`` prints on a plain 100-column console, as text."""
    from rich.console import Console

    buf = io.StringIO()
    render(Console(file=buf, width=100, markup=False, emoji=False, highlight=False,
                   color_system=None, soft_wrap=True))
    return buf.getvalue()


def named(err: ApmcalError, path: Path, name: str) -> ApmcalError:
    """``err`` naming the file as dropped instead of its copy on this computer."""
    if err.path is None or Path(err.path) == path:
        err.path = name
    return err


def stages_for(kind: str, names: list[str]) -> list[str]:
    """The progress bar's stages for ``kind`` over the files ``names``."""
    per_file = {"log": ["reading", "calibrating", "figures"],
                "tcal": ["reading", "fitting", "figures"],
                "gap": ["reading", "diagnosing", "report"]}[kind]
    return [f"{step} {name}" for name in names for step in per_file]


def run_files(job, kind: str, files: list[tuple[str, Path]], lat, lon) -> dict:
    """The job's work: every file of ``files`` ((name, path) pairs) in turn.

    Returns
    -------
    dict
        ``{"kind": kind, "entries": [...]}``, one entry per file (see the module docstring).
    """
    work = {"log": log_entry, "tcal": tcal_entry, "gap": gap_entry}[kind]
    entries = []
    for index, (name, path) in enumerate(files):
        folder = job.folder / f"file-{index}"
        folder.mkdir(exist_ok=True)
        try:
            entry = work(job, index, name, path, folder, lat, lon)
        except ApmcalError as err:
            entry = {"name": name, "error": str(named(err, path, name))}
        except MemoryError:
            entry = {"name": name, "error": f"{name}: out of memory: too large for this computer"}
        if "error" in entry:        # this file's stages from the one that failed on
            ours = [s for s in stages_for(kind, [name]) if s in job.stages]
            job.skip(ours[ours.index(job.stages[job.current]):]
                     if job.current >= 0 and job.stages[job.current] in ours else ours)
        entries.append(entry)
    return {"kind": kind, "entries": entries}


def read_checked(job, name: str, path: Path):
    """The file read and its units checked (ApmcalError for anything else)."""
    from apmcal.sources import read_log
    from apmcal.sources.units import require_plausible_units

    job.stage(f"reading {name}")
    contents = read_log(path)
    require_plausible_units(contents)       # a sensor in impossible units is not data
    return contents


def _downloads(job, index: int, stem: str, write) -> list[dict]:
    """Both parameter files written by ``write(path, fmt)``, registered for download."""
    out = []
    for suffix, (fmt, who) in PARAM_FORMATS.items():
        file_name = f"{stem}{suffix}"
        path = job.folder / f"file-{index}" / file_name
        path.parent.mkdir(parents=True, exist_ok=True)
        write(path, fmt)
        job.files[f"{index}/{file_name}"] = path
        out.append({"label": f"{file_name} ({who})",
                    "url": f"/api/jobs/{job.id}/files/{index}/{file_name}"})
    return out


def _page(job, index: int, folder: Path) -> str:
    """The report page in ``folder`` registered; its address."""
    job.pages[str(index)] = folder
    return f"/api/jobs/{job.id}/pages/{index}/index.html"


# --------------------------------------------------------------------------- apmcal log
def log_entry(job, index: int, name: str, path: Path, folder: Path, lat, lon) -> dict:
    """One file as ``apmcal log`` sees it: a flight's compass check, or its calibration."""
    from apmcal.calibration.flight import calibrate_flight_log

    job.stage(f"reading {name}", "is it a flight?")
    site = (lat, lon) if lat is not None and lon is not None else None
    flight, lacking = calibrate_flight_log(path, site)
    if flight is not None:
        return flight_entry(job, index, name, path, flight, folder)
    entry = session_entry(job, index, name, path, lat, lon)
    if lacking:
        entry["notes"] = [f"compass in flight: not checked — {lacking}"]
    return entry


def session_entry(job, index: int, name: str, path: Path, lat, lon) -> dict:
    """Calibrate one log: verdict, proposal, downloads, figures, the text report."""
    from apmcal.core.options import Options

    contents = read_checked(job, name, path)
    job.stage(f"calibrating {name}")
    report = calibrate_contents(contents, name, Options("auto", lat, lon))
    job.stage(f"figures {name}")
    return report_entry(job, index, name, report, contents)


def calibrate_contents(contents, name: str, opts):
    """The :class:`~apmcal.report.session.SessionReport` of ``contents`` calibrated with
    ``opts`` (:class:`~apmcal.core.options.Options`), naming the file ``name``."""
    from apmcal.calibration.log import calibrate_log
    from apmcal.report.session import SessionReport

    report = replace(SessionReport.build(contents), path=name)
    return report.with_calibration(*calibrate_log(contents, opts))


def report_entry(job, index: int, name: str, report, contents) -> dict:
    """The page's entry of a :class:`~apmcal.report.session.SessionReport` (a log's or a live
    session's): the report package's verdict and figures, the proposal, the downloads."""
    from apmcal.report.html import session_figures, verdict_block

    verdicts = report.verdict
    overall = verdicts.get("overall")
    writable = report.writable
    entry = {"name": name, "kind": "session", "grade": overall.grade if overall else None,
             "verdict_html": verdict_block(verdicts), "proposal": proposal_rows(report),
             "downloads": [], "figures": [], "notes": []}
    if report.proposal is None:
        entry["notes"].append("no parameter file: this file names no firmware (a CSV file); "
                              "`apmcal log FILE --firmware 3.2` or `3.3+` writes one")
    elif writable.values:
        stem = Path(name).stem or "cal"
        entry["downloads"] = _downloads(job, index, stem,
                                        lambda p, fmt: report.write_params(p, fmt))
    elif writable.withheld:
        entry["notes"].append("nothing to write: every value proposed is withheld (below)")
    for caption, png in session_figures(report, contents):
        entry["figures"].append({"caption": caption,
                                 "png": base64.b64encode(png).decode("ascii")})
    entry["text"] = console_text(lambda c: (report.print_calibration(c), c.print(),
                                            report.print_summary(c)))
    return entry


def proposal_rows(report) -> dict | None:
    """The proposal beside the values in force: generation, (name, in force, proposed, why
    withheld or None) rows, and the proposal's notes. What may be written is the report's
    :attr:`~apmcal.report.session.SessionReport.writable` (none of a sensor graded REDO, none
    out of the firmware's limits): the others are shown with the reason."""
    proposal = report.proposal
    if proposal is None:
        return None
    in_force = report.summary.get("calibration_params_in_force", {})
    withheld = report.writable.withheld
    values = {**proposal.values, **{n: None for n in withheld if n not in proposal.values}}
    return {"generation": proposal.generation,
            "rows": [[n, in_force.get(n), v, withheld.get(n)] for n, v in values.items()],
            "notes": list(proposal.notes)}


def flight_entry(job, index: int, name: str, path: Path, flight, folder: Path) -> dict:
    """A flight log: each compass's heading error in force and proposed, its page, files."""
    from apmcal.ardupilot.paramfile import write_param_file
    from apmcal.calibration.flight_proposal import flight_firmware, flight_writable
    from apmcal.report.html import write_flight_html

    job.stage(f"calibrating {name}", "the compass in flight")
    entry = {"name": name, "kind": "flight", "text": "\n".join(flight.lines()),
             "downloads": [], "notes": []}
    log_params, generation = flight_firmware(path)
    writable = flight_writable(flight, log_params, generation)
    entry["notes"] += [f"not written: {n}: {why}" for n, why in writable.withheld.items()]
    if writable.values:
        entry["downloads"] = _downloads(
            job, index, Path(name).stem or "compass",
            lambda p, fmt: write_param_file(p, writable.values,
                                            f"apmcal flight compass fit of {name}", fmt=fmt,
                                            generation=generation))
    job.stage(f"figures {name}")
    write_flight_html(flight, folder / "report")
    entry["page"] = _page(job, index, folder / "report")
    return entry


# --------------------------------------------------------------------------- apmcal tcal
def tcal_entry(job, index: int, name: str, path: Path, folder: Path, lat, lon) -> dict:
    """One warm-up log's temperature calibration: what is proposed, its page and files."""
    from apmcal.ardupilot.paramfile import write_param_file
    from apmcal.calibration.tcal import TemperatureCalibration, calibrate_temperature
    from apmcal.report.html import write_tcal_html
    from apmcal.report.tcal import print_tcal

    contents = read_checked(job, name, path)
    job.stage(f"fitting {name}")
    tcal = TemperatureCalibration(calibrate_temperature(contents))
    values = tcal.params()
    withheld = [r.withheld for r in tcal.results if r.withheld]
    imus = [{"instance": r.instance, "source": r.source, "proposed": not r.withheld,
             "why": r.withheld or f"INS_TCAL{r.instance + 1}_ENABLE 1 over "
                                  f"{r.tmin_c:.1f}-{r.tmax_c:.1f} °C"} for r in tcal.results]
    entry = {"name": name, "kind": "tcal", "imus": imus, "downloads": [], "notes": [],
             "text": console_text(lambda c: print_tcal(tcal.results, c))}
    if values:
        entry["downloads"] = _downloads(
            job, index, f"{Path(name).stem}-tcal",
            lambda p, fmt: write_param_file(p, values, "\n".join([f"apmcal tcal of {name}",
                                                                  *withheld]), fmt=fmt))
        entry["notes"].append("INS_TCALn_ENABLE takes effect at the vehicle's next reboot")
    else:
        entry["notes"].append("nothing to apply: no temperature drift is significant")
    job.stage(f"figures {name}")
    write_tcal_html(tcal, name, folder / "report")
    entry["page"] = _page(job, index, folder / "report")
    return entry


# --------------------------------------------------------------------------- apmcal gap
def gap_entry(job, index: int, name: str, path: Path, folder: Path, lat, lon) -> dict:
    """One log's gap diagnosis: the verdict and what to do first, its page, the twin file."""
    from apmcal.core.options import Options
    from apmcal.diagnosis.output.advice import advice
    from apmcal.diagnosis.output.report import write_report
    from apmcal.diagnosis.output.summary import print_summary, verdict
    from apmcal.diagnosis.reading import LogReading
    from apmcal.diagnosis.run import diagnose
    from apmcal.diagnosis.twin.file import write_twin

    job.stage(f"reading {name}")
    session, warnings, error = LogReading(str(path), Options(lat_deg=lat, lon_deg=lon)).session()
    if error is not None:
        raise error
    job.stage(f"diagnosing {name}")
    diagnosis = diagnose(session, None, seed=0, progress=lambda text: job.detail(text))
    job.stage(f"report {name}")
    result = diagnosis.result
    write_report(diagnosis, folder / "report")
    stem = Path(name).stem or "gap"
    twin = folder / f"{stem}-twin.parm"
    write_twin(diagnosis, twin)
    job.files[f"{index}/{twin.name}"] = twin
    saved = folder / f"{stem}-gap.json"
    result.save(saved)
    job.files[f"{index}/{saved.name}"] = saved
    return {"name": name, "kind": "gap", "verdict": verdict(result), "advice": advice(result),
            "notes": list(warnings),
            "downloads": [{"label": f"{twin.name} (ArduPilot SITL parameters of the twin)",
                           "url": f"/api/jobs/{job.id}/files/{index}/{twin.name}"},
                          {"label": f"{saved.name} (the whole result)",
                           "url": f"/api/jobs/{job.id}/files/{index}/{saved.name}"}],
            "text": console_text(lambda c: print_summary(result, c)),
            "page": _page(job, index, folder / "report")}
