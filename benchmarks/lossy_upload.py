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

Peer, measured in the same run on the same seeds (``--peer-runs``, default 3): apmcal's
previous download, :class:`BatchedReads` — missing indices asked for 20 at a time, each batch
waiting for all its answers or a whole ``answer_timeout_s`` of silence, 8 rounds within 20 s,
and 3 tries per write (5 per put-back).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sitl"), str(ROOT / "tests")]

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


class BatchedReads(VehicleLink):
    """The peer: apmcal's download and write tries before the pipelined, adaptive ones."""

    def _read_missing(self, got, timeout_s, attempts):
        deadline = time.monotonic() + timeout_s
        idle_s = min(2 * self.answer_timeout_s, self.answer_timeout_s)
        for _ in range(attempts or 8):
            missing = got.missing()
            if not missing or time.monotonic() >= deadline:
                return
            for i in range(0, len(missing), 20):
                batch = missing[i:i + 20]
                for index in batch:
                    self.master.mav.param_request_read_send(self.target_system,
                                                            self.target_component, b"", index)
                self._receive_batch(got, deadline, idle_s, set(batch))

    def _receive_batch(self, got, deadline, idle_s, until):
        while (remaining := deadline - time.monotonic()) > 0:
            msg = self.recv({"PARAM_VALUE"}, min(idle_s, remaining))
            if msg is None:
                return
            if self._from_target(msg):
                got.add(msg)
                if until <= got.seen:
                    return

    def answer_wait_s(self):
        return self.answer_timeout_s

    def attempts(self, minimum=3):
        return minimum


def one_run(loss: float, seed: int, answer_timeout_s: float, folder: Path,
            link_class=VehicleLink) -> dict:
    """{"ok", "upload_s", "restore_s", "why", "drops"} of one upload + restore."""
    backup = folder / f"backup{seed}.param"
    out = {"ok": False, "upload_s": float("nan"), "restore_s": float("nan"), "why": ""}
    with vehicle_behind_lossy_link(loss, seed, full_params=True) as (connection, served, proxy):
        before = served.params.as_dict()
        try:
            with link_class(connection) as link:
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
    ap.add_argument("--peer-runs", type=int, default=3,
                    help="runs of the peer (the previous batched download) on the first seeds")
    args = ap.parse_args(argv)
    ok, totals = series("apmcal", VehicleLink, args.runs, args)
    peer_ok, peer_totals = series("peer (batched reads)", BatchedReads, args.peer_runs, args)
    print(f"apmcal: {ok} of {args.runs} upload+restore runs succeeded at {args.loss:.0%} loss "
          f"each way; peer (batched reads): {peer_ok} of {args.peer_runs}")
    if totals:
        print(f"apmcal upload+restore time: median {np.median(totals):.1f} s, max "
              f"{max(totals):.1f} s (target {TARGET_S:.0f} s: max/target "
              f"{max(totals) / TARGET_S:.2f})")
    if totals and peer_totals:
        print(f"peer median {np.median(peer_totals):.1f} s over its successes: "
              f"peer/apmcal {np.median(peer_totals) / np.median(totals):.2f}")
    return 0 if ok == args.runs and totals and max(totals) <= TARGET_S else 1


def series(name: str, link_class, runs: int, args) -> tuple[int, list[float]]:
    """(successes, upload+restore times of the successes [s]) of ``runs`` runs."""
    ok, totals = 0, []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(runs):
            r = one_run(args.loss, args.seed0 + k, args.answer_timeout, Path(tmp), link_class)
            total = r["upload_s"] + r["restore_s"]
            if r["ok"]:
                ok += 1
                totals.append(total)
                print(f"{name} run {k + 1}: ok, {r['params']} parameters, upload "
                      f"{r['upload_s']:.1f} s + restore {r['restore_s']:.1f} s = {total:.1f} s "
                      f"(lost {r['drops'][0]:.0%} up, {r['drops'][1]:.0%} down)", flush=True)
            else:
                print(f"{name} run {k + 1}: FAILED: {r['why']}", flush=True)
    return ok, totals


if __name__ == "__main__":
    sys.exit(main())
