"""How often ``apmcal gap`` gets tests/test_gap_firmware.py's claims right, over fresh
recordings of ArduPilot's own firmware (SITL, ``../shared/ardupilot-sitl``).

    python benchmarks/gap_firmware_rates.py [--runs 10] [--keep DIR] [--sessions drift ...]
                                            [--roundtrip]

SITL's noise, and the simulated second at which its telemetry starts (after the parameter
download, at the speedup asked for), differ between recordings: one recording per test run
passes or fails by chance where a claim is not reliable. This records each session of the test
(its SIM_* at boot, its length) ``--runs`` times, diagnoses the .tlog and the dataflash log of
each as the test does, and prints per recording the slow effects selected, then per claim how
many of the recordings met it. ``--roundtrip``: also the warm-up's round trip of the test
(--write-twin, SITL booted with the twin records the session again, ``--twin-log``) on each
warm-up recording: closed when it exits 0 with no effect significant. ``--keep``: the logs and
results stay in DIR (recordings already there are reused). Needs the firmware; about 15 s of
recording and 10-20 s of diagnosis per session and log on two busy cores.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "sitl")]

from gap_sitl_sessions import record  # noqa: E402
from test_gap_firmware import SESSIONS  # noqa: E402

from apmcal.ardupilot.paramfile import read_param_file  # noqa: E402
from apmcal.cli import main  # noqa: E402
from apmcal.diagnosis.output.result import GapResult  # noqa: E402
from apmcal.diagnosis.session.decimate import FINE_EFFECTS  # noqa: E402

# the slow effects each session's claim expects (tests/test_gap_firmware.py)
CLAIMS = {"drift": {"triangle_drift"}, "warmup": {"temperature_drift"},
          "both": {"temperature_drift", "triangle_drift"}}


def recorded(folder: Path, name: str) -> tuple[Path, Path]:
    """The .tlog and .bin of session ``name`` in ``folder``, recorded when not yet there."""
    if not (folder / "done").exists():
        shutil.rmtree(folder, ignore_errors=True)
        spec = dict(SESSIONS[name])
        until = spec.pop("until")
        rec = record(folder / "sitl", [("until", until)], spec.pop("boot", None), **spec)
        shutil.copy(rec.tlog, folder / "s.tlog")
        shutil.copy(rec.bin, folder / "s.bin")
        shutil.rmtree(folder / "sitl")
        (folder / "done").write_text("")
    return folder / "s.tlog", folder / "s.bin"


def diagnosed(log: Path, out: Path, extra=()) -> GapResult | None:
    """``apmcal gap LOG`` as the test runs it (None: it exited with an error)."""
    if not out.exists() and main(["gap", str(log), "--json", str(out), "--quiet", *extra]):
        return None
    return GapResult.load(out)


def round_trip(folder: Path, log: Path) -> str:
    """The test's round trip of the warm-up ``log``: "closed", or what was left."""
    parm = folder / "twin.parm"
    if not parm.exists():
        main(["gap", str(log), "--quiet", "--write-twin", str(parm),
              "--json", str(folder / "twin-of.json")])
    twin_folder = folder / "twin"
    if not (twin_folder / "s.bin").exists():
        shutil.rmtree(twin_folder, ignore_errors=True)
        rec = record(twin_folder / "sitl", [("until", SESSIONS["warmup"]["until"] + 5)],
                     read_param_file(parm))
        shutil.copy(rec.bin, twin_folder / "s.bin")
        shutil.rmtree(twin_folder / "sitl")
    again = diagnosed(log, folder / "roundtrip.json", ["--twin-log", str(twin_folder / "s.bin")])
    if again is None:
        return "error (exit 2)"
    left = [e["name"] for e in again.effects if e["significant"]]
    return "closed" if not again.selected and not left else f"left {left}"


def main_() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--keep", type=Path)
    parser.add_argument("--sessions", nargs="+", default=list(CLAIMS), choices=list(CLAIMS))
    parser.add_argument("--roundtrip", action="store_true")
    args = parser.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="gap_firmware_rates_"))
    met: dict[tuple, list] = {}
    for run in range(args.runs):
        for name in args.sessions:
            folder = root / f"{name}{run}"
            tlog, dataflash = recorded(folder, name)
            for kind, log in (("tlog", tlog), ("bin", dataflash)):
                result = diagnosed(log, folder / f"{kind}.json")
                slow = None if result is None else set(result.selected) - set(FINE_EFFECTS)
                met.setdefault((name, kind), []).append(slow == CLAIMS[name])
                print(f"{name:7s} {run:2d} {kind:4s} {sorted(slow) if slow is not None else 'error'}",
                      flush=True)
            if args.roundtrip and name == "warmup":
                outcome = round_trip(folder, dataflash)
                met.setdefault(("warmup", "round trip"), []).append(outcome == "closed")
                print(f"warmup  {run:2d} round trip: {outcome}", flush=True)
    print("\n| session | log | claim met |\n|---|---|---|")
    for (name, kind), hits in met.items():
        print(f"| {name} | {kind} | {sum(hits)} of {len(hits)} |")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
