"""The joint method on simulated hand-held sessions as people record them, this tree against
another revision: does the fit converge, does it fall back, how far are its results from the
injected errors?

    python benchmarks/joint_holds.py [--before REV] [--seeds 1-6] [--seconds 120]

Sessions: sitl ``handheld_real`` (holds of 2-10 s, turns of 90-180° at 30-200 °/s that also
move the board, a hand's 5-12 Hz tremor, a laptop's slowly changing field of 30 mGauss RMS per
axis, 100 Hz) and ``handheld_laptop`` (the same right beside the laptop, 150 mGauss: the
compass's ellipsoid, where the joint fit starts, is far off) for each seed, effects no joint
model holds switched off (as in tests/test_joint_holds.py). Each is calibrated by ``apmcal log
FILE --method joint`` of this tree and of ``--before`` (default main; ``git archive``, fresh
process). Printed per session and tree: the verdict, passes (``conv`` when converged), the
levelling and ZUPT noise scales, the gyro matrix's diagonal, and the largest |estimate −
injected| / σ over the accelerometer's, the gyro's and the compass's offsets and matrices
(the compass matrix scaled by the datum, F_WMM / mean |B_true|: tests/test_joint_holds.py).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl"), str(ROOT / "tests"), str(ROOT / "benchmarks")]

SITE = ["--lat", "5.6037", "--lon", "-0.187"]


def make(tmp: Path, script: str, seed: int, seconds: float) -> tuple[Path, dict]:
    from test_joint_holds import OFF

    from apmcal_sim.makelog import main as makelog
    log, truth = tmp / f"{script}_{seed}.bin", tmp / f"{script}_{seed}.json"
    if makelog(["--script", script, "--out", str(log), "--seed", str(seed), "--rate", "100",
                "--fs", "100", "--duration", str(seconds), "--disable", OFF,
                "--truth-out", str(truth)]) != 0:
        raise SystemExit(f"makelog failed for {script} {seed}")
    return log, json.loads(truth.read_text())


def calibrate(tree: Path, log: Path, out: Path) -> tuple[str, dict]:
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree}/sitl")
    done = subprocess.run([sys.executable, "-m", "apmcal", "log", str(log), "--method", "joint",
                           *SITE, "--json", str(out)], env=env, cwd=out.parent, capture_output=True,
                          text=True)      # cwd: not this tree first on the path
    if done.returncode not in (0, 1):
        return f"exit {done.returncode}: {done.stderr.strip()[-80:]}", {}
    return done.stdout.splitlines()[0].split("(")[0].replace("verdict: ", "").strip(), \
        json.loads(out.read_text())


def worst_z(run: dict) -> dict[str, float]:
    from test_joint_holds import accelerometer_frame, z_scores
    est, truth = run["est"], accelerometer_frame(run)
    out = {}
    for sensor in ("acc", "gyr", "mag"):
        offset, matrix = truth[sensor]
        s = est[sensor]
        out[sensor] = float(max(z_scores(s["offset"], offset, s["sigma"]["offset"]).max(),
                                z_scores(s["matrix"], matrix, s["sigma"]["matrix"]).max()))
    return out


def main(argv=None) -> int:
    from end_to_end import export_tree
    from test_joint_holds import SECONDS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default="main")
    ap.add_argument("--seeds", default="1-6", help="first-last seed (default 1-6)")
    ap.add_argument("--seconds", type=float, default=SECONDS)
    args = ap.parse_args(argv)
    first, last = (int(v) for v in args.seeds.split("-"))
    trees = {"now": ROOT, args.before: export_tree(args.before)}
    print("| session | tree | verdict | passes | noise scale level / zupt | gyro matrix diagonal "
          "| max z acc / gyr / mag |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for script in ("handheld_real", "handheld_laptop"):
            for seed in range(first, last + 1):
                log, truth = make(Path(tmp), script, seed, args.seconds)
                for name, tree in trees.items():
                    verdict, est = calibrate(tree, log, Path(tmp) / f"{name}.json")
                    if not est:
                        print(f"| {script} {seed} | {name} | {verdict} | | | | |")
                        continue
                    j = est["report"]["joint"]
                    run = {"est": est, "truth": truth, "script": script, "seed": seed}
                    z = worst_z(run)
                    passes = f"{j.get('passes', '?')}" + (" conv" if j.get("converged") else "")
                    if j.get("fallback"):
                        passes += " fallback"
                    ns = j["noise_scale"]
                    diag = np.diag(np.array(est["gyr"]["matrix"]))
                    print(f"| {script} {seed} | {name} | {verdict} | {passes} | "
                          f"{ns.get('level', 0):.3g} / {ns.get('zupt', 0):.3g} | "
                          f"{' '.join(f'{v:.4f}' for v in diag)} | "
                          f"{z['acc']:.1f} / {z['gyr']:.1f} / {z['mag']:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
