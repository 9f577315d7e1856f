"""Human and machine summaries of what was read and what was computed."""
from __future__ import annotations

import numpy as np

from apmcal.recording import LogContents

CALIBRATION_PARAM_PREFIXES = ("INS_ACC", "INS_GYR", "COMPASS_OFS", "COMPASS_DIA", "COMPASS_ODI",
                              "COMPASS_MOT", "COMPASS_ORIENT", "AHRS_ORIENTATION")


def summarize(contents: LogContents) -> dict:
    """Plain-dict summary of a source: sensors, rates, duration, parameters in force, firmware."""
    recordings = []
    for rec in contents.recordings:
        recordings.append({
            "message": rec.message, "instance": rec.instance, "samples": len(rec),
            "sensors": rec.sensors, "rate_hz": round(rec.rate_hz, 3),
            "duration_s": round(rec.duration, 3), "corrected": rec.corrected, "frame": rec.frame,
            "has_temperature": "temp" in rec.data.columns,
        })
    in_force = {k: v for k, v in sorted(contents.params.items())
                if k.startswith(CALIBRATION_PARAM_PREFIXES)}
    return {"file": contents.path, "format": contents.format, "vehicle": contents.vehicle,
            "firmware": contents.firmware, "recordings": recordings,
            "calibration_params_in_force": in_force, "param_count": len(contents.params),
            "bytes_skipped": contents.bytes_skipped, "messages": contents.messages[:20]}


def print_summary(summary: dict, console) -> None:
    """Render :func:`summarize` output with rich."""
    from rich.table import Table

    console.print(f"[bold]{summary['file']}[/] ({summary['format']}); vehicle: "
                  f"{summary['vehicle'] or 'unknown'}; firmware: {summary['firmware'] or 'unknown'}")
    table = Table("message", "inst", "sensors", "samples", "rate [Hz]", "duration [s]",
                  "corrected", "frame")
    for r in summary["recordings"]:
        table.add_row(r["message"], str(r["instance"]), ",".join(r["sensors"]), str(r["samples"]),
                      f"{r['rate_hz']:.1f}", f"{r['duration_s']:.1f}", str(r["corrected"]),
                      r["frame"])
    console.print(table)
    params = summary["calibration_params_in_force"]
    if params:
        console.print("calibration parameters in force: " +
                      ", ".join(f"{k}={v:.6g}" for k, v in params.items()))
    else:
        console.print(f"calibration parameters in force: none found "
                      f"({summary['param_count']} parameters in the log)")
    if summary["bytes_skipped"]:
        console.print(f"[yellow]damaged input: {summary['bytes_skipped']} bytes skipped[/]")


def print_calibration(calibration, proposal, console) -> None:
    """Render a Calibration and its ArduPilot parameter proposal."""
    used = calibration.report.get("recording")
    console.print(f"[bold]method:[/] {calibration.method}" + (f" on {used}" if used else ""))
    units = {"acc": "m/s²", "gyr": "rad/s", "mag": "mGauss"}
    for name, cal in calibration.sensors.items():
        sig = cal.sigma.get("offset")
        off = ", ".join(f"{v:+.6g}" for v in cal.offset)
        sig_txt = "" if sig is None else " ± (" + ", ".join(f"{v:.2g}" for v in np.ravel(sig)) + ")"
        console.print(f"  {name}: offset [{units[name]}] = ({off}){sig_txt}")
        with np.printoptions(precision=6, suppress=True):
            console.print("    matrix = " + str(cal.matrix).replace("\n", "\n             "))
        if np.any(cal.drift):
            console.print(f"    drift [{units[name]}/s] = {cal.drift}")
    for line in calibration.report.get("warnings", []):
        console.print(f"  [yellow]warning:[/] {line}")
    if proposal is not None:
        console.print(f"[bold]ArduPilot parameters ({proposal.generation}):[/]")
        for name, value in proposal.values.items():
            console.print(f"  {name} {value:.6g}")
        for name, why in proposal.rejected.items():
            console.print(f"  [red]not proposed[/] {name}: {why}")
        for note in proposal.notes:
            console.print(f"  note: {note}")
