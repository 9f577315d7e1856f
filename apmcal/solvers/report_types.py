"""What a calibration run found, as numbers: one small dataclass per stage.

Solvers fill these in; :mod:`apmcal.report.lines` turns them into words and :mod:`apmcal.report.verdict`
into grades. Every field is a number, an array, a name or a message; units are in the field name
or the docstring (accelerometer m/s², gyroscope rad/s, magnetometer mGauss, time s, angles deg
unless the name says rad). :func:`to_plain` and :func:`from_plain` turn any of them into plain
JSON values and back (:meth:`apmcal.solvers.result.Calibration.save` / ``load``).
"""
from __future__ import annotations

import types
import typing
from dataclasses import dataclass, field, fields, is_dataclass

import numpy as np

from apmcal.solvers.misfit import HoldMisfit


@dataclass
class Hold:
    """One still period a method used: its span [s] and sample count."""

    start_s: float
    end_s: float
    samples: int = 0


@dataclass
class Holds:
    """The still periods: how many were found, and the ones the method used by name (Ferraris
    poses "x_p" … "z_a"; "level" for the one-position method)."""

    count: int | None = None
    used: dict[str, Hold] = field(default_factory=dict)


@dataclass
class Turn:
    """A full turn about one axis used for the gyro matrix: span [s] and integrated angle [deg]."""

    start_s: float
    end_s: float
    angle_deg: float


@dataclass
class SixFaceFit:
    """The Ferraris accelerometer stage ([Oppong] §4.1-4.2).

    Attributes
    ----------
    u_plus, u_minus : (3, 3) array, m/s²
        Hold means of x_p, y_p, z_p / x_a, y_a, z_a as columns.
    q : float
        Mean column norm of U+ [m/s²] ([Oppong] eq. 4).
    gravity : float
        The g the scale was fitted to [m/s²]; gravity_source says where it came from.
    gravity_source : str
    misfit : HoldMisfit
        The six-face model against its redundant holds (:mod:`apmcal.solvers.misfit`).
    sigma_noise_only : dict
        "offset" (3,) m/s², "matrix" (3, 3): σ from the noise alone, before the
        misfit widened it.
    """

    u_plus: np.ndarray
    u_minus: np.ndarray
    q: float
    gravity: float
    gravity_source: str
    misfit: HoldMisfit
    sigma_noise_only: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class GyroTurns:
    """The Ferraris gyro stage ([Oppong] §4.3-4.4).

    Attributes
    ----------
    t_ref : float
        Time [s] at which the gyro offset holds (drift is referred to it).
    earth_rate_left : float or None
        Horizontal Earth rate Ω cos φ [rad/s] left in the bias when the vertical
        part was removed; None when it was not removed.
    integrals_rad : (3, 3) array or None
        Bias-corrected integral of each turn (column j: turn about axis j).
    angles_deg : (3,) array or None
        The angle each turn is taken to be.
    """

    t_ref: float = 0.0
    earth_rate_left: float | None = None
    integrals_rad: np.ndarray | None = None
    angles_deg: np.ndarray | None = None


@dataclass
class Coverage:
    """How the sample directions cover the sphere: ``fraction`` (0..1) of it within 20° of a
    sample and the ``eigenvalues`` (3,) of 3·mean(n nᵀ) (1 = uniform, 0 = one plane)."""

    fraction: float
    eigenvalues: np.ndarray


@dataclass
class Residuals:
    """|calibrated| − field over ``samples`` samples [sensor units]: RMS, robust σ (MAD) and
    the count beyond 5 robust σ."""

    samples: int
    rms: float
    robust_sigma: float
    outliers: int


@dataclass
class MseScore:
    """[Niespodziany]'s figure of merit (§VI.B): relative MSE of |calibrated| raw and calibrated.

    Attributes
    ----------
    raw, calibrated : float
        The relative MSE (dimensionless) of the raw and the calibrated samples.
    scored_on : str
        "fitting" or "held-out" samples, or "held-out blocks" (the odd ones of
        ``blocks`` consecutive blocks, fitted on the even ones).
    blocks : int
    failed : str
        Why no score could be given (then raw and calibrated are NaN).
    """

    raw: float
    calibrated: float
    scored_on: str
    blocks: int = 0
    failed: str = ""


@dataclass
class Debias:
    """The geometric fit's second-order bias removed (:mod:`apmcal.solvers.ellipsoid.debias`):
    offset moved by ``offset_shift`` (3,) [sensor units], matrix entries by up to
    ``matrix_shift_max``, from ``pairs`` antithetic refit pairs."""

    offset_shift: np.ndarray
    matrix_shift_max: float
    pairs: int


@dataclass
class EllipsoidFit:
    """Quality of one sensor's ellipsoid fit ([Niespodziany] and its robust successor).

    Attributes
    ----------
    radius : float
        Field magnitude fitted to [sensor units].
    method : str
        The estimator.
    parameterisation : str
        "symmetric", "upper" or "diagonal".
    samples : int
        Samples fitted.
    n_params : int or None
        Parameters fitted (None: the paper's fits).
    rms, cond, rank, start, f_scale, outlier_fraction : float, int or str, or None
        The fit's internals (rms and f_scale in
        sensor units), None when the estimator does not give them.
    notes : list of str
        The fit's own findings (diagonal fallback, outliers, bounds), as messages.
    coverage : Coverage or None
        Of the calibrated samples (eigenvalues: the smaller of their scatter and of the
        raw samples' own shape).
    residuals : Residuals or None
        |calibrated| − field on the fitted samples.
    score : MseScore or None
        Relative MSE on the fitting or held-out samples.
    held_out : MseScore or None
        On held-out blocks.
    debias : Debias or None
        The second-order bias removed (robust magnetometer fit).
    """

    radius: float
    method: str
    parameterisation: str = ""
    samples: int = 0
    n_params: int | None = None
    rms: float | None = None
    cond: float | None = None
    rank: int | None = None
    start: str | None = None
    f_scale: float | None = None
    outlier_fraction: float | None = None
    notes: list[str] = field(default_factory=list)
    coverage: Coverage | None = None
    residuals: Residuals | None = None
    score: MseScore | None = None
    held_out: MseScore | None = None
    debias: Debias | None = None


@dataclass
class MagneticField:
    """The compass's field: magnitude [mGauss], where it came from ("WMM at recording date …",
    "sphere fit (no --lat/--lon)") and how the samples cover the directions around the fitted
    offset (fraction of the sphere within 20°, smallest eigenvalue of 3·mean(n nᵀ))."""

    mgauss: float
    source: str
    coverage_fraction: float | None = None
    coverage_min_eig: float | None = None
    sigma_mgauss: float = 0.0       # one sigma of the true field about ``mgauss`` (WMM's error)


@dataclass
class AtRest:
    """What the sensors read at rest with the calibration in force (as logged): the median
    |specific force| of the still periods [m/s²] beside gravity at the site [m/s²], and the
    median |field| of the compass [mGauss] beside the World Magnetic Model's (None without a
    site). Whatever the method, a reading far from either is reported (apmcal.report.verdict)."""

    acc_ms2: float | None = None
    gravity_ms2: float | None = None
    mag_mgauss: float | None = None
    wmm_mgauss: float | None = None


@dataclass
class OnePositionAcc:
    """[Oppong] §5.1 on the level hold (body FRD, m/s²): step-1 ``mean`` (3,), g := ‖mean‖,
    step-3 mean ``R`` and high-pass mean ``R_f`` (3,), ``bias`` (3,), F (3, 3) and its β, γ, μ,
    μ read literally (a_s = R), F in the paper's sign convention, tilt from level [deg].

    Attributes
    ----------
    mean : (3,) array, m/s²
        Step-1 mean.
    g : float
        ‖mean‖ [m/s²].
    R, R_f : (3,) array, m/s²
        Step-3 mean and high-pass mean.
    bias : (3,) array, m/s²
    F : (3, 3) array
    beta_gamma_mu : (3,) array
        β, γ, μ of F (dimensionless).
    mu_literal : float
        μ read literally (a_s = R).
    F_paper_convention : (3, 3) array
        F in the paper's sign convention.
    tilt_deg : float
        Tilt from level [deg].
    """

    mean: np.ndarray
    g: float
    R: np.ndarray
    R_f: np.ndarray
    bias: np.ndarray
    F: np.ndarray
    beta_gamma_mu: np.ndarray
    mu_literal: float
    F_paper_convention: np.ndarray
    tilt_deg: float


@dataclass
class OnePositionGyr:
    """[Oppong] §5.2 (rad/s): mean ``R``, high-pass mean ``R_f``, ``bias``; with a latitude the
    Earth-rate input ``omega_p`` (3,), E (3, 3) and its τ, ξ, ν (reported, never applied).

    Attributes
    ----------
    R, R_f, bias : (3,) array, rad/s
        Mean, high-pass mean, bias.
    omega_p : (3,) array, rad/s, or None
        Earth-rate input (with a latitude).
    E : (3, 3) array or None
    tau_xi_nu : (3,) array or None
        τ, ξ, ν of E (dimensionless).
    """

    R: np.ndarray
    R_f: np.ndarray
    bias: np.ndarray
    omega_p: np.ndarray | None = None
    E: np.ndarray | None = None
    tau_xi_nu: np.ndarray | None = None


@dataclass
class OnePositionFit:
    """The one-position method ([Oppong] §5): its two parts, sample rate [Hz], duration [s],
    high-pass cut-off [Hz] and the latitude [deg] used (None: unknown)."""

    acc: OnePositionAcc
    gyr: OnePositionGyr
    fs_hz: float
    duration_s: float
    cutoff_hz: float
    lat_deg: float | None = None


@dataclass
class JointFit:
    """[Chow]'s joint fit: conditions and robust rejections per family, each family's noise
    scale (1 = the still periods' white noise), the parameters (name → [value, σ] in the units
    of :data:`apmcal.solvers.joint.model.UNITS`), those held fixed and those the t-test dropped,
    and what ArduPilot cannot hold: the gyro matrix's cost [deg per 360° turn] and the
    g-sensitivity's largest effect at 1 g [rad/s]. ``block_samples`` > 1: the fit ran on
    means of that many samples of a ``recorded_rate_hz`` recording; ``compass_own_fit``: the
    compass result is the compass's own ellipsoid fit (``auto``), not the joint fit's.

    Attributes
    ----------
    conditions, rejected : dict
        family → number of conditions, of robust rejections.
    noise_scale : dict
        family → noise scale (1 = the still periods' white noise).
    n_estimated, n_params : int
        Parameters estimated, of all.
    parameters : dict
        name → [value, σ] in the units of :data:`apmcal.solvers.joint.model.UNITS`.
    fixed, dropped_t_test : list of str
        Parameters held fixed, and those the t-test dropped.
    gyr_matrix_cost_deg_per_turn : float
        The gyro matrix's cost [deg per 360° turn].
    gyr_g_sensitivity_at_1g : float
        The g-sensitivity's largest effect at 1 g [rad/s].
    block_samples : int
    recorded_rate_hz : float or None
        [Hz].
    compass_own_fit : bool
    passes : int
        Outer Gauss-Helmert passes run (full fit and t-test refit together).
    converged : bool
        False when a fit stopped at its pass limit before its objective settled.
    explained : dict
        family → [start, result]: median standardised misclosure of the session's conditions
        (1 = the still periods' white noise) under the start (the ellipsoid and static results)
        and under the fit, the yardstick of ``fallback``.
    fallback : str
        Empty when the fit is the result; else why the start was returned instead (the fit
        explains the session worse than the start).
    clipped_turns : int
        Turns left out because the gyro or accelerometer was at its range limit in them.
    """

    conditions: dict[str, int]
    rejected: dict[str, int]
    noise_scale: dict[str, float]
    n_estimated: int
    n_params: int
    parameters: dict[str, list[float]]
    fixed: list[str]
    dropped_t_test: list[str]
    gyr_matrix_cost_deg_per_turn: float
    gyr_g_sensitivity_at_1g: float
    block_samples: int = 1
    recorded_rate_hz: float | None = None
    compass_own_fit: bool = False
    passes: int = 0
    converged: bool = True
    explained: dict[str, list[float]] = field(default_factory=dict)
    fallback: str = ""
    clipped_turns: int = 0


@dataclass
class CalibrationReport:
    """Everything a calibration run found besides the corrections themselves.

    Attributes
    ----------
    recording : str or None
        Which record was calibrated ("RAW_IMU (IMU instance 0)").
    warnings : list of str
        Messages for the user.
    undetermined : dict
        sensor → why its values cannot be trusted (never sent to a vehicle).
    not_calibrated : dict
        sensor → why it was not calibrated at all.
    not_measured : list of str
        Sensors among ``not_calibrated`` that the session did not turn through enough
        directions to measure (not a fault of the data): the overall verdict is the others'.
    holds : Holds
    rotations : dict
        The still periods and full turns used (rotations: axis → :class:`Turn`).
    six_face : SixFaceFit or None
    gyro_turns : GyroTurns or None
        The Ferraris stages.
    one_position : OnePositionFit or None
    joint : JointFit or None
        Those methods' stages.
    gyro_offset_only : bool
        The gyro offset is a mean at rest (ellipsoid method: no matrix).
    ellipsoids : dict
        sensor → quality of its ellipsoid fit (:class:`EllipsoidFit`).
    magnetic_field : MagneticField or None
        The compass's field and coverage.
    at_rest : AtRest or None
        What the sensors read at rest with the calibration in force.
    """

    recording: str | None = None
    warnings: list[str] = field(default_factory=list)
    undetermined: dict[str, str] = field(default_factory=dict)
    not_calibrated: dict[str, str] = field(default_factory=dict)
    not_measured: list[str] = field(default_factory=list)
    holds: Holds = field(default_factory=Holds)
    rotations: dict[str, Turn] = field(default_factory=dict)
    six_face: SixFaceFit | None = None
    gyro_turns: GyroTurns | None = None
    one_position: OnePositionFit | None = None
    joint: JointFit | None = None
    gyro_offset_only: bool = False
    ellipsoids: dict[str, EllipsoidFit] = field(default_factory=dict)
    magnetic_field: MagneticField | None = None
    at_rest: AtRest | None = None

    def to_dict(self) -> dict:
        """The report as plain JSON values (:func:`to_plain`)."""
        return to_plain(self)

    @classmethod
    def from_dict(cls, d: dict) -> "CalibrationReport":
        """The report from :meth:`to_dict`'s output (:func:`from_plain`)."""
        return from_plain(cls, d)


# --------------------------------------------------------------------------- plain values
def to_plain(obj):
    """Dataclasses, numpy arrays and scalars → dicts, lists and plain numbers, recursively.

    Parameters
    ----------
    obj : object
        A dataclass, dict, list, tuple, numpy array or scalar, or a plain value.

    Returns
    -------
    object
        The same with dataclasses as dicts (one key per field), dict keys as str, tuples and
        arrays as (nested) lists and numpy scalars as Python numbers.
    """
    if is_dataclass(obj):
        return {f.name: to_plain(getattr(obj, f.name)) for f in fields(obj)}
    if isinstance(obj, dict):
        return {str(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def from_plain(cls, data: dict):
    """The dataclass ``cls`` from :func:`to_plain`'s output (keys it does not know: ignored;
    missing ones: the default). Arrays come back as float arrays.

    Parameters
    ----------
    cls : type
        A dataclass.
    data : dict
        :func:`to_plain`'s output for an instance of it.

    Returns
    -------
    cls
    """
    hints = typing.get_type_hints(cls)
    kwargs = {f.name: _typed(hints[f.name], data[f.name]) for f in fields(cls) if f.name in data}
    return cls(**kwargs)


def _typed(tp, value):
    if value is None:
        return None
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return _typed(next(a for a in args if a is not type(None)), value)
    if tp is np.ndarray:
        return np.asarray(value, dtype=float)
    if is_dataclass(tp):
        return from_plain(tp, value)
    if origin is dict:
        return {k: _typed(args[1], v) for k, v in value.items()}
    if origin is list:
        return [_typed(args[0], v) for v in value]
    return value
