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
            "param_changes": [str(c) for c in contents.param_changes]}


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


def print_summary(summary: dict, console) -> None:
    """Render :func:`summarize` output with rich.

    Parameters
    ----------
    summary : dict
        :func:`summarize` output.
    console : rich.console.Console
    """
    from rich import box
    from rich.table import Table

    console.print(Text.assemble((str(summary["file"]), "bold"),
                                f" ({summary['format']}); vehicle: "
                                f"{summary['vehicle'] or 'unknown'}; firmware: "
                                f"{summary['firmware'] or 'unknown'}"))
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
    if params:
        console.print(Text("calibration parameters in force: " +
                           ", ".join(f"{k}={v:.6g}" for k, v in params.items())))
    else:
        console.print(Text(f"calibration parameters in force: none found "
                           f"({summary['param_count']} parameters in the log)"))
    if summary["bytes_skipped"]:
        console.print(Text(f"damaged input: {summary['bytes_skipped']} bytes skipped",
                           style="yellow"))
    for change in summary.get("param_changes", []):
        console.print(_note(f"warning: while recording, {change}"))
    for note in summary.get("notes", []):
        console.print(_note(note))


# Report lines for the specialist: shown with --verbose only (the JSON keeps them all). A line
# is technical when it names a paper's equations, a statistics device or a fit's internals.
TECHNICAL_MARKERS = ("[Niespodziany]", "[Chow]", "[Oppong]", "antithetic", "Jacobian", "rank ",
                     "second-order fit bias", "coverage eigenvalues", "condition number",
                     "cannot be separated", "NOT determinable", "not determinable at",
                     "relative MSE", "β, γ, μ", "τ, ξ, ν", "R_f", "(1σ)", "huber", "averaged in blocks")


def is_technical(line: str) -> bool:
    """True for a solver report line that only a specialist needs (see TECHNICAL_MARKERS)."""
    return any(marker in line for marker in TECHNICAL_MARKERS)


GRADE_STYLE = {"good": "green", "usable": "yellow", "redo": "red"}


def print_verdict(verdicts: dict, console) -> None:
    """The overall grade, its reason and next step, then one line per sensor.

    Parameters
    ----------
    verdicts : dict
        :func:`apmcal.report.verdict.judge` output (nothing printed without "overall").
    console : rich.console.Console
    """
    from apmcal.report.verdict import NAMES

    overall = verdicts.get("overall")
    if overall is None:
        return
    sensors = {n: v for n, v in verdicts.items() if n != "overall"}
    console.print(Text.assemble(("verdict: ", "bold"),
                                (overall.grade.upper(), f"bold {GRADE_STYLE[overall.grade]}"),
                                " (" + ", ".join(f"{NAMES[n]} {v.grade}"
                                                 for n, v in sensors.items()) + ")"))
    for name, v in sensors.items():
        console.print(Text.assemble(f"  {NAMES[name]}: ", (v.grade, GRADE_STYLE[v.grade]),
                                    f" — {v.reason}"))
        if v.next_step:
            console.print(Text(f"    next: {v.next_step}"))


def verdict_dict(calibration, proposal) -> dict:
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

    return {name: v.to_dict() for name, v in judge(calibration, proposal).items()}


def _vector(values, fmt: str) -> str:
    """``(a, b, c)`` with each value in ``fmt``."""
    return "(" + ", ".join(format(v, fmt) for v in np.ravel(values)) + ")"


def print_calibration(calibration, proposal, console, verbose: bool = False) -> None:
    """Render a Calibration: the verdict first, then the numbers, the solver's report lines
    (technical ones only when ``verbose``) and the ArduPilot parameter proposal.

    Parameters
    ----------
    calibration : Calibration
        Offsets shown in m/s², rad/s, mGauss, drift per s.
    proposal : ParamProposal or None
        The ArduPilot parameters proposed for it.
    console : rich.console.Console
    verbose : bool
        Also the technical report lines and :func:`apmcal.report.lines.verbose_lines`.
    """
    from apmcal.report.verdict import judge

    print_verdict(judge(calibration, proposal), console)
    used = calibration.report.recording
    console.print(Text.assemble(("method:", "bold"), f" {calibration.method}"
                                + (f" on {used}" if used else "")))
    units = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}
    for name, cal in calibration.sensors.items():
        sig = cal.sigma.get("offset")
        sig_txt = "" if sig is None else " ± " + _vector(sig, ".2g")
        console.print(Text(f"  {name}: offset [{units[name]}] = {_vector(cal.offset, '+.6g')}"
                           f"{sig_txt}"))
        with np.printoptions(precision=6, suppress=True):
            console.print(Text("    matrix = " + str(cal.matrix).replace("\n", "\n             ")))
        if np.any(cal.drift):
            console.print(Text(f"    drift [{units[name]}/s] = {cal.drift}"))
    from apmcal.report.lines import calibration_lines, verbose_lines

    # identifiability, residuals, verdicts of the fits
    for line in calibration_lines(calibration.report, calibration.sensors):
        if verbose or not is_technical(line):
            console.print(Text(f"  {line}"))
    for line in calibration.report.warnings:
        console.print(Text.assemble("  ", ("warning:", "yellow"), f" {line}"))
    if verbose:
        for line in verbose_lines(calibration.report):      # the six-face misfit, Earth rate
            console.print(Text(f"  {line}"))
    if proposal is not None:
        console.print(Text(f"ArduPilot parameters ({proposal.generation}):", style="bold"))
        for name, value in proposal.values.items():
            console.print(Text(f"  {name} {value:.6g}"))
        for name, why in proposal.rejected.items():
            console.print(Text.assemble("  ", ("not proposed", "red"), f" {name}: {why}"))
        for note in proposal.notes:
            console.print(Text(f"  note: {note}"))
