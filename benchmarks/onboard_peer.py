"""apmcal against ArduPilot's own onboard calibrators, side by side on ArduPilot's own firmware.

    python benchmarks/onboard_peer.py [--seeds 1 2 3 4 5] [--speedup 20]

For each seed, the same errors are injected through SIM_* into two fresh SITL copters (the
`calibration` model; tests/firmware_sessions.py draws them: accelerometer bias and scale, gyro
bias, compass hard and soft iron) with the same wrong calibration already in force (COMPASS_SCALE
≠ 1 among it), and each is calibrated by one tool:

- ArduPilot: its accelerometer calibration (MAV_CMD_PREFLIGHT_CALIBRATION, each of the six
  poses it asks for confirmed with MAV_CMD_ACCELCAL_VEHICLE_POS), then its compass calibration
  (MAV_CMD_DO_START_MAG_CAL, autosave) while the model turns about the axes of
  tests/firmware_sessions.TURN_AXES until it reports success; the values it saved are read back.
- apmcal: `apmcal live --guide ardupilot6 --auto` (no site: the firmware's world has standard
  gravity and no Earth rate), then `apmcal live --duration` with the site while the model turns
  the same way; the values it proposes.

Both turn the model between poses at 90°/s, as a person would. Each parameter's error is taken
against the exact calibration of the firmware README's table (INS_ACCOFFS = SIM_ACC1_BIAS, ...,
COMPASS_DIA/ODI = SIM_MAG1_DIA/ODI at COMPASS_SCALE 1: a calibration that writes a scale is
compared by the matrix it applies, SCALE × DIA/ODI). Times are the vehicle's (simulated)
seconds from the first command to the last value: the time a person spends; wall seconds are
printed too. The table printed at the end is docs/onboard-peer.md's.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl"), str(ROOT / "tests")]

from ardupilot_sitl import ArduPilotSitl, unavailable_reason  # noqa: E402
from firmware_sessions import (  # noqa: E402
    TURN_AXES,
    calibration_in_force,
    compass_turns,
    exact_calibration,
    guided_six_faces,
    injected_errors,
)

SITE = ("--lat", "-35.363262", "--lon", "149.165237")
GROUPS = {"INS_ACCOFFS [m/s²]": [f"INS_ACCOFFS_{a}" for a in "XYZ"],
          "INS_ACCSCAL": [f"INS_ACCSCAL_{a}" for a in "XYZ"],
          "COMPASS_OFS [mGauss]": [f"COMPASS_OFS_{a}" for a in "XYZ"],
          "COMPASS_DIA (× SCALE)": [f"COMPASS_DIA_{a}" for a in "XYZ"],
          "COMPASS_ODI (× SCALE)": [f"COMPASS_ODI_{a}" for a in "XYZ"]}


def vehicle(workdir: Path, seed: int, speedup: float) -> ArduPilotSitl:
    sitl = ArduPilotSitl(workdir, speedup=speedup, boot_params={"SIM_DRIFT_SPEED": 0}).start()
    sitl.set_params(injected_errors(seed))
    sitl.set_params(calibration_in_force(seed))
    return sitl


def applied_matrix(params: dict) -> dict:
    """DIA/ODI as the firmware applies them: times COMPASS_SCALE where one is set."""
    scale = params.get("COMPASS_SCALE", 0.0)
    gain = scale if 0.0 < scale else 1.0
    return {k: (v * gain if k.startswith(("COMPASS_DIA", "COMPASS_ODI")) else v)
            for k, v in params.items()}


def onboard(workdir: Path, seed: int, speedup: float) -> tuple[dict, float, float]:
    with vehicle(workdir, seed, speedup) as sitl:
        wall = time.monotonic()
        accel_s = sitl.onboard_accel_calibration()
        _, compass_s = sitl.onboard_compass_calibration(TURN_AXES)
        names = [n for group in GROUPS.values() for n in group] + ["COMPASS_SCALE"]
        params = {n: sitl.get_param(n) for n in names}
        return applied_matrix(params), accel_s + compass_s, time.monotonic() - wall


def apmcal(workdir: Path, seed: int, speedup: float) -> tuple[dict, float, float]:
    with vehicle(workdir, seed, speedup) as sitl:
        wall = time.monotonic()
        start = sitl.time_boot_s
        status, out, accel = guided_six_faces(sitl, workdir / "guided")
        if status != 0 or accel is None:
            raise RuntimeError(f"apmcal live --guide failed: {out[-500:]}")
        status, out, compass = compass_turns(sitl, workdir / "turns", extra=SITE)
        if status != 0 or compass is None:
            raise RuntimeError(f"apmcal live (turns) failed: {out[-500:]}")
        params = {k: v for k, v in accel["params"].items() if k.startswith("INS_ACC")}
        params.update({k: v for k, v in compass["params"].items() if k.startswith("COMPASS_")})
        return applied_matrix(params), sitl.time_boot_s - start, time.monotonic() - wall


def errors(params: dict, exact: dict) -> dict[str, float]:
    return {name: abs(params[name] - exact[name]) for names in GROUPS.values() for name in names
            if name in params}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--speedup", type=float, default=20.0)
    args = ap.parse_args()
    if unavailable_reason():
        print(unavailable_reason())
        return 2
    results = {"ArduPilot onboard": [], "apmcal": []}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            exact = exact_calibration(injected_errors(seed))
            for tool, run in (("ArduPilot onboard", onboard), ("apmcal", apmcal)):
                workdir = Path(tmp) / f"{tool.split()[0]}-{seed}"
                workdir.mkdir()
                (workdir / "guided").mkdir()
                (workdir / "turns").mkdir()
                params, sim_s, wall_s = run(workdir, seed, args.speedup)
                err = errors(params, exact)
                results[tool].append((err, sim_s, wall_s))
                worst = {g: max(err[n] for n in names) for g, names in GROUPS.items()}
                print(f"seed {seed} {tool:18s} {sim_s:6.0f} s vehicle, {wall_s:5.1f} s wall; "
                      + "; ".join(f"{g.split()[0]} {w:.2g}" for g, w in worst.items()), flush=True)
    print()
    print(f"Largest |error| over {len(args.seeds)} seeds (3 axes each), and the time taken "
          "(median):")
    print()
    print("| parameter | ArduPilot onboard | apmcal |")
    print("|---|---|---|")
    for group, names in GROUPS.items():
        cells = [f"{max(e[n] for e, _, _ in results[t] for n in names):.2g}" for t in results]
        print(f"| {group} | {cells[0]} | {cells[1]} |")
    for label, k in (("time, vehicle seconds", 1), ("time, wall seconds", 2)):
        cells = [f"{statistics.median(r[k] for r in results[t]):.0f}" for t in results]
        print(f"| {label} | {cells[0]} | {cells[1]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
