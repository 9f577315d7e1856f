"""Upload then restore through a link losing a quarter of the packets each way, against the
simulated vehicle with a real vehicle's full-size parameter table (1,349 names).

    python benchmarks/lossy_upload.py [--runs 10] [--loss 0.25] [--seed0 100]

Each run: a fresh simulated vehicle behind tests/lossy_udp.py's proxy (seeded drops, each
direction), ``upload_params`` of six calibration values (fetch of every parameter, backup,
verified writes), then ``restore_params`` of the backup (fetch again, verified writes back).
A run succeeds when both end without error AND the vehicle itself (read directly, not over the
link) holds the uploaded values after the upload and the backed-up values after the restore;
a run that ends in an error counts as a failure, and is checked to have left nothing
half-written (every name at its value before, or as the error says). Prints one line per run
and the success count, with the times against the target of 60 s for upload + restore.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from lossy_udp import vehicle_behind_lossy_link  # noqa: E402

from apmcal.core.errors import ApmcalError  # noqa: E402
from apmcal.link.upload import restore_params, upload_params  # noqa: E402
from apmcal.sources.live import VehicleLink  # noqa: E402

NEW = {"INS_ACCOFFS_X": 0.31, "INS_ACCOFFS_Y": -0.27, "INS_ACCOFFS_Z": 0.52,
       "COMPASS_OFS_X": 41.5, "COMPASS_OFS_Y": -63.25, "COMPASS_OFS_Z": 120.0}
TARGET_S = 60.0
SETTLE_S = 0.5          # a PARAM_SET still on its way reaches the vehicle before it is read


def stored(values: dict) -> dict:
    return {k: float(np.float32(v)) for k, v in values.items()}


def one_run(loss: float, seed: int, answer_timeout_s: float, folder: Path) -> dict:
    """{"ok", "upload_s", "restore_s", "why", "drops"} of one upload + restore."""
    backup = folder / f"backup{seed}.param"
    out = {"ok": False, "upload_s": float("nan"), "restore_s": float("nan"), "why": ""}
    with vehicle_behind_lossy_link(loss, seed, full_params=True) as (connection, served, proxy):
        before = served.params.as_dict()
        try:
            with VehicleLink(connection) as link:
                link.answer_timeout_s = answer_timeout_s
                t0 = time.monotonic()
                upload_params(link, NEW, backup)
                out["upload_s"] = time.monotonic() - t0
                time.sleep(SETTLE_S)
                uploaded = {n: served.params[n] for n in NEW}
                if uploaded != stored(NEW):
                    out["why"] = f"upload reported verified, vehicle holds {uploaded}"
                    return out
                t0 = time.monotonic()
                restore_params(link, backup)
                out["restore_s"] = time.monotonic() - t0
        except ApmcalError as err:
            time.sleep(SETTLE_S)
            after = served.params.as_dict()
            odd = [n for n in NEW if after[n] not in (before[n], stored(NEW)[n])]
            out["why"] = f"{err}" + (f" [third value on {odd}]" if odd else "")
            return out
        time.sleep(SETTLE_S)
        restored = {n: served.params[n] for n in NEW}
        if restored != {n: before[n] for n in NEW}:
            out["why"] = f"restore reported verified, vehicle holds {restored}"
            return out
        out["ok"] = True
        out["drops"] = (proxy.up.dropped / max(proxy.up.dropped + proxy.up.passed, 1),
                        proxy.down.dropped / max(proxy.down.dropped + proxy.down.passed, 1))
        out["params"] = len(before)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--loss", type=float, default=0.25, help="share lost each way")
    ap.add_argument("--seed0", type=int, default=100, help="first proxy seed")
    ap.add_argument("--answer-timeout", type=float, default=1.0,
                    help="longest wait for one answer [s] (VehicleLink's default 1.0)")
    args = ap.parse_args(argv)
    ok, totals = 0, []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.runs):
            r = one_run(args.loss, args.seed0 + k, args.answer_timeout, Path(tmp))
            total = r["upload_s"] + r["restore_s"]
            if r["ok"]:
                ok += 1
                totals.append(total)
                print(f"run {k + 1}: ok, {r['params']} parameters, upload {r['upload_s']:.1f} s"
                      f" + restore {r['restore_s']:.1f} s = {total:.1f} s (lost "
                      f"{r['drops'][0]:.0%} up, {r['drops'][1]:.0%} down)", flush=True)
            else:
                print(f"run {k + 1}: FAILED: {r['why']}", flush=True)
    print(f"{ok} of {args.runs} upload+restore runs succeeded at {args.loss:.0%} loss each way")
    if totals:
        print(f"upload+restore time: median {np.median(totals):.1f} s, max {max(totals):.1f} s "
              f"(target {TARGET_S:.0f} s: max/target {max(totals) / TARGET_S:.2f})")
    return 0 if ok == args.runs and totals and max(totals) <= TARGET_S else 1


if __name__ == "__main__":
    sys.exit(main())
