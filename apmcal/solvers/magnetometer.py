"""Magnetometer calibration: coverage check, field magnitude, robust ellipsoid fit ([Niespodziany])
with its second-order bias removed (:mod:`apmcal.solvers.ellipsoid.debias`)."""
from __future__ import annotations

import datetime
from dataclasses import dataclass, field, replace

import numpy as np

from apmcal.core.blas_threads import single_threaded_blas
from apmcal.core.errors import ApmcalError
from apmcal.core.geomag import decimal_year, field_magnitude, field_uncertainty
from apmcal.solvers.ellipsoid.debias import debiased, warm_refit
from apmcal.solvers.ellipsoid.fit import fit_ellipsoid_robust, fit_report, relative_mse, sphere_fit
from apmcal.solvers.report_types import EllipsoidFit, MagneticField, MseScore
from apmcal.solvers.result import SensorCalibration

# An ellipsoid with the field's radius known has 9 unknowns (offset 3, symmetric matrix 6):
# the readings must come from at least this many distinct directions, each one more point on
# it. Six still poses give six, whatever the number of samples: not enough
MIN_DISTINCT_DIRECTIONS = 12
# readings closer than this angle (seen from the field's size) count as one direction [deg]
DISTINCT_DIRECTION_DEG = 10.0
# a direction seen in fewer samples counts as its share of one
SAMPLES_PER_DIRECTION = 3
NOT_MEASURED = "compass not measured by this session"


class CompassNotMeasured(ApmcalError):
    """The session did not turn the compass through enough directions to determine it: nothing
    wrong with the data, the session was not meant for (or did not reach) the compass."""


def distinct_directions(mag: np.ndarray, angle_deg: float = DISTINCT_DIRECTION_DEG,
                        enough: int = 4 * MIN_DISTINCT_DIRECTIONS) -> float:
    """How many distinct readings the samples [mGauss] hold: greedy groups of readings within
    2·sin(angle/2)·|median reading| of a group's first one, each counted as one direction when
    it has SAMPLES_PER_DIRECTION samples or more, else as its share (a reading passed once on
    a quick turn between poses is a third of one); counted up to ``enough``.

    Centre-free: a hard-iron offset moves every reading alike, so two readings that differ by
    less than that chord are one direction of the field seen twice (a still pose, however
    long, is one).
    """
    mag = np.asarray(mag, dtype=float)
    if len(mag) == 0:
        return 0.0
    chord = 2 * np.sin(np.radians(angle_deg) / 2) * float(np.median(np.linalg.norm(mag, axis=1)))
    sample = mag[::max(1, len(mag) // 20_000)]
    unassigned = np.ones(len(sample), dtype=bool)
    count = 0.0
    while unassigned.any() and count < enough:
        near = unassigned & (np.linalg.norm(sample - sample[np.argmax(unassigned)], axis=1)
                             <= chord)
        count += min(1.0, near.sum() / SAMPLES_PER_DIRECTION)
        unassigned &= ~near
    return count


def check_distinct_directions(mag: np.ndarray) -> None:
    """Refuse a compass seen from fewer than MIN_DISTINCT_DIRECTIONS directions.

    Raises
    ------
    CompassNotMeasured
        Saying how many there were and what to do.
    """
    count = distinct_directions(mag)
    if count < MIN_DISTINCT_DIRECTIONS:
        raise CompassNotMeasured(
            f"{NOT_MEASURED}: its readings come from only {count:.0f} distinct directions "
            f"({DISTINCT_DIRECTION_DEG:g}° apart; the compass's 9 unknowns need at least "
            f"{MIN_DISTINCT_DIRECTIONS}): turn the vehicle slowly through every direction, "
            f"nose up and down, each side down, upside down, and a full turn about each axis")


def check_coverage(mag: np.ndarray, min_spread: float = 0.25) -> None:
    """Refuse a fit on samples [mGauss] that do not turn through space.

    Each principal standard deviation of the raw samples must reach ``min_spread`` × their median
    magnitude: a uniform sphere gives 1/√3 ≈ 0.58, one still pose only the noise, a turn about
    one axis a flat disc.

    Parameters
    ----------
    mag : (n, 3) array
        Raw samples [mGauss].
    min_spread : float
        Least principal standard deviation, as a fraction of the median magnitude.

    Raises
    ------
    CompassNotMeasured
        When the samples do not spread enough along their flattest direction.
    """
    spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(mag.T)), 0, None))
    scale = float(np.median(np.linalg.norm(mag, axis=1)))
    if scale <= 0 or spread[0] < min_spread * scale:
        raise CompassNotMeasured(
            f"{NOT_MEASURED}: its readings span only {spread[0] / max(scale, 1e-9):.2f} of "
            f"the field along their flattest direction (need {min_spread}): turn the vehicle "
            f"slowly through every direction, nose up and down, each side down, upside down, "
            f"and a full turn about each axis")


@dataclass
class CompassFit:
    """What :func:`calibrate_magnetometer` found.

    Attributes
    ----------
    sensor : SensorCalibration
        Offset (3,) [mGauss], matrix (3, 3), with their sigmas.
    ellipsoid : EllipsoidFit
        The fit's quality (residuals, coverage, held-out score, debiasing).
    magnetic_field : MagneticField
        The field magnitude the matrix was fitted to [mGauss] and where it came from.
    warnings : list of str
        About the field model (a date outside its years, a field unlike the model's).
    """

    sensor: SensorCalibration
    ellipsoid: EllipsoidFit
    magnetic_field: MagneticField
    warnings: list[str] = field(default_factory=list)


@single_threaded_blas
def calibrate_magnetometer(mag: np.ndarray, lat_deg: float | None, lon_deg: float | None,
                           when: datetime.date | None = None,
                           resolution_mgauss: float | None = None) -> CompassFit:
    """Robust ellipsoid fit of raw sensor-frame samples [mGauss], with the field used and the
    fit's quality.

    The field magnitude comes from the World Magnetic Model when the site is known; otherwise
    from a sphere fit, which ties the overall scale to the data's own mean radius (offsets and
    shape are unaffected). ``when`` is the recording's date (the field drifts ~0.1 %/year);
    today when unknown.

    Parameters
    ----------
    mag : (n, 3) array
        Raw sensor-frame samples [mGauss].
    lat_deg, lon_deg : float or None
        Site [deg], for the World Magnetic Model.
    when : datetime.date, optional
        Recording date.
    resolution_mgauss : float, optional
        The readings' quantization step [mGauss] (int16 telemetry, or whole-mGauss floats):
        rounding is modelled as such, not taken for outliers.

    Returns
    -------
    CompassFit
        Its sensor: offset (3,) [mGauss], matrix (3, 3) with their sigmas, second-order bias
        removed.

    Raises
    ------
    CompassNotMeasured
        When the samples do not turn through space (:func:`check_coverage`) or come from too
        few directions (:func:`check_distinct_directions`).
    ApmcalError
        When the fit fails.
    """
    check_coverage(mag)
    check_distinct_directions(mag)
    warnings: list[str] = []
    mag = distinct_readings(mag)
    sphere = sphere_fit(mag)           # [Niespodziany] step 1: the field check and the fit's box
    radius_sigma = 0.0
    if lat_deg is not None and lon_deg is not None:
        date = f"recording date {when}" if when else f"today's date {datetime.date.today()}"
        radius, note = field_magnitude(lat_deg, lon_deg, when)
        radius_sigma = field_uncertainty(lat_deg, lon_deg, 0.0,
                                         decimal_year(when or datetime.date.today()))[0]
        origin = f"WMM at {date}"
        if note:
            warnings.append(f"mag: {note}")
        mismatch = field_mismatch(sphere[1], radius, lat_deg, lon_deg)
        if mismatch:
            warnings.append(mismatch)
    else:
        radius, origin = sphere[1], "sphere fit (no --lat/--lon)"
    info: dict = {}
    fitted = fit_ellipsoid_robust(mag, radius, info=info, sphere=sphere,
                                  resolution=resolution_mgauss)
    cal, bias = debiased(warm_refit(fitted, radius, info), mag[info["inliers"]], fitted, radius)
    fit = fit_report(mag, cal, radius, info)
    fit.debias = bias
    fit.held_out = held_out_score(mag, radius, info["parameterisation"], start=fitted,
                                  f_scale=info["f_scale"])
    cal = with_field_gain_sigma(cal, radius_sigma / radius)
    return CompassFit(cal, fit, MagneticField(float(radius), origin, sigma_mgauss=radius_sigma),
                      warnings)


# a reading repeated this many times in a row is a compass quieter than its quantization step
MIN_STUCK_RUN = 5


def distinct_readings(mag: np.ndarray, min_run: int = MIN_STUCK_RUN) -> np.ndarray:
    """The samples [mGauss] with each run of ``min_run`` or more identical consecutive readings
    kept once, in time order.

    A quantized compass read while still and with less noise than one step (a noise-free
    simulated compass, a quiet sensor read as whole int16 mGauss) repeats one reading for as
    long as it is held: every repeat carries the same rounding error, so the run is one point
    of the ellipsoid, not thousands. Counted as many, they shrink σ by the square root of the
    repeats (ArduPilot's SITL: 80 distinct readings in 2,679 samples of a six-pose session,
    offsets 3σ off and more). A noisy compass repeats a reading a few times in a row by chance,
    each time with its own noise: shorter runs keep their weight.
    """
    if len(mag) < min_run:
        return mag
    same = np.all(mag[1:] == mag[:-1], axis=1)
    run_start = np.concatenate([[True], ~same])
    run_id = np.cumsum(run_start) - 1
    run_length = np.bincount(run_id)
    keep = run_start | (run_length[run_id] < min_run)
    return mag if keep.all() else mag[keep]


def with_field_gain_sigma(cal: SensorCalibration, relative_sigma: float) -> SensorCalibration:
    """``cal`` with the field reference's uncertainty in its matrix σ.

    The ellipsoid gives the matrix's shape; its overall gain comes from the field magnitude it
    is scaled to (|M·(raw − offset)| = radius). A radius known to ``relative_sigma`` (the WMM's
    own error for the field's magnitude) scales the whole matrix by a common factor of that
    uncertainty: each entry's σ gains |M_ij|·relative_sigma, in quadrature with the fit's. The
    offsets do not depend on the radius.
    """
    if not relative_sigma or cal.sigma is None or cal.sigma.get("matrix") is None:
        return cal
    gain = np.abs(cal.matrix) * relative_sigma
    sigma = dict(cal.sigma, matrix=np.hypot(np.asarray(cal.sigma["matrix"]), gain))
    return replace(cal, sigma=sigma)


HELD_OUT_FIT_SAMPLES = 20_000    # the held-out score's fit uses at most about this many

# the measured and the modelled field magnitude may differ this much (relative to the model)
# before the user is warned: sensor gain errors are a few per cent, the WMM's own error ~1 %
MAX_FIELD_MISMATCH = 0.20


def field_mismatch(measured_mgauss: float, wmm_mgauss: float, lat_deg: float,
                   lon_deg: float) -> str | None:
    """A warning when the samples' field magnitude (their sphere fit) and the WMM's at the
    given site differ by more than MAX_FIELD_MISMATCH, else None.

    The WMM value sets the calibration's scale, so a wrong site (a sign slip: south and west are
    negative) scales the compass wrongly; a right site with a distorted field means iron,
    magnets or currents near the vehicle.

    Parameters
    ----------
    measured_mgauss : float
        Sphere-fit radius of the samples [mGauss].
    wmm_mgauss : float
        World Magnetic Model total intensity [mGauss].
    lat_deg, lon_deg : float
        The site [deg] (for the message).

    Returns
    -------
    str or None
    """
    apart = abs(measured_mgauss - wmm_mgauss) / wmm_mgauss
    if apart <= MAX_FIELD_MISMATCH:
        return None
    return (f"mag: the samples' field magnitude is {measured_mgauss:.0f} mGauss (sphere fit), "
            f"the World Magnetic Model's at --lat {lat_deg:g} --lon {lon_deg:g} is "
            f"{wmm_mgauss:.0f} mGauss: {100 * apart:.0f} % apart (more than "
            f"{100 * MAX_FIELD_MISMATCH:.0f} %). Check --lat/--lon first (south and west are "
            f"negative): a wrong site scales the compass wrongly. If the site is right, trust "
            f"the WMM value (used here) and look for iron, magnets or currents near the "
            f"vehicle, which distort the field the fit sees")


def held_out_score(mag: np.ndarray, radius: float, parameterisation: str,
                   n_blocks: int = 20, *, start: SensorCalibration | None = None,
                   f_scale: float | None = None) -> MseScore:
    """[Niespodziany]'s figure of merit (§VI.B) on samples the fit never saw.

    The record is cut into ``n_blocks`` consecutive blocks; the even ones are fitted and the odd
    ones scored, so neighbouring (correlated) samples do not sit on both sides. The relative MSE
    of |calibrated| is given raw and calibrated; the calibration itself uses every sample.
    ``start`` and ``f_scale`` [mGauss]: the fit on every sample and its Huber scale, so that the
    half-fit starts next to its minimum (a few steps instead of a search from the quadric).
    A half that cannot be fitted gives NaN scores and the reason in ``failed``.

    Parameters
    ----------
    mag : (n, 3) array
        Raw samples [mGauss].
    radius : float
        Field magnitude [mGauss].
    parameterisation : str
        As the full fit used ("symmetric", "upper", "diagonal").
    n_blocks : int
        Number of consecutive blocks.
    start : SensorCalibration, optional
    f_scale : float, optional

    Returns
    -------
    MseScore
        Relative MSE raw and calibrated (dimensionless).
    """
    blocks = np.array_split(np.arange(len(mag)), n_blocks)
    train = mag[np.concatenate(blocks[0::2])]
    test = mag[np.concatenate(blocks[1::2])]
    # every k-th training sample beyond HELD_OUT_FIT_SAMPLES: the score is the test samples'
    # noise and model error (~1e-3 here); the fit's own error adds ~(σ/r)²·9/n (≤ 1e-7 at
    # 20 000 samples), invisible in the three digits printed
    train = train[::max(1, len(train) // HELD_OUT_FIT_SAMPLES)]
    try:
        check_coverage(train)
        cal = fit_ellipsoid_robust(train, radius, parameterisation=parameterisation,
                                   start=start, f_scale=f_scale)
    except ApmcalError as err:
        return MseScore(float("nan"), float("nan"), "held-out blocks", n_blocks, failed=err.why)
    return MseScore(relative_mse(test, None, radius), relative_mse(test, cal, radius),
                    "held-out blocks", n_blocks)
