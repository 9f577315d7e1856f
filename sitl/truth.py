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
acc_cross_axis         α_yz, α_zy, α_zx [rad] (seed 002 §2.1)     0.005 (cross-axis ±2 %)
acc_misalignment       rotation vector sensor vs board [rad]      0.01
gyro_bias              offset at t=0 [rad/s]                      0.02 (≈1 °/s, spec ±20 °/s)
gyro_bias_drift        linear drift [rad/s per s] (seed 002 eq.5) 2e-6
gyro_bias_random_walk  rate random walk [rad/s/√s]                fixed 2e-5
gyro_scale             diagonal factor − 1                        0.01 (±3 %)
gyro_misalignment      γ_yz, γ_zy, γ_zx, γ_xz, γ_xy, γ_yx [rad]   0.005 (seed 002 §2.2 T_g)
g_sensitivity          3×3 [rad/s per m/s²]                       1.8e-4 (0.1 °/s/g)
acc_noise              density [m/s²/√Hz]                         fixed 3.9e-3 (400 µg/√Hz)
gyro_noise             density [rad/s/√Hz]                        fixed 8.7e-5 (0.005 °/s/√Hz)
temperature_drift      warm-up +12 K, τ 240 s; acc 2e-3 m/s²/K,   coefficients per axis
                       gyro 1.7e-4 rad/s/K per axis
quantization           4096 LSB/g, 16.4 LSB/(°/s) (±8 g, ±2000 °/s APM ranges) — fixed;
                       also RAW_IMU truncation toward zero (off: rounded to nearest)
lowpass_filter         2nd-order Butterworth, 20 Hz (INS_MPU6K_FILTER)             — fixed
scale_nonlinearity     quadratic k2 (out += k2·x²): acc [1/(m/s²)] 2e-4, gyro [s/rad] 1e-4
time_offset            accelerometer later than gyro [s]          fixed 0.002
motion_contamination   tremor 0.05° at 4-9 Hz + sway 0.3° at 0.1-0.5 Hz (hand-held holds)
earth_rate             Ω = 7.292115e-5 rad/s projected at the site latitude
local_gravity          WGS-84 normal gravity at lat/height (off → 9.80665)
mag_hard_iron          offset [mGauss]                            80
mag_soft_iron          symmetric matrix − I                       0.05 diag, 0.03 off-diag
mag_interference       field per unit throttle [mGauss]           60
mag_noise              per-sample σ [mGauss]                      fixed 3
=====================  =========================================  ==============================

Mounting (not effects): ``board_orientation`` is how the board (IMU and internal compass) is
turned in the vehicle, an ArduPilot Rotation value, so AHRS_ORIENTATION = board_orientation
undoes it. ``compass_orientation`` None means the compass is the board's internal one; an integer
means an EXTERNAL compass whose chip is turned by that Rotation relative to the vehicle body
(COMPASS_EXTERNAL=1 with COMPASS_ORIENT = compass_orientation undoes it). The mag_* errors are in
the compass chip's own frame.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, asdict
from pathlib import Path

import numpy as np

from apmcal.constants import normal_gravity, STANDARD_GRAVITY
from sitl.errors import SitlError
from apmcal.solvers.result import SensorCalibration

EFFECTS = (
    "acc_bias", "acc_scale", "acc_cross_axis", "acc_misalignment",
    "gyro_bias", "gyro_bias_drift", "gyro_bias_random_walk", "gyro_scale", "gyro_misalignment",
    "g_sensitivity", "acc_noise", "gyro_noise", "temperature_drift", "quantization",
    "lowpass_filter", "scale_nonlinearity", "time_offset", "motion_contamination", "earth_rate",
    "local_gravity", "mag_hard_iron", "mag_soft_iron", "mag_interference", "mag_noise",
)

# default site: Accra (seed 002 was recorded in Ghana), 60 m; year None: the WMM epoch is the
# date of the vehicle's own clock (SimVehicle start_unix), as for a real vehicle
DEFAULT_SITE = {"lat": 5.6037, "lon": -0.1870, "alt": 60.0, "year": None}


def _zeros(n=3):
    return field(default_factory=lambda: [0.0] * n)


@dataclass
class Truth:
    """Every injected error parameter plus which effects are on (see module docstring)."""

    enabled: dict = field(default_factory=lambda: {e: True for e in EFFECTS})
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
    gyro_bias_random_walk: float = 2e-5
    gyro_scale: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    gyro_misalignment: list = _zeros(6)
    g_sensitivity: list = field(default_factory=lambda: np.zeros((3, 3)).tolist())
    acc_noise: float = 3.9e-3
    gyro_noise: float = 8.7e-5
    temperature: dict = field(default_factory=lambda: {
        "ambient_c": 25.0, "rise_k": 12.0, "tau_s": 240.0,
        "acc_coef": [0.0] * 3, "gyro_coef": [0.0] * 3})
    quantization: dict = field(default_factory=lambda: {"acc_lsb_per_g": 4096.0,
                                                        "gyro_lsb_per_dps": 16.4,
                                                        "acc_range_g": 8.0,
                                                        "gyro_range_dps": 2000.0})
    lowpass_hz: float = 20.0
    scale_nonlinearity: dict = field(default_factory=lambda: {"acc": [0.0] * 3,
                                                              "gyro": [0.0] * 3})
    time_offset: float = 0.002
    motion_contamination: dict = field(default_factory=lambda: {
        "tremor_deg": 0.05, "tremor_hz": [4.0, 9.0], "sway_deg": 0.3, "sway_hz": [0.1, 0.5]})
    mag_hard_iron: list = _zeros()
    mag_soft_iron: list = field(default_factory=lambda: np.eye(3).tolist())
    mag_interference: list = _zeros()
    mag_noise: float = 3.0

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

    def with_effects(self, enable: list[str] | None = None, disable: list[str] | None = None
                     ) -> "Truth":
        """Switch effects by canonical name ("all" for every one); ``disable`` is applied first,
        so disable=["all"], enable=["acc_bias"] isolates one effect. Unknown names raise
        SitlError."""
        for names, state in ((disable or [], False), (enable or [], True)):
            for name in names:
                if name == "all":
                    self.enabled = {e: state for e in EFFECTS}
                    continue
                if name not in EFFECTS:
                    raise SitlError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
                self.enabled[name] = state
        return self

    def on(self, effect: str) -> bool:
        return bool(self.enabled.get(effect, False))

    # ---- derived quantities ---------------------------------------------------------------
    def gravity(self) -> float:
        """Local gravity magnitude [m/s²] (WGS-84 normal gravity when local_gravity is on)."""
        if self.on("local_gravity"):
            return normal_gravity(self.site["lat"], self.site["alt"])
        return STANDARD_GRAVITY

    def acc_forward(self) -> np.ndarray:
        """F with s = F·f + b: sensor output from board-frame specific force.

        Seed 002 eq. 1: a_s = K_a·R_a·a_p + b with R_a = T_a⁻¹ (non-orthogonality), times the
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
        """F with ω_s = F·ω + b (seed 002 eq. 2, full T_g with six γ terms)."""
        k = np.diag(self.gyro_scale) if self.on("gyro_scale") else np.eye(3)
        t_g = np.eye(3)
        if self.on("gyro_misalignment"):
            g_yz, g_zy, g_zx, g_xz, g_xy, g_yx = self.gyro_misalignment
            t_g = np.array([[1, -g_yz, g_zy], [g_xz, 1, -g_zx], [-g_xy, g_yx, 1.0]])
        return k @ np.linalg.inv(t_g)

    def mag_forward(self) -> np.ndarray:
        return np.asarray(self.mag_soft_iron, float) if self.on("mag_soft_iron") else np.eye(3)

    def sensor_calibrations(self) -> dict[str, SensorCalibration]:
        """The truth in the project convention calibrated = M @ (measured − offset − drift·t)."""
        z = np.zeros(3)
        acc = SensorCalibration(offset=self.acc_bias if self.on("acc_bias") else z,
                                matrix=np.linalg.inv(self.acc_forward()))
        gyr = SensorCalibration(offset=self.gyro_bias if self.on("gyro_bias") else z,
                                matrix=np.linalg.inv(self.gyro_forward()),
                                drift=self.gyro_bias_drift if self.on("gyro_bias_drift") else z)
        mag = SensorCalibration(offset=self.mag_hard_iron if self.on("mag_hard_iron") else z,
                                matrix=np.linalg.inv(self.mag_forward()))
        return {"acc": acc, "gyr": gyr, "mag": mag}

    # ---- JSON -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {k: v.to_dict() for k, v in self.sensor_calibrations().items()}
        d["effects"] = asdict(self)
        d["gravity_ms2"] = self.gravity()
        return d

    def save(self, path: str | Path, extra: dict | None = None) -> None:
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
            raise SitlError(f"not a sitl truth file ({exc})", path) from None
        unknown = set(t.enabled) - set(EFFECTS)
        if unknown:
            raise SitlError(f"unknown effects {sorted(unknown)}", path)
        return t


def _expm(rotvec) -> np.ndarray:
    """Rotation matrix of a rotation vector [rad] (Rodrigues)."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.asarray(rotvec, float)).as_matrix()
