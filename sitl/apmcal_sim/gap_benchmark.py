"""Does ``apmcal gap`` find an effect the twin was not told about? A benchmark of the diagnosis on
simulated sessions, beside the simulator because it needs one (the library never imports it)::

    python -m apmcal_sim.gap_benchmark [--quick] [--rate HZ] [--json FILE]

Each case simulates a session with sitl (the ``diagnosis`` script: six faces, three 360° turns
and a motor run) in which the nominal errors plus one effect (or a pair) are switched on — the
"real" data — and runs ``apmcal gap`` on its dataflash log blind. A null case switches on no
extra effect. Printed: the confusion table (withheld effect vs the effect ranked first), the
held-out shrink of the withheld effect, and the false-alarm rate (null sessions in which some
effect was reported as supported). Targets: the withheld effect first in ≥ 90 % of
the cases, held-out shrink ≥ 50 % where the effect is strong, false alarms ≤ 5 %.

``local_gravity`` is not a case: it only rescales gravity, which no self-calibration can tell
from the accelerometer's own scale factor (the fit absorbs it exactly), so it cannot leave a gap.
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SITE = {"lat": 47.4, "lon": 8.5, "alt": 400.0, "year": None}   # Zurich: both Earth-rate parts
START_UNIX = 1_780_000_000.0
SINGLE = ("temperature_drift", "bias_drift", "triangle_drift", "bias_random_walk",
          "g_sensitivity", "earth_rate", "cross_axis", "scale_nonlinearity", "gyro_scale",
          "time_offset", "quantization", "lowpass_filter", "uniform_noise",
          "motion_contamination", "mag_interference")
PAIRS = (("temperature_drift", "g_sensitivity"), ("gyro_scale", "mag_interference"),
         ("bias_random_walk", "lowpass_filter"))
QUICK = (("temperature_drift",), ("gyro_scale",), ("mag_interference",), ())
NULL_SESSIONS = 40      # clean sessions (no extra effect) of a full run


@dataclass
class Case:
    """One simulated session and what the blind diagnosis made of it.

    Attributes
    ----------
    withheld : tuple of str
        The effects switched on in the "real" data and not told to the twin (empty: null case).
    seed : int
        Seed of the simulated session.
    top : str or None
        The effect ranked first when it is significant, else None.
    selected : list of str
        The selected combination.
    gap_heldout : float
        Held-out gap of the nominal model [nats per sample].
    shrink : float
        Held-out shrink of the withheld effect(s) (1 − gap_after / gap_before; the largest
        of a pair's), NaN for a null case.
    seconds : float
        Wall time of the case, simulation included [s].
    """

    withheld: tuple
    seed: int
    top: str | None = None
    selected: list = field(default_factory=list)
    gap_heldout: float = float("nan")
    shrink: float = float("nan")            # held-out shrink of the withheld effect(s)
    seconds: float = 0.0

    @property
    def hit(self) -> bool:
        """Null: nothing supported; otherwise the effect ranked first is a withheld one."""
        return self.top is None if not self.withheld else self.top in self.withheld

    @property
    def extra(self) -> list:
        """Selected effects that were not withheld (stand-ins for part of a withheld one)."""
        return [n for n in self.selected if n not in self.withheld]

    @property
    def exact(self) -> bool:
        """The selected combination is exactly the withheld effects."""
        return set(self.selected) == set(self.withheld)


def truth_for(withheld: tuple, seed: int):
    """The "real" board: nominal errors plus the withheld effects, everything else off."""
    from apmcal.sensor_model.truth import NOMINAL_EFFECTS, Truth

    truth = Truth.random(seed, dict(SITE))
    return truth.with_effects(disable=["all"], enable=list(NOMINAL_EFFECTS) + list(withheld),
                              prefer="diagnosis")


def simulate_log(withheld: tuple, seed: int, path: Path, rate_hz: float, fs: float) -> None:
    """Write the session's dataflash log (neutral parameters, no boot gyro calibration).

    ``fs`` is sitl's sensor rate; at the log's rate every logged sample is a sensor sample,
    as on a board whose IMU is filtered and read at the loop rate (sitl at a higher rate
    reports single samples without averaging: white noise far above the log's band would
    alias into it, several times noisier than a real MPU-6000 behind its low-pass).

    Parameters
    ----------
    withheld : tuple of str
        Effects switched on besides the nominal errors.
    seed : int
        Seed of the board's errors and of the simulation.
    path : Path
        The dataflash log to write.
    rate_hz : float
        Logging rate [Hz].
    fs : float
        sitl's sensor rate [Hz].
    """
    from apmcal_sim.makelog import write_bin
    from apmcal_sim.vehicle import SimVehicle

    v = SimVehicle(truth_for(withheld, seed), "diagnosis", "3.3", None, fs=fs, seed=seed,
                   start_unix=START_UNIX)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None
    v.reset_zero_compass_diagonals()
    write_bin(v, path, rate_hz, v.motion.duration + 1.0)


def run_case(withheld: tuple, seed: int, rate_hz: float, fs: float) -> Case:
    """Simulate, diagnose blind, score.

    Parameters
    ----------
    withheld : tuple of str
        Effects switched on besides the nominal errors (empty: a null case).
    seed : int
        Seed of the board's errors, the simulation and the diagnosis.
    rate_hz : float
        Logging rate [Hz].
    fs : float
        sitl's sensor rate [Hz].

    Returns
    -------
    Case
    """
    from apmcal.core.options import Options
    from apmcal.diagnosis.run import diagnose
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "session.bin"
        simulate_log(withheld, seed, path, rate_hz, fs)
        session = session_from_log(read_log(path), Options(lat_deg=SITE["lat"],
                                                           lon_deg=SITE["lon"]))
    result = diagnose(session, seed=seed).result
    case = Case(withheld, seed, result.top, result.selected, result.gap["heldout"],
                seconds=time.perf_counter() - start)
    if withheld:
        entries = [result.effect(n) for n in withheld]
        shrinks = [e.get("shrink_heldout", np.nan) for e in entries if e]
        case.shrink = float(np.nanmax(shrinks)) if shrinks else float("nan")
    return case


def cases(quick: bool, null: int = NULL_SESSIONS, effects: bool = True) -> list[tuple]:
    """The (withheld effects, seed) pairs to run: a few with ``quick``, else every single
    effect on two seeds and the pairs (unless ``effects`` is False), and ``null`` clean
    sessions (seeds 1 to ``null``)."""
    if quick:
        return [(w, 1) for w in QUICK]
    singles = [((e,), s) for e in SINGLE for s in (1, 2)] + [(p, 1) for p in PAIRS]
    return (singles if effects else []) + [((), s) for s in range(1, null + 1)]


def main(argv=None) -> int:
    """``python -m apmcal_sim.gap_benchmark``: run the cases and print the tables."""
    import argparse

    from rich.console import Console

    parser = argparse.ArgumentParser(prog="python -m apmcal_sim.gap_benchmark",
                                     description="simulate sessions with one effect withheld "
                                                 "from the twin and check the diagnosis finds it")
    parser.add_argument("--quick", action="store_true", help="a small run")
    parser.add_argument("--rate", type=float, default=None, metavar="HZ",
                        help="the simulated sessions' sample rate [Hz] (default 100, 50 with "
                             "--quick; above 200 the slow effects are scored on block means)")
    parser.add_argument("--json", default=None, help="write the cases as JSON")
    parser.add_argument("--null", type=int, default=NULL_SESSIONS, metavar="N",
                        help=f"clean sessions to run (default {NULL_SESSIONS})")
    parser.add_argument("--null-only", action="store_true",
                        help="only the clean sessions (the false-alarm rate)")
    args = parser.parse_args(argv)
    if args.rate is not None and not 10 <= args.rate <= 2000:
        parser.error("--rate must be within 10 to 2000 Hz")
    if args.null < 0:
        parser.error("--null must be 0 or more")
    return run_benchmark(args, Console(highlight=False, markup=False, emoji=False))


def run_benchmark(args, console) -> int:
    """Run the cases, print the tables (and write them as JSON with --json)."""
    rate = args.rate or (50.0 if args.quick else 100.0)
    fs = rate
    done = []
    for withheld, seed in cases(args.quick, args.null, not args.null_only):
        case = run_case(withheld, seed, rate, fs)
        done.append(case)
        console.print(f"{'+'.join(withheld) or 'none':40s} seed {seed}: first "
                      f"{case.top or 'none':22s} {'ok' if case.hit else 'MISS'}  shrink "
                      f"{case.shrink:6.2f}  ({case.seconds:.0f} s)", soft_wrap=True)
    print_tables(done, console)
    if args.json:
        import json

        Path(args.json).write_text(json.dumps([c.__dict__ for c in done], indent=1,
                                              default=float) + "\n")
    return 0


def print_tables(done: list[Case], console) -> None:
    """Confusion counts, first-rank rate, exact combinations, shrink and false alarms."""
    effect_cases = [c for c in done if c.withheld]
    null_cases = [c for c in done if not c.withheld]
    confusion: dict = {}
    for c in effect_cases:
        key = "+".join(c.withheld)
        confusion.setdefault(key, {})
        confusion[key][c.top or "none"] = confusion[key].get(c.top or "none", 0) + 1
    def say(text: str) -> None:         # one line each, however narrow the terminal
        console.print(text, soft_wrap=True)

    say("withheld effect -> effect ranked first (count)")
    for key, row in confusion.items():
        say(f"  {key:40s} " + ", ".join(f"{k}: {v}" for k, v in sorted(row.items())))
    hits = np.mean([c.hit for c in effect_cases]) if effect_cases else float("nan")
    alarms = np.mean([not c.hit for c in null_cases]) if null_cases else float("nan")
    shrinks = [c.shrink for c in effect_cases if np.isfinite(c.shrink)]
    say(f"withheld effect ranked first: {100 * hits:.0f} % of {len(effect_cases)} "
        f"cases (target ≥ 90 %)")
    exact = np.mean([c.exact for c in effect_cases]) if effect_cases else float("nan")
    extras: dict = {}
    for c in effect_cases:
        for name in c.extra:
            extras[name] = extras.get(name, 0) + 1
    say(f"selected combination exactly the withheld effects: {100 * exact:.0f} % of the cases; "
        f"effects selected besides: " + (", ".join(f"{k} {v}×" for k, v in
                                                   sorted(extras.items())) or "none"))
    say(f"held-out shrink of the withheld effect: median "
        f"{100 * np.median(shrinks) if shrinks else float('nan'):.0f} %, smallest "
        f"{100 * np.min(shrinks) if shrinks else float('nan'):.0f} %, "
        f"≥ 50 % in {np.mean(np.array(shrinks) >= 0.5) * 100 if shrinks else 0:.0f} %"
        f" of the cases")
    say(f"false alarms: {100 * alarms:.0f} % of {len(null_cases)} sessions without an "
        f"extra effect (target ≤ 5 %)")


if __name__ == "__main__":
    raise SystemExit(main())
