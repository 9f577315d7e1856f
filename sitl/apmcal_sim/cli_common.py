"""Command-line options shared by ``python -m apmcal_sim`` and ``python -m apmcal_sim.makelog``."""
from __future__ import annotations

from apmcal.sensor_model.truth import DEFAULT_SITE, Truth


def add_truth_args(ap) -> None:
    """Options choosing the injected errors: seed, truth or twin file, effect switches, home site."""
    ap.add_argument("--seed", type=int, default=0, help="error draw and noise seed")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--truth", help="LOAD the injected errors from this JSON (else drawn by seed)")
    src.add_argument("--twin", metavar="TWIN.json",
                     help="LOAD the injected errors of a simulated twin of a real session: a twin "
                     "written by `apmcal gap --write-twin` (a truth file; its extra keys such as "
                     "\"twin\" are ignored)")
    ap.add_argument("--disable", default="", help="effects to switch off, comma-separated "
                    "('all' for every effect; sitl names or `apmcal gap` diagnosis names)")
    ap.add_argument("--enable", default="", help="effects to switch on, comma-separated "
                    "(sitl names or diagnosis names, e.g. bias_drift, cross_axis; 'nominal' for "
                    "the errors `apmcal gap` always models)")
    ap.add_argument("--lat", type=float, default=DEFAULT_SITE["lat"], help="home latitude [deg]")
    ap.add_argument("--lon", type=float, default=DEFAULT_SITE["lon"], help="home longitude [deg]")
    ap.add_argument("--alt", type=float, default=DEFAULT_SITE["alt"], help="home height [m]")


def make_truth(args) -> Truth:
    """Truth from --truth / --twin or --seed, then --lat/--lon/--alt (only when drawn) and
    switches (sitl effect names or diagnosis names, see
    :data:`apmcal.sensor_model.truth.DIAGNOSIS_EFFECTS`)."""
    path = args.truth or getattr(args, "twin", None)
    if path:
        truth = Truth.load(path)       # only the "effects" block is read
    else:
        truth = Truth.random(args.seed, dict(DEFAULT_SITE, lat=args.lat, lon=args.lon,
                                             alt=args.alt))
    split = lambda s: [x.strip() for x in s.split(",") if x.strip()]
    # --disable first so "--disable all --enable acc_bias" isolates one effect
    truth.with_effects(disable=split(args.disable))
    return truth.with_effects(enable=split(args.enable))


def add_firmware_args(ap) -> None:
    """Options reproducing firmware faults (not sensor errors: the truth is unaffected)."""
    ap.add_argument("--highres-mag-bug", action="store_true",
                    help="send HIGHRES_IMU's magnetic field in mGauss×1000 instead of gauss, as "
                         "ArduPilot firmware of about May 2024 - Feb 2026 did")
    ap.add_argument("--whole-mgauss-compass", action="store_true",
                    help="round the compass's raw readings to whole mGauss, as a real "
                         "ArduPilot SITL's are (use with --disable mag_noise for its "
                         "noise-free compass)")


def apply_firmware_args(vehicle, args) -> None:
    """Set the firmware faults chosen by :func:`add_firmware_args` on ``vehicle``."""
    from apmcal_sim.vehicle import FAULTY_HIGHRES_MAG_PER_MGAUSS

    if args.highres_mag_bug:
        vehicle.highres_mag_per_mgauss = FAULTY_HIGHRES_MAG_PER_MGAUSS
    vehicle.whole_mgauss_compass = bool(getattr(args, "whole_mgauss_compass", False))
