"""The injected IMU errors (the truth a calibration must recover), with JSON load/save.

Each effect of :data:`sitl.EFFECTS` can be switched on/off; its parameters stay in the file either
way so a run can be repeated with one effect removed. Units are SI in the SENSOR frame (the IMU
chip axes on the board): m/s², rad/s, mGauss, seconds, kelvin.

Default magnitudes (drawn per seed, one-sigma, chosen to look like an APM 2.8 / MPU-6000 +
HMC5883L board; datasheet figures quoted where they exist):

=====================  =========================================  ==============================
effect                 parameter                                  default (1 σ unless fixed)
=====================  =========================================  ==============================
acc_bias               offset [m/s²]                              0.3 (MPU-6000 zero-g ±50..80 mg)
acc_scale              diagonal factor − 1                        0.02 (sensitivity tolerance ±3 %)
acc_cross_axis         α_yz, α_zy, α_zx [rad] ([Oppong] §2.1)     0.005 (cross-axis ±2 %)
acc_misalignment       rotation vector sensor vs board [rad]      0.01
gyro_bias              offset at t=0 [rad/s]                      0.02 (≈1 °/s, spec ±20 °/s)
gyro_bias_drift        linear drift [rad/s per s] ([Oppong] eq.5) 2e-6
gyro_bias_random_walk  rate random walk [rad/s/√s] (or per axis)  fixed 2e-5
gyro_scale             diagonal factor − 1                        0.01 (±3 %)
gyro_misalignment      γ_yz, γ_zy, γ_zx, γ_xz, γ_xy, γ_yx [rad]   0.005 ([Oppong] §2.2 T_g)
g_sensitivity          3×3 [rad/s per m/s²]                       1.8e-4 (0.1 °/s/g)
acc_noise              density [m/s²/√Hz] (or per axis)           fixed 3.9e-3 (400 µg/√Hz)
gyro_noise             density [rad/s/√Hz] (or per axis)          fixed 8.7e-5 (0.005 °/s/√Hz)
temperature_drift      warm-up +12 K, τ 240 s; acc 2e-3 m/s²/K,   coefficients per axis
                       gyro 1.7e-4 rad/s/K per axis (ΔT of the curve, or of an explicit
                       board temperature series given to the error model)
quantization           4096 LSB/g, 16.4 LSB/(°/s) (±8 g, ±2000 °/s APM ranges) — fixed;
                       also RAW_IMU truncation toward zero (off: rounded to nearest)
lowpass_filter         2nd-order Butterworth, 20 Hz (INS_MPU6K_FILTER)             — fixed
                       (``lowpass_hz`` one cutoff or per sensor; skipped at/above Nyquist)
scale_nonlinearity     quadratic k2 (out += k2·x²): acc [1/(m/s²)] 2e-4, gyro [s/rad] 1e-4
time_offset            accelerometer later than gyro [s]          fixed 0.002
motion_contamination   tremor 0.05° at 4-9 Hz + sway 0.3° at 0.1-0.5 Hz (hand-held holds)
earth_rate             Ω = 7.292115e-5 rad/s projected at the site latitude
local_gravity          WGS-84 normal gravity at lat/height (off → 9.80665)
mag_hard_iron          offset [mGauss]                            80
mag_soft_iron          symmetric matrix − I                       0.05 diag, 0.03 off-diag
mag_interference       field per unit throttle [mGauss]           60
mag_noise              per-sample σ [mGauss] (or per axis)        fixed 3
uniform_noise          acc/gyro/mag white noise drawn UNIFORM     OFF by default (ArduPilot
                       with the same σ (half-width √3·σ)          SITL quirk)
triangle_drift         gyro triangle wave, same on all 3 axes:    OFF by default (ArduPilot
                       speed [°/s per minute], half-period [min]  SITL quirk); fixed 0.05, 5
=====================  =========================================  ==============================

Per-axis parameters: ``acc_noise``, ``gyro_noise``, ``mag_noise`` and ``gyro_bias_random_walk``
are a float (all three sensor axes) or a 3-list (x, y, z of the sensor). ``lowpass_hz`` is a float
(accelerometer and gyroscope) or ``{"acc": hz, "gyro": hz}``; a cutoff at or above the Nyquist
frequency of the model's rate skips that filter (see :mod:`apmcal.sensor_model.imu`).

The two ArduPilot SITL quirks (``SIMULATOR_QUIRKS``) reproduce what the real ArduPilot simulator
(libraries/AP_InertialSensor/AP_InertialSensor_SITL.cpp) does to its sensors, so a log from it
can be twinned: its noise is ``noise·rand_float()``, uniform in [−noise, noise] (set σ =
noise/√3 here to mimic SIM_ACC1_RND / SIM_GYR1_RND = noise), and its gyro drift is a triangle
wave of period 2·SIM_DRIFT_TIME minutes rising at SIM_DRIFT_SPEED °/s per minute (defaults 0.05
°/s/min, 5 min: peak 0.25 °/s at 5 min), added to all three axes. They are off in ``Truth()`` and
``Truth.random()`` and a truth file without them loads with them off; ``with_effects(enable=
["all"])`` switches them on like every other effect.

Diagnosis names (``apmcal gap``) — :data:`DIAGNOSIS_EFFECTS` maps each canonical "unmodelled
effect" of the diagnosis to the sitl switches above; ``with_effects`` and the CLI's
``--enable/--disable`` accept either vocabulary:

=====================  ===========================================
diagnosis name         sitl switches
=====================  ===========================================
bias_drift             gyro_bias_drift
bias_random_walk       gyro_bias_random_walk
cross_axis             acc_cross_axis
gyro_scale             gyro_scale, gyro_misalignment (*)
every other name       the sitl effect of the same name
=====================  ===========================================

(*) "gyro_scale" is also a sitl switch: given to ``with_effects`` / the CLI it means the sitl
switch alone (existing behaviour); pass ``prefer="diagnosis"`` to ``with_effects`` (or
:func:`expand_effects`) to read it as the diagnosis name. :data:`NOMINAL_EFFECTS` are the switches
of the nominal model the diagnosis always fits (biases, accelerometer scale, white noise, hard
and soft iron).

Compass interference: the simulator's battery current is ``FULL_THROTTLE_CURRENT_A`` (20 A) ×
throttle, so ``mag_interference`` [mGauss per unit throttle] = 20 × [mGauss per A]
(COMPASS_MOTCT=2 per-amp coefficients).

Mounting (not effects): ``board_orientation`` is how the board (IMU and internal compass) is
turned in the vehicle, an ArduPilot Rotation value, so AHRS_ORIENTATION = board_orientation
undoes it. ``compass_orientation`` None means the compass is the board's internal one; an integer
means an EXTERNAL compass whose chip is turned by that Rotation relative to the vehicle body
(COMPASS_EXTERNAL=1 with COMPASS_ORIENT = compass_orientation undoes it). The mag_* errors are in
the compass chip's own frame.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from apmcal.core.constants import STANDARD_GRAVITY, normal_gravity
from apmcal.core.errors import ApmcalError
from apmcal.solvers.result import SensorCalibration

EFFECTS = (
    "acc_bias", "acc_scale", "acc_cross_axis", "acc_misalignment",
    "gyro_bias", "gyro_bias_drift", "gyro_bias_random_walk", "gyro_scale", "gyro_misalignment",
    "g_sensitivity", "acc_noise", "gyro_noise", "temperature_drift", "quantization",
    "lowpass_filter", "scale_nonlinearity", "time_offset", "motion_contamination", "earth_rate",
    "local_gravity", "mag_hard_iron", "mag_soft_iron", "mag_interference", "mag_noise",
    "uniform_noise", "triangle_drift",
)

# quirks of ArduPilot's own simulator, not of real boards: off unless switched on
SIMULATOR_QUIRKS = ("uniform_noise", "triangle_drift")

# canonical "unmodelled effect" names of the diagnosis (apmcal gap) → the sitl switches each one
# stands for; names not listed under a different sitl name map to the sitl effect of that name
DIAGNOSIS_EFFECTS: dict[str, tuple[str, ...]] = {
    "temperature_drift": ("temperature_drift",),
    "bias_drift": ("gyro_bias_drift",),
    "bias_random_walk": ("gyro_bias_random_walk",),
    "g_sensitivity": ("g_sensitivity",),
    "cross_axis": ("acc_cross_axis",),
    "gyro_scale": ("gyro_scale", "gyro_misalignment"),
    "scale_nonlinearity": ("scale_nonlinearity",),
    "earth_rate": ("earth_rate",),
    "local_gravity": ("local_gravity",),
    "quantization": ("quantization",),
    "lowpass_filter": ("lowpass_filter",),
    "time_offset": ("time_offset",),
    "motion_contamination": ("motion_contamination",),
    "mag_interference": ("mag_interference",),
    "uniform_noise": ("uniform_noise",),
    "triangle_drift": ("triangle_drift",),
}

# the switches of the nominal model the diagnosis always fits (not "unmodelled effects")
NOMINAL_EFFECTS = ("acc_bias", "acc_scale", "gyro_bias", "acc_noise", "gyro_noise",
                   "mag_hard_iron", "mag_soft_iron", "mag_noise")

# the simulator's battery current is FULL_THROTTLE_CURRENT_A × throttle [A] (SYS_STATUS, MAG
# MOX..Z with COMPASS_MOTCT=2), so mag_interference [mGauss per unit throttle] = 20 × [mGauss/A]
FULL_THROTTLE_CURRENT_A = 20.0

# ArduPilot SITL defaults SIM_DRIFT_SPEED [°/s per minute], SIM_DRIFT_TIME [minutes]
ARDUPILOT_DRIFT = {"speed_dps_per_min": 0.05, "time_min": 5.0}


def expand_effects(names, prefer: str = "sitl") -> list[str]:
    """sitl switch names of ``names`` (sitl switches or diagnosis names; "all" kept as is).

    "nominal" stands for :data:`NOMINAL_EFFECTS`. ``prefer="sitl"``: a name that is a sitl
    switch means that switch (so "gyro_scale" is the sitl gyro_scale alone);
    ``prefer="diagnosis"``: a diagnosis name is expanded first ("gyro_scale" → gyro_scale,
    gyro_misalignment). Unknown names raise ApmcalError listing both vocabularies.
    """
    if prefer not in ("sitl", "diagnosis"):
        raise ValueError(f"prefer must be 'sitl' or 'diagnosis', got {prefer!r}")
    out: list[str] = []
    for name in names:
        if name == "all":
            out.append(name)
        elif name == "nominal":     # what the diagnosis always fits
            out.extend(NOMINAL_EFFECTS)
        elif prefer == "diagnosis" and name in DIAGNOSIS_EFFECTS:
            out.extend(DIAGNOSIS_EFFECTS[name])
        elif name in EFFECTS:
            out.append(name)
        elif name in DIAGNOSIS_EFFECTS:
            out.extend(DIAGNOSIS_EFFECTS[name])
        else:
            raise ApmcalError(f"unknown effect {name!r}; sitl effects: {', '.join(EFFECTS)}; "
                            f"diagnosis names: {', '.join(DIAGNOSIS_EFFECTS)}")
    return out


def default_enabled() -> dict:
    """Every effect on except the ArduPilot simulator quirks."""
    return {e: e not in SIMULATOR_QUIRKS for e in EFFECTS}


def per_axis(value, name: str = "parameter") -> np.ndarray:
    """A float or a 3-list as a (3,) float array (one value per sensor axis)."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape not in ((), (3,)):
        raise ApmcalError(f"{name} must be a number or a list of 3 numbers, got {value!r}")
    return np.broadcast_to(a, (3,)).copy()


# default site: Accra ([Oppong] was recorded in Ghana), 60 m; year None: the WMM epoch is the
# date of the vehicle's own clock (SimVehicle start_unix), as for a real vehicle
DEFAULT_SITE = {"lat": 5.6037, "lon": -0.1870, "alt": 60.0, "year": None}


def _zeros(n=3):
    return field(default_factory=lambda: [0.0] * n)


@dataclass
class Truth:
    """Every injected error parameter plus which effects are on (see module docstring)."""

    enabled: dict = field(default_factory=default_enabled)
    seed: int = 0
    site: dict = field(default_factory=lambda: dict(DEFAULT_SITE))
    board_orientation: int = 0
    compass_orientation: int | None = None
    acc_bias: list = _zeros()
    acc_scale: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    acc_cross_axis: list = _zeros()
    acc_misalignment: list = _zeros()
    gyro_bias: list = _zeros()
    gyro_bias_drift: list = _zeros()
    gyro_bias_random_walk: float | list = 2e-5           # or per axis [x, y, z]
    gyro_scale: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    gyro_misalignment: list = _zeros(6)
    g_sensitivity: list = field(default_factory=lambda: np.zeros((3, 3)).tolist())
    acc_noise: float | list = 3.9e-3                     # or per axis [x, y, z]
    gyro_noise: float | list = 8.7e-5
    temperature: dict = field(default_factory=lambda: {
        "ambient_c": 25.0, "rise_k": 12.0, "tau_s": 240.0,
        "acc_coef": [0.0] * 3, "gyro_coef": [0.0] * 3})
    quantization: dict = field(default_factory=lambda: {"acc_lsb_per_g": 4096.0,
                                                        "gyro_lsb_per_dps": 16.4,
                                                        "acc_range_g": 8.0,
                                                        "gyro_range_dps": 2000.0})
    lowpass_hz: float | dict = 20.0                      # or {"acc": hz, "gyro": hz}
    scale_nonlinearity: dict = field(default_factory=lambda: {"acc": [0.0] * 3,
                                                              "gyro": [0.0] * 3})
    time_offset: float = 0.002
    motion_contamination: dict = field(default_factory=lambda: {
        "tremor_deg": 0.05, "tremor_hz": [4.0, 9.0], "sway_deg": 0.3, "sway_hz": [0.1, 0.5]})
    mag_hard_iron: list = _zeros()
    mag_soft_iron: list = field(default_factory=lambda: np.eye(3).tolist())
    mag_interference: list = _zeros()
    mag_noise: float | list = 3.0
    triangle_drift: dict = field(default_factory=lambda: dict(ARDUPILOT_DRIFT))

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def random(cls, seed: int, site: dict | None = None) -> "Truth":
        """APM 2.8-like errors drawn from ``seed`` (magnitudes in the module docstring)."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5171]))
        n = lambda s, k=3: (rng.standard_normal(k) * s).tolist()
        soft = np.eye(3) + np.diag(rng.standard_normal(3) * 0.05)
        off = rng.standard_normal(3) * 0.03
        soft[0, 1] = soft[1, 0] = off[0]
        soft[0, 2] = soft[2, 0] = off[1]
        soft[1, 2] = soft[2, 1] = off[2]
        t = cls(seed=seed, site=dict(site or DEFAULT_SITE))
        t.acc_bias, t.acc_scale = n(0.3), (1 + rng.standard_normal(3) * 0.02).tolist()
        t.acc_cross_axis, t.acc_misalignment = n(0.005), n(0.01)
        t.gyro_bias, t.gyro_bias_drift = n(0.02), n(2e-6)
        t.gyro_scale = (1 + rng.standard_normal(3) * 0.01).tolist()
        t.gyro_misalignment = n(0.005, 6)
        t.g_sensitivity = (rng.standard_normal((3, 3)) * 1.8e-4).tolist()
        t.temperature["acc_coef"], t.temperature["gyro_coef"] = n(2e-3), n(1.7e-4)
        t.scale_nonlinearity = {"acc": n(2e-4), "gyro": n(1e-4)}
        t.mag_hard_iron, t.mag_soft_iron, t.mag_interference = n(80.0), soft.tolist(), n(60.0)
        return t

    def with_effects(self, enable: list[str] | None = None, disable: list[str] | None = None,
                     prefer: str = "sitl") -> "Truth":
        """Switch effects by name ("all" for every one, the simulator quirks included);
        ``disable`` is applied first, so disable=["all"], enable=["acc_bias"] isolates one effect.

        Names are sitl switches (:data:`EFFECTS`) or diagnosis names (:data:`DIAGNOSIS_EFFECTS`,
        expanded to their switches); ``prefer`` decides the one name in both vocabularies,
        "gyro_scale" (see :func:`expand_effects`). Unknown names raise ApmcalError.
        """
        for names, state in ((disable or [], False), (enable or [], True)):
            for name in expand_effects(names, prefer):
                if name == "all":
                    self.enabled = {e: state for e in EFFECTS}
                else:
                    self.enabled[name] = state
        return self

    def on(self, effect: str) -> bool:
        """True when ``effect`` is switched on."""
        return bool(self.enabled.get(effect, False))

    # ---- derived quantities ---------------------------------------------------------------
    def lowpass_cutoff(self, sensor: str) -> float:
        """Low-pass cutoff [Hz] of "acc" or "gyro" (``lowpass_hz`` a float or a per-sensor dict)."""
        hz = self.lowpass_hz
        if isinstance(hz, dict):
            try:
                return float(hz[sensor])
            except (KeyError, TypeError, ValueError):
                raise ApmcalError(f"lowpass_hz needs a number for {sensor!r}, got {hz!r}") from None
        try:
            return float(hz)
        except (TypeError, ValueError):
            raise ApmcalError(f"lowpass_hz must be a number or {{'acc': hz, 'gyro': hz}}, "
                            f"got {hz!r}") from None

    def gravity(self) -> float:
        """Local gravity magnitude [m/s²] (WGS-84 normal gravity when local_gravity is on)."""
        if self.on("local_gravity"):
            return normal_gravity(self.site["lat"], self.site["alt"])
        return STANDARD_GRAVITY

    def acc_forward(self) -> np.ndarray:
        """F with s = F·f + b: sensor output from board-frame specific force.

        [Oppong] eq. 1: a_s = K_a·R_a·a_p + b with R_a = T_a⁻¹ (non-orthogonality), times the
        rotation of the triad relative to the board (misalignment).
        """
        k = np.diag(self.acc_scale) if self.on("acc_scale") else np.eye(3)
        t_a = np.eye(3)
        if self.on("acc_cross_axis"):
            a_yz, a_zy, a_zx = self.acc_cross_axis
            t_a = np.array([[1, -a_yz, a_zy], [0, 1, -a_zx], [0, 0, 1.0]])
        r = _expm(self.acc_misalignment).T if self.on("acc_misalignment") else np.eye(3)
        return k @ np.linalg.inv(t_a) @ r

    def gyro_forward(self) -> np.ndarray:
        """F with ω_s = F·ω + b ([Oppong] eq. 2, full T_g with six γ terms)."""
        k = np.diag(self.gyro_scale) if self.on("gyro_scale") else np.eye(3)
        t_g = np.eye(3)
        if self.on("gyro_misalignment"):
            g_yz, g_zy, g_zx, g_xz, g_xy, g_yx = self.gyro_misalignment
            t_g = np.array([[1, -g_yz, g_zy], [g_xz, 1, -g_zx], [-g_xy, g_yx, 1.0]])
        return k @ np.linalg.inv(t_g)

    def mag_forward(self) -> np.ndarray:
        """Soft-iron matrix S with m_s = S·m + h [mGauss]; identity when mag_soft_iron is off."""
        return np.asarray(self.mag_soft_iron, float) if self.on("mag_soft_iron") else np.eye(3)

    def sensor_calibrations(self) -> dict[str, SensorCalibration]:
        """The truth in the project convention calibrated = M @ (measured − offset − drift·t −
        G·f), f the true specific force (board frame; what the calibrated accelerometer gives)."""
        z = np.zeros(3)
        acc = SensorCalibration(offset=self.acc_bias if self.on("acc_bias") else z,
                                matrix=np.linalg.inv(self.acc_forward()))
        gyr = SensorCalibration(offset=self.gyro_bias if self.on("gyro_bias") else z,
                                matrix=np.linalg.inv(self.gyro_forward()),
                                drift=self.gyro_bias_drift if self.on("gyro_bias_drift") else z,
                                g_sensitivity=(self.g_sensitivity if self.on("g_sensitivity")
                                               else np.zeros((3, 3))))
        mag = SensorCalibration(offset=self.mag_hard_iron if self.on("mag_hard_iron") else z,
                                matrix=np.linalg.inv(self.mag_forward()))
        return {"acc": acc, "gyr": gyr, "mag": mag}

    # ---- JSON -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The truth as JSON-ready data: each sensor's calibration, the effects, gravity [m/s²]."""
        d = {k: v.to_dict() for k, v in self.sensor_calibrations().items()}
        d["effects"] = asdict(self)
        d["gravity_ms2"] = self.gravity()
        return d

    def save(self, path: str | Path, extra: dict | None = None) -> None:
        """Write :meth:`to_dict` (plus ``extra`` keys) as JSON to ``path``."""
        d = self.to_dict()
        d.update(extra or {})
        Path(path).write_text(json.dumps(d, indent=1) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "Truth":
        """Read a truth file written by :meth:`save` (only the "effects" block is used)."""
        try:
            d = json.loads(Path(path).read_text())["effects"]
            t = cls(**d)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ApmcalError(f"not a sitl truth file ({exc})", path) from None
        unknown = set(t.enabled) - set(EFFECTS)
        if unknown:
            raise ApmcalError(f"unknown effects {sorted(unknown)}", path)
        # a file older than an effect (uniform_noise, triangle_drift) loads with it off
        t.enabled = {e: bool(t.enabled.get(e, False)) for e in EFFECTS}
        try:
            t.check()
        except ApmcalError as exc:
            raise ApmcalError(str(exc), path) from None
        return t

    def check(self) -> None:
        """Raise ApmcalError when a parameter has the wrong shape (per-axis values, low-pass)."""
        for name in ("acc_noise", "gyro_noise", "mag_noise", "gyro_bias_random_walk"):
            per_axis(getattr(self, name), name)
        for sensor in ("acc", "gyro"):
            hz = self.lowpass_cutoff(sensor)
            if not hz > 0:
                raise ApmcalError(f"lowpass_hz must be positive, got {self.lowpass_hz!r}")
        try:
            float(self.triangle_drift["speed_dps_per_min"])
            if not float(self.triangle_drift["time_min"]) > 0:
                raise ValueError
        except (KeyError, TypeError, ValueError):
            raise ApmcalError("triangle_drift must be {'speed_dps_per_min': x, 'time_min': > 0}, "
                            f"got {self.triangle_drift!r}") from None


def _expm(rotvec) -> np.ndarray:
    """Rotation matrix of a rotation vector [rad] (Rodrigues)."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.asarray(rotvec, float)).as_matrix()
