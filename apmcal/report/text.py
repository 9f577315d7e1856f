"""Human and machine summaries of what was read and what was computed."""
from __future__ import annotations

import datetime

import numpy as np
from rich.text import Text

from apmcal.ardupilot.names import is_correction_param
from apmcal.core.recording import LogContents


def reader_notes(contents: LogContents) -> list[str]:
    """What the reader itself noted about the file (dropped columns, NaN parameters ignored, raw
    counts, ...), as opposed to the vehicle's own STATUSTEXT/MSG texts.

    The ArduPilot readers prefix their notes with "note: " or "warning: "; everything a CSV
    reader puts in ``messages`` is a note of its own (a CSV file carries no vehicle texts).

    Parameters
    ----------
    contents : LogContents

    Returns
    -------
    list of str
    """
    if contents.format == "csv":
        return list(contents.messages)
    return [m for m in contents.messages if m.startswith(READER_NOTE_PREFIXES)]


READER_NOTE_PREFIXES = ("note: ", "warning: ")


def summarize(contents: LogContents) -> dict:
    """Plain-dict summary of a source: sensors, rates, duration, parameters in force, firmware.

    ``messages`` holds the first 20 texts of the file (vehicle texts and reader notes, as read);
    ``notes`` every note of the reader (:func:`reader_notes`), which the text report prints.

    Parameters
    ----------
    contents : LogContents

    Returns
    -------
    dict
        Plain values: per recording its sample count, ``rate_hz`` [Hz] and ``duration_s`` [s]
        (rounded to 1 ms); the calibration parameters in force; ``recorded_utc`` (ISO 8601) and
        the clock it comes from; messages, notes and parameter changes as text.
    """
    recordings = []
    for rec in contents.recordings:
        recordings.append({
            "message": rec.message, "instance": rec.instance, "samples": len(rec),
            "sensors": rec.sensors, "rate_hz": round(rec.rate_hz, 3),
            "duration_s": round(rec.duration, 3), "corrected": rec.corrected, "frame": rec.frame,
            "has_temperature": "temp" in rec.data.columns,
        })
    in_force = {k: v for k, v in sorted(contents.params.items()) if is_correction_param(k)}
    return {"file": contents.path, "format": contents.format, "vehicle": contents.vehicle,
            "firmware": contents.firmware, "recordings": recordings,
            "calibration_params_in_force": in_force, "param_count": len(contents.params),
            "bytes_skipped": contents.bytes_skipped, "messages": contents.messages[:20],
            "notes": reader_notes(contents), "recorded_utc": _utc(contents.start_unix_s),
            "recorded_by": "ground station clock" if contents.format == "tlog" else "GPS time",
            "param_changes": [str(c) for c in contents.param_changes],
            "moving_share": moving_share(contents),
            "gyro_cal_at_boot": gyro_cal_at_boot(contents)}


def gyro_cal_at_boot(contents: LogContents) -> bool | None:
    """True when the vehicle re-measures its gyro offsets at every boot (INS_GYR_CAL not 0,
    its default 1 when the log does not say; ardupilot-facts.md), False when INS_GYR_CAL is 0,
    None for a CSV file (no vehicle to ask)."""
    if contents.format == "csv":
        return None
    return contents.params.get("INS_GYR_CAL", 1.0) != 0


FLIGHT_MOVING_FRACTION = 0.3    # moving in more than this share of 1 s windows: a flight log
MOVING_STD_RAD_S = 0.05         # gyro scatter within a 1 s window above this: moving (a bias,
                                # however large, has no scatter; a hand-held pose has little)


def moving_share(contents: LogContents) -> float | None:
    """The share of 1 s windows in which the first gyro recording moves (gyro scatter within
    the window above MOVING_STD_RAD_S); None for a CSV file (the user's own session) or too
    little data. A still-stretch calibration of a log moving in more than
    FLIGHT_MOVING_FRACTION of it is a flight log's."""
    if contents.format == "csv":
        return None
    rec = next((r for r in contents.recordings if "gyr" in r.sensors and len(r) > 1), None)
    if rec is None:
        return None
    per_window = max(2, int(round(rec.rate_hz))) if np.isfinite(rec.rate_hz) else 2
    xyz = rec.xyz("gyr")
    n = len(xyz) // per_window
    if n < 10:
        return None
    windows = xyz[: n * per_window].reshape(n, per_window, 3)
    with np.errstate(invalid="ignore"):
        moving = np.nanmax(np.nanstd(windows, axis=1), axis=1) > MOVING_STD_RAD_S
    return round(float(np.mean(moving)), 3)


def _utc(unix_s: float | None) -> str | None:
    """ISO 8601 UTC time of ``unix_s`` [s since 1970], to the second; None stays None."""
    if unix_s is None:
        return None
    when = datetime.datetime.fromtimestamp(unix_s, tz=datetime.timezone.utc)
    return when.isoformat(timespec="seconds")


# Everything below prints Text objects, never strings rich would parse: file names, notes and
# unit brackets such as "[m/s²]" are shown as they are (rich markup would eat "[m/s²]" and
# "[blue]"), whatever the console's markup setting.

def _note(text: str) -> Text:
    """A reader/solver note, its "warning:" prefix in yellow."""
    for prefix in ("warning:", "note:"):
        if text.startswith(prefix):
            return Text.assemble((prefix, "yellow" if prefix == "warning:" else ""),
                                 text[len(prefix):])
    return Text(text)


def print_summary(summary: dict, console, verbose: bool = True) -> None:
    """Render :func:`summarize` output with rich (the parameters in force only when
    ``verbose``: the report shows them beside the proposed ones).

    Parameters
    ----------
    summary : dict
        :func:`summarize` output.
    console : rich.console.Console
    verbose : bool
    """
    from rich import box
    from rich.table import Table

    head = Text.assemble((str(summary["file"]), "bold"), f" ({summary['format']})")
    what = (f"vehicle: {summary['vehicle'] or 'unknown'}; firmware: "
            f"{summary['firmware'] or 'unknown'}")
    if len(head.plain) + len(what) + 2 <= MAX_WIDTH:       # one line when it fits
        console.print(head + Text(f"; {what}"))
    else:
        console.print(head)
        console.print(Text(what))
    if summary.get("recorded_utc"):
        console.print(Text(f"recorded: {summary['recorded_utc']} ({summary['recorded_by']})"))
    # compact (no borders, one space between columns): fits 80 columns, so a piped run neither
    # wraps headers nor truncates cells ("acc,gyr,mag")
    table = Table(box=box.SIMPLE_HEAD, padding=(0, 0), collapse_padding=True, show_edge=False,
                  pad_edge=False)
    for header in ("message", "inst", "sensors", "samples", "rate [Hz]", "duration [s]",
                   "corrected", "frame"):
        table.add_column(Text(header))
    for r in summary["recordings"]:
        table.add_row(*[Text(str(c)) for c in (
            r["message"], r["instance"], ",".join(r["sensors"]), r["samples"],
            f"{r['rate_hz']:.1f}", f"{r['duration_s']:.1f}", r["corrected"], r["frame"])])
    console.print(table)
    params = summary["calibration_params_in_force"]
    if params and verbose:
        say(console, "calibration parameters in force: " +
            ", ".join(f"{k}={v:.6g}" for k, v in params.items()))
    elif not params:
        console.print(Text(f"calibration parameters in force: none found "
                           f"({summary['param_count']} parameters in the log)"))
    if summary["bytes_skipped"]:
        console.print(Text(f"damaged input: {summary['bytes_skipped']} bytes skipped",
                           style="yellow"))
    for change in summary.get("param_changes", []):
        console.print(_note(f"warning: while recording, {change}"))
    for note in summary.get("notes", []):
        note_text = _note(note)
        if len(note_text.plain) <= MAX_WIDTH:
            console.print(note_text)
        else:
            say(console, note_text)


# Report lines for the specialist: shown with --verbose only (the JSON keeps them all). A line
# is technical when it names a paper's equations, a statistics device or a fit's internals.
TECHNICAL_MARKERS = ("[Niespodziany]", "[Chow]", "[Oppong]", "antithetic", "Jacobian", "rank ",
                     "second-order fit bias", "coverage eigenvalues", "condition number",
                     "cannot be separated", "NOT determinable", "not determinable at",
                     "relative MSE", "β, γ, μ", "τ, ξ, ν", "R_f", "(1σ)", "huber", "averaged in blocks",
                     "≈ mean: the high-pass mean", "E not computed", "E is reported")


def is_technical(line: str) -> bool:
    """True for a solver report line that only a specialist needs (see TECHNICAL_MARKERS)."""
    return any(marker in line for marker in TECHNICAL_MARKERS)


GRADE_STYLE = {"good": "green", "usable": "yellow", "redo": "red", "not measured": "dim",
               "nothing to apply": "yellow"}
MAX_WIDTH = 100        # default report lines are wrapped at this many characters


def say(console, text, indent: str = "", style: str = "") -> None:
    """Print ``text`` (str or Text) wrapped at :data:`MAX_WIDTH` characters, continuation lines
    indented two more than ``indent``; never cut inside a word."""
    import textwrap

    plain = text.plain if isinstance(text, Text) else str(text)
    if len(indent) + len(plain) <= MAX_WIDTH:
        console.print(Text(indent) + (text if isinstance(text, Text) else Text(plain, style)))
        return
    for line in textwrap.wrap(plain, MAX_WIDTH, initial_indent=indent,
                              subsequent_indent=indent + "  ", break_on_hyphens=False):
        console.print(Text(line, style))


def _worst_first(sensors: dict) -> list:
    """(name, Verdict) of the measured sensors, worst grade first, then the not measured."""
    from apmcal.report.verdict import GRADES

    rank = {g: i for i, g in enumerate(reversed(GRADES))}
    return sorted(sensors.items(), key=lambda nv: rank.get(nv[1].grade, len(rank)))


def print_verdict(verdicts: dict, console, session_note: str = "") -> None:
    """The overall grade with each sensor's grade in one line, then ``session_note`` (what kind
    of session this was, e.g. a flight log), then per sensor, worst first: its grade, the reason
    and the next step.

    Parameters
    ----------
    verdicts : dict
        :func:`apmcal.report.verdict.judge` output (nothing printed without "overall").
    console : rich.console.Console
    session_note : str
        One plain sentence about the session ("" for none).
    """
    from apmcal.report.verdict import NAMES, NOTHING_TO_APPLY

    overall = verdicts.get("overall")
    if overall is None:
        return
    sensors = {n: v for n, v in verdicts.items() if n != "overall"}
    measured = [f"{NAMES[n]} {v.grade}" for n, v in sensors.items() if v.measured]
    missing = [NAMES[n] for n, v in sensors.items() if not v.measured]
    grades = ", ".join(measured) + (("; " if measured else "") + "not measured: "
                                    + ", ".join(missing) if missing else "")
    console.print(Text.assemble(("verdict: ", "bold"),
                                (overall.grade.upper(), f"bold {GRADE_STYLE[overall.grade]}"),
                                f" ({grades})"))
    if session_note:
        say(console, session_note, "  ")
    elif overall.grade == NOTHING_TO_APPLY:
        say(console, overall.reason, "  ")
    for name, v in _worst_first(sensors):
        grade = v.grade if v.measured else "not measured by this session"
        say(console, Text.assemble(f"{NAMES[name]}: ", (grade, GRADE_STYLE[v.grade]),
                                   f" — {v.reason}"), "  ")
        if v.next_step:
            say(console, f"next: {v.next_step}", "    ")


def raw_count_sensors(summary: dict | None) -> list[str]:
    """Sensors the reader kept in raw counts (its "<sensor>: raw sensor counts" notes)."""
    return [n.split(":")[0] for n in (summary or {}).get("notes", [])
            if "raw sensor counts" in n and n.split(":")[0] in ("acc", "gyr", "mag")]


def verdict_dict(calibration, proposal, raw_counts=(), gyro_cal_at_boot=None) -> dict:
    """The verdicts as plain dicts, for the JSON output.

    Parameters
    ----------
    calibration : Calibration
    proposal : ParamProposal or None
        As for :func:`apmcal.report.verdict.judge`.

    Returns
    -------
    dict
        sensor name (and "overall") → :meth:`apmcal.report.verdict.Verdict.to_dict`.
    """
    from apmcal.report.verdict import judge

    return {name: v.to_dict()
            for name, v in judge(calibration, proposal, raw_counts, gyro_cal_at_boot).items()}


def _vector(values, fmt: str) -> str:
    """``(a, b, c)`` with each value in ``fmt``."""
    return "(" + ", ".join(format(v, fmt) for v in np.ravel(values)) + ")"


def _decimals(sigma: float) -> int:
    """Decimal places that show two significant digits of ``sigma`` (0 for σ ≥ 10)."""
    if not np.isfinite(sigma) or sigma <= 0:
        return 6
    return int(max(0, 1 - np.floor(np.log10(sigma))))


def with_sigma(values, sigma) -> str:
    """``(v1, v2, v3) ± (s1, s2, s3)``: each value to the precision its σ supports (σ with two
    significant digits); without σ, four significant digits and no ± part."""
    values = np.ravel(values)
    if sigma is None:
        return _vector(values, "+.4g")
    sigma = np.ravel(sigma)
    vals = ", ".join(f"{v:+.{_decimals(s)}f}" for v, s in zip(values, sigma))
    sigs = ", ".join("< 1e-9" if s <= 0 else f"{s:.2g}" for s in sigma)
    return f"({vals}) ± ({sigs})"


#: proposal notes printed by default (the others, about what ArduPilot's parameters cannot hold,
#: go under --verbose)
DEFAULT_NOTES = ("withheld", "re-measured", "COMPASS_OFS is minus", "INS_ACCOFFS = INS_ACCSCAL",
                 "unknown: assumed")

MISSION_PLANNER = "Mission Planner (Config > Full Parameter List > Load from file)"
QGROUNDCONTROL = "QGroundControl (Vehicle Setup > Parameters > Tools > Load from file)"


def _notes(proposal, verbose: bool) -> list[str]:
    """The proposal's notes to print: the ones that concern the values proposed, or all."""
    notes = []
    for note in proposal.notes:
        if "INS_ACCOFFS = INS_ACCSCAL" in note and not any(
                n.startswith("INS_ACC") and "OFFS" in n for n in proposal.values):
            continue                                   # about a value that is withheld
        if verbose or any(k in note for k in DEFAULT_NOTES):
            notes.append(note.replace(" (see the identifiability report)",
                                      "" if verbose else " (--verbose shows why)"))
    return notes


def print_apply(proposal, verdicts: dict, console, link: str | None = None,
                param_file: str | None = None, writable=None,
                gyro_cal_at_boot: bool | None = None) -> None:
    """"apply it": the exact commands that put the proposal on the vehicle and take it off,
    or why there is nothing to put there.

    Parameters
    ----------
    proposal : ParamProposal or None
    verdicts : dict
        :func:`apmcal.report.verdict.judge` output.
    console : rich.console.Console
    link : str, optional
        The vehicle's connection (live), else "LINK".
    param_file : str, optional
        The parameter file written (--param-file), else a placeholder and how to write it.
    writable : Writable, optional
        What of the proposal may be written (:class:`apmcal.ardupilot.limits.Writable`);
        default: all of its values.
    gyro_cal_at_boot : bool, optional
        The vehicle re-measures its gyro offsets at every boot (None: unknown).
    """
    from apmcal.ardupilot.limits import ACCEPT_REDO_FLAG

    console.print(Text("apply it:", style="bold"))
    overall = verdicts.get("overall")
    values = {} if proposal is None else proposal.values
    if proposal is None:
        say(console, "no parameters: this file names no firmware; add --firmware 3.2 or "
                     "--firmware 3.3+ to get them", "  ")
        return
    if not values:
        say(console, "nothing to apply: no parameter is proposed", "  ")
        return
    kept = values if writable is None else writable.values
    if writable is not None and writable.redo:
        say(console, "not advised: " + redo_words(verdicts) + "; its values are left out of "
                     f"the parameter file and the upload ({ACCEPT_REDO_FLAG} puts them in); "
                     "calibrate again first", "  ")
    elif overall is not None and overall.grade == "redo":
        say(console, "not advised: the verdict is REDO; calibrate again first", "  ")
    if not kept:
        say(console, "nothing to apply: every value proposed is withheld (below)", "  ")
        return
    if all(n.startswith("INS_GYR") for n in kept):
        if gyro_cal_at_boot:
            say(console, "only gyro offsets are proposed, and ArduPilot re-measures those at "
                         "every boot (INS_GYR_CAL is not 0): applying them changes nothing you "
                         "will notice", "  ")
        elif gyro_cal_at_boot is False:
            say(console, "only gyro offsets are proposed; INS_GYR_CAL is 0 on this vehicle, so "
                         "it keeps the offsets it is given: these replace the ones it flies "
                         "with", "  ")
    link = link or "LINK"
    target = param_file or "cal.param"
    if not param_file:
        say(console, f"write the file: add --param-file {target} to this command, then", "  ")
    say(console, f"apmcal upload {link} {target}   (backs up the vehicle's parameters first)",
        "  ")
    say(console, f"or load {target} in {MISSION_PLANNER}", "  ")
    say(console, f"or in {QGROUNDCONTROL}", "  ")
    say(console, f"undo: apmcal restore {link} BACKUP.param   (the backup the upload names)",
        "  ")
    if link == "LINK":
        say(console, "LINK: the vehicle, e.g. /dev/ttyACM0 (USB) or udp:127.0.0.1:14550", "  ")


def redo_words(verdicts: dict) -> str:
    """"the compass is graded REDO" (the sensors graded redo, in words)."""
    from apmcal.report.verdict import NAMES

    names = [NAMES[n] for n, v in verdicts.items() if n in NAMES and v.grade == "redo"]
    if not names:
        return "the verdict is REDO"
    return ("the " + " and the ".join(names) + (" are" if len(names) > 1 else " is")
            + " graded REDO")


def print_proposal(proposal, console, in_force: dict | None = None,
                   verbose: bool = False, writable=None, target: str | None = None) -> None:
    """The proposed parameters beside the values in force (old → new), those the firmware
    would refuse, those withheld for a REDO grade (``writable``, written to ``target``), and
    the notes that concern them."""
    if proposal is None:
        return
    in_force = in_force or {}
    console.print(Text(f"proposed parameters (ArduPilot {proposal.generation}; in force → "
                       "proposed):", style="bold"))
    width = max((len(n) for n in proposal.values), default=0)
    for name, value in proposal.values.items():
        old = in_force.get(name)
        old_txt = "?" if old is None else f"{old:.6g}"
        console.print(Text(f"  {name:<{width}} {old_txt} → {value:.6g}"))
    for name, why in proposal.rejected.items():
        say(console, Text.assemble(("not proposed", "red"), f" {name}: {why}"), "  ")
    if writable is not None:
        for line in writable.lines(target or "the parameter file or the vehicle"):
            say(console, Text(line, style="red" if line.startswith("not") else "yellow"), "  ")
    for note in _notes(proposal, verbose):
        say(console, f"note: {note}", "  ")


def session_note(calibration, summary: dict | None = None) -> str:
    """One sentence on what kind of session this was, when it limits what it measures
    ("" otherwise): a flight log or a single still pose measures the gyro offsets only."""
    moving = (summary or {}).get("moving_share")
    if calibration.method == "static" and moving is not None and moving > FLIGHT_MOVING_FRACTION:
        return ("this is a flight log: it measures the gyro offsets only (at a still moment); "
                "the accelerometer and compass need calibration sessions of their own")
    if calibration.method == "static":
        return ("one still stretch measures the gyro offsets only; the accelerometer needs six "
                "faces, the compass turning")
    return ""


def frame_words(calibration, summary: dict | None) -> str:
    """In which frame the offsets and matrices are: the frame of the recording calibrated."""
    used = calibration.report.recording or ""
    for r in (summary or {}).get("recordings", []):
        if used.startswith(f"{r['message']} "):
            frame = r["frame"]
            return (f"{frame} frame, as logged" + (" (after AHRS_ORIENTATION)"
                                                   if frame == "body" else ""))
    return "the frame of the data"


def print_calibration(calibration, proposal, console, verbose: bool = False, *,
                      summary: dict | None = None, link: str | None = None,
                      param_file: str | None = None, writable=None) -> None:
    """Render a Calibration top down: the verdict (first line), how to apply it, the proposed
    parameters beside the values in force, then the numbers and the findings (the technical
    ones, fit internals and the proposal's cost notes only when ``verbose``).

    Parameters
    ----------
    calibration : Calibration
        Offsets shown in m/s², rad/s, mGauss, drift per s.
    proposal : ParamProposal or None
        The ArduPilot parameters proposed for it.
    console : rich.console.Console
    verbose : bool
        Also the technical report lines and :func:`apmcal.report.lines.verbose_lines`.
    summary : dict, optional
        :func:`summarize` of the file: the parameters in force, the frame, the session kind.
    link : str, optional
        The vehicle's connection string (live) for the apply commands.
    param_file : str, optional
        The parameter file written, for the apply commands.
    writable : Writable, optional
        What of the proposal may be written (:class:`apmcal.ardupilot.limits.Writable`).
    """
    from apmcal.report.verdict import judge, plain

    at_boot = (summary or {}).get("gyro_cal_at_boot")
    verdicts = judge(calibration, proposal, raw_count_sensors(summary), at_boot)
    print_verdict(verdicts, console, session_note(calibration, summary))
    print_apply(proposal, verdicts, console, link, param_file, writable, at_boot)
    print_proposal(proposal, console, (summary or {}).get("calibration_params_in_force"),
                   verbose, writable, param_file)
    print_numbers(calibration, console, verbose, summary)
    said = {v.reason for v in verdicts.values()}
    for line in dict.fromkeys(calibration.report.warnings):      # each once
        core = line.removeprefix("magnetometer not calibrated: ").split(
            "not measured by this session: ", 1)[-1]
        if any(plain(core) in r for r in said):
            continue                                 # already the verdict's reason
        say(console, Text.assemble(("warning:", "yellow"), f" {plain(line)}"), "  ")


def print_numbers(calibration, console, verbose: bool, summary: dict | None = None) -> None:
    """The estimates with their σ, in their frame, then the solver's findings."""
    from apmcal.report.lines import calibration_lines, verbose_lines
    from apmcal.report.verdict import plain

    used = calibration.report.recording
    console.print(Text.assemble(("method:", "bold"), f" {calibration.method}"
                                + (f" on {used}" if used else "")))
    say(console, f"numbers: apmcal's model, corrected = matrix · (raw − offset), in the "
                 f"{frame_words(calibration, summary)}; ± is 1σ", "  ")
    units = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}
    for name, cal in calibration.sensors.items():
        console.print(Text(f"  {name}: offset [{units[name]}] = "
                           f"{with_sigma(cal.offset, cal.sigma.get('offset'))}"))
        with np.printoptions(precision=4, suppress=True):
            console.print(Text("    matrix = " + str(cal.matrix).replace("\n", "\n             ")))
        if np.any(cal.drift):
            console.print(Text(f"    drift [{units[name]}/s] = {_vector(cal.drift, '+.3g')}"))
    # identifiability, residuals, verdicts of the fits
    for line in calibration_lines(calibration.report, calibration.sensors):
        if verbose or not is_technical(line):
            say(console, line if verbose else plain(line), "  ")
    if verbose:
        for line in verbose_lines(calibration.report):      # the six-face misfit, Earth rate
            say(console, line, "  ")
