"""The SITL twin's round trip on ArduPilot's own firmware: diagnose a log, write its twin as
SIM_* parameters, record the same session again on SITL booted with them, and diagnose the
first log against that recording.

    python benchmarks/gap_sitl_roundtrip.py [--configs drift warmup poses both] [--kind bin]
                                            [--keep DIR]

For each configuration (SIM_* injections on a fresh ArduPilot 4.7 SITL, ``../shared/
ardupilot-sitl``; the session a script of holds and turns of its ``calibration`` model,
tests/gap_sitl_sessions.py):

1. record the "real" session, both logs (.tlog, dataflash .BIN);
2. ``apmcal gap REAL --write-twin twin.parm --json real.json``: the gap before and after the
   effects it selects (what the diagnosis promises), each selected effect's parameters against
   the injected SIM_* (in units of the σ the diagnosis gives them);
3. record the same script on a fresh SITL booted with twin.parm (its values as boot defaults:
   they hold from the first sample), a few seconds longer;
4. ``apmcal gap REAL --twin-log TWIN --json roundtrip.json``: the gap of the real log against
   that recording, and whatever effect is still left (none, beyond chance, when the twin
   closes the gap).

Printed: per configuration one line of the promise and one of the round trip, then a table
(Markdown) for docs/sitl-twin.md. Exits 1 when a round trip leaves an effect or a recovered
parameter is beyond 3σ of its injection.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "sitl")]

SITE = ["--lat", "-35.363262", "--lon", "149.165237"]   # SITL's default home
TEMPERATURE = {"SIM_IMUT1_ENABLE": 1, "SIM_IMUT1_TMIN": -10, "SIM_IMUT1_TMAX": 80,
               "SIM_IMUT_TCONST": 100,
               "SIM_IMUT1_GYR1_X": 300, "SIM_IMUT1_GYR1_Y": -200, "SIM_IMUT1_GYR1_Z": 150,
               "SIM_IMUT1_ACC1_X": 3000, "SIM_IMUT1_ACC1_Y": -2000, "SIM_IMUT1_ACC1_Z": 4000}
POSED = {"SIM_DRIFT_SPEED": 0, "SIM_IMUT_FIXED": 30,
         "SIM_ACC1_BIAS_X": 0.25, "SIM_ACC1_BIAS_Y": -0.15, "SIM_ACC1_BIAS_Z": 0.3,
         "SIM_ACC1_SCAL_X": 1.02, "SIM_ACC1_SCAL_Y": 0.985, "SIM_ACC1_SCAL_Z": 1.01,
         "SIM_GYR1_SCALE_X": 2.0, "SIM_GYR1_SCALE_Y": -1.5, "SIM_GYR1_SCALE_Z": 1.0}
FACES = [(0, 0, 0), (180, 0, 0), (90, 0, 0), (-90, 0, 0), (0, 89, 0), (0, -89, 0)]
POSES = [step for roll, pitch, yaw in FACES for step in (("hold", roll, pitch, yaw, 12),)] + \
    [("hold", 0, 0, 0, 8), ("spin", 1.0, (1, 0, 0), 2 * np.pi), ("hold", 0, 0, 0, 8),
     ("spin", 1.0, (0, 1, 0), 2 * np.pi), ("hold", 0, 0, 0, 8),
     ("spin", 1.0, (0, 0, 1), 2 * np.pi), ("hold", 0, 0, 0, 8)]
CONFIGS = {
    "drift": dict(script=[("until", 420)], boot={},
                  truth={"triangle_drift": {"speed": 0.05}}),
    "warmup": dict(script=[("until", 240)], boot=dict(TEMPERATURE, SIM_DRIFT_SPEED=0),
                   truth={"temperature_drift": {
                       "gyro_coef": [v * 1e-6 for v in (300, -200, 150)],
                       "acc_coef": [v * 1e-6 for v in (3000, -2000, 4000)]}}),
    "poses": dict(script=POSES, boot=POSED,
                  truth={"gyro_scale": {"scale": [1.02, 0.985, 1.01]}}),
    "both": dict(script=[("until", 400)], boot=TEMPERATURE,
                 truth={"triangle_drift": {"speed": 0.05},
                        "temperature_drift": {
                            "gyro_coef": [v * 1e-6 for v in (300, -200, 150)],
                            "acc_coef": [v * 1e-6 for v in (3000, -2000, 4000)]}}),
}


def gap(*argv) -> dict:
    """``apmcal gap`` in a fresh process; its JSON."""
    out = Path(tempfile.mkstemp(suffix=".json")[1])
    done = subprocess.run([sys.executable, "-m", "apmcal", "gap", *map(str, argv), *SITE,
                           "--json", str(out), "--quiet"], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"apmcal gap {' '.join(map(str, argv))}: {done.stderr.strip()}")
    data = json.loads(out.read_text())
    out.unlink()
    return data


def recovered(result: dict, truth: dict) -> list[tuple[str, float, float, float]]:
    """(parameter, injected, recovered, z) of each injected effect parameter the diagnosis
    reports with a σ."""
    rows = []
    for name, params in truth.items():
        entry = next((e for e in result["effects"] if e["name"] == name), None)
        for key, want in params.items():
            got = (entry or {}).get("params", {}).get(key)
            if got is None:
                rows.append((f"{name}.{key}", np.nan, np.nan, np.inf))
                continue
            for i, (w, v, s) in enumerate(zip(np.ravel(want), np.ravel(got["value"]),
                                              np.ravel(got["sigma"]))):
                rows.append((f"{name}.{key}[{i}]" if np.size(want) > 1 else f"{name}.{key}",
                             float(w), float(v), float((v - w) / s) if s else np.inf))
    return rows


def round_trip(name: str, spec: dict, kind: str, folder: Path) -> dict:
    from gap_sitl_sessions import record

    from apmcal.ardupilot.paramfile import read_param_file

    real = record(folder / "real", spec["script"], spec["boot"])
    log = real.bin if kind == "bin" else real.tlog
    twin_parm = folder / "twin.parm"
    first = gap(log, "--write-twin", twin_parm)
    # held a few seconds longer: each command to the simulator shifts what follows a little
    twin = record(folder / "twin", list(spec["script"]) + [("until", real.seconds + 5)],
                  read_param_file(twin_parm))
    second = gap(log, "--twin-log", twin.bin if kind == "bin" else twin.tlog)
    left = [e["name"] for e in second["effects"] if e["significant"]]
    rows = recovered(first, spec["truth"])
    return dict(name=name, selected=first["selected"], before=first["gap"]["heldout"],
                promised=first["after"]["heldout"], roundtrip=second["gap"]["heldout"],
                left=left, params=rows, seconds=real.seconds,
                wall=real.wall_s + twin.wall_s)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--kind", choices=["bin", "tlog"], default="bin",
                    help="the log diagnosed: dataflash (default) or telemetry")
    ap.add_argument("--keep", type=Path, default=None, help="keep the logs in this folder")
    args = ap.parse_args(argv)
    from ardupilot_sitl import unavailable_reason

    reason = unavailable_reason()
    if reason:
        print(reason)
        return 0
    base = args.keep or Path(tempfile.mkdtemp(prefix="gap-roundtrip-"))
    results, failed = [], False
    try:
        for name in args.configs:
            folder = base / name
            shutil.rmtree(folder, ignore_errors=True)
            r = round_trip(name, CONFIGS[name], args.kind, folder)
            results.append(r)
            worst = max((abs(z) for *_, z in r["params"]), default=0.0)
            failed |= bool(r["left"]) or worst > 3
            print(f"{name}: selected {', '.join(r['selected']) or 'nothing'}; held-out gap "
                  f"{r['before']:.3g} → {r['promised']:.3g} nats/sample promised; "
                  f"parameters {worst:.2g} σ off at most", flush=True)
            print(f"{name}: against the SITL twin's recording {r['roundtrip']:.3g} "
                  f"nats/sample; left: {', '.join(r['left']) or 'nothing'}", flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(base, ignore_errors=True)
    print()
    print(f"| configuration ({args.kind}) | selected | held-out gap before → promised "
          "[nats/sample] | against the recorded twin | effects left | recovered (z = Δ/σ) |")
    print("|---|---|---|---|---|---|")
    for r in results:
        params = "; ".join(f"{p} {v:.4g} (injected {w:.4g}, z {z:+.1f})"
                           for p, w, v, z in r["params"])
        print(f"| {r['name']} | {', '.join(r['selected']) or '-'} | {r['before']:.3g} → "
              f"{r['promised']:.3g} | {r['roundtrip']:.3g} | {', '.join(r['left']) or 'none'} "
              f"| {params} |")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
