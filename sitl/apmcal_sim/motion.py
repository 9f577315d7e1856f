"""Motion scripts: the true attitude and body rate of the vehicle as functions of time.

A script is a list of segments: holds (static, one pose) and rotations about one BODY axis with a
smooth (1 − cos) rate profile, so attitude and rate are analytic and exact at any time — the
accelerometer can be evaluated at t − time_offset. Hand-held tremor/sway (motion_contamination)
is a small rotation Exp(δ(t)) applied on top: R = R_script·Exp(δ), ω = Exp(δ)ᵀω_script + J_r(δ)·δ'.

Attitude R_nb maps body (FRD) vectors to NED; poses are built as Rz(yaw)·Ry(pitch)·Rx(roll).
Face names follow imucal / Ferraris: "x_p" = x axis reads +g (x up, nose up), "x_a" = x down.

Each segment also carries a throttle (0..1), constant or a linear ramp over the segment
(:meth:`Motion.throttle`); it drives the mag_interference effect and COMPASS_MOT. Only the
``motors`` and ``diagnosis`` scripts run the motors: every other script is at throttle 0
throughout.

``diagnosis`` (the ``apmcal gap`` benchmark session) is the Ferraris session followed by the
``motors`` section, level and still: one session that exercises every effect, compass
interference included.

``handheld_real`` is a hand-held session as people record one at a desk: uneven holds, fast
turns that also move the board (a segment's ``shift``: its NED displacement, on the same smooth
profile as the turn, so the velocity is zero at both ends), the tremor of a hand (the script's
own :attr:`Motion.tremor`, in place of the truth's ``motion_contamination`` figures) and the
slowly changing field of a laptop beside it (:class:`LaptopField`, :attr:`Motion.disturbance`,
added to the Earth's field in NED). ``handheld_laptop`` is the same right beside the laptop
(five times the field): the compass's ellipsoid, the joint fit's start, is then far off.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from apmcal_sim.firmware import euler_matrix

# ardupilot-facts.md (Frames and signs): nose down → acc_x ≈ −g, left side down → acc_y ≈ +g,
# upside down → acc_z ≈ +g.
POSES = {
    "level": (0, 0, 0), "left": (-90, 0, 0), "right": (90, 0, 0),
    "nosedown": (0, -90, 0), "noseup": (0, 90, 0), "back": (180, 0, 0),
    "x_p": (0, 90, 0), "x_a": (0, -90, 0), "y_p": (-90, 0, 0), "y_a": (90, 0, 0),
    "z_p": (180, 0, 0), "z_a": (0, 0, 0),
}
# ArduPilot accelcal ACCELCAL_VEHICLE_POS values (param1 of MAV_CMD_ACCELCAL_VEHICLE_POS)
ACCELCAL_POSES = {1: "level", 2: "left", 3: "right", 4: "nosedown", 5: "noseup", 6: "back"}
SCRIPTS = ("ferraris", "ardupilot6", "onepos", "tumble", "warmup", "operator", "motors",
           "diagnosis", "handheld", "handheld_real", "handheld_laptop")


def pose_matrix(name: str, yaw_deg: float = 0.0) -> np.ndarray:
    """R_nb of a named pose, heading ``yaw_deg`` (applied about NED down)."""
    r, p, _ = POSES[name]
    return euler_matrix(0, 0, yaw_deg) @ euler_matrix(r, p, 0)


@dataclass
class Segment:
    """One piece of a motion: a hold, or a turn about a fixed body axis (smooth rate profile).

    Times in s from the start of the motion, attitudes as body → NED rotation matrices (3, 3).
    """
    t0: float
    duration: float
    r0: np.ndarray                   # attitude at the start (body → NED)
    axis: np.ndarray                 # body-frame unit rotation axis (zeros for a hold)
    angle: float                     # total rotation [rad] (0 for a hold)
    label: str
    r1: np.ndarray | None = None     # exact end pose when known (avoids round-off build-up)
    throttle: tuple = (0.0, 0.0)     # throttle at the start and end (linear ramp in between)
    shift: np.ndarray | None = None  # NED displacement over the segment [m] (None: none)

    @property
    def t1(self) -> float:
        """End time [s]."""
        return self.t0 + self.duration

    def end_pose(self) -> np.ndarray:
        """Attitude at the end (body → NED), shape (3, 3)."""
        if self.r1 is not None:
            return self.r1
        return self.r0 @ Rotation.from_rotvec(self.axis * self.angle).as_matrix()


@dataclass
class Motion:
    """A sequence of segments; beyond the last one the vehicle holds its final pose."""

    segments: list = field(default_factory=list)
    start_pose: np.ndarray = field(default_factory=lambda: np.eye(3))
    #: hand tremor figures (the keys of Truth.motion_contamination) used instead of the
    #: truth's when that effect is on; None: the truth's
    tremor: dict | None = None
    #: field added to the Earth's [mGauss, NED] at times t (n,) → (n, 3); None: none
    disturbance: object = None

    @property
    def duration(self) -> float:
        """Length [s] of all segments."""
        return self.segments[-1].t1 if self.segments else 0.0

    def end_pose(self) -> np.ndarray:
        """Attitude after the last segment (body → NED), shape (3, 3)."""
        return self.segments[-1].end_pose() if self.segments else self.start_pose

    def hold(self, seconds: float, label: str, throttle: float | tuple = 0.0) -> "Motion":
        """Hold the current pose; ``throttle`` a level or a (start, end) ramp."""
        self.segments.append(Segment(self.duration, seconds, self.end_pose(), np.zeros(3), 0.0,
                                     label, throttle=_ramp(throttle)))
        return self

    def rotate(self, axis, angle_deg: float, seconds: float, label: str,
               throttle: float | tuple = 0.0, shift=None) -> "Motion":
        """Turn by ``angle_deg`` [deg] about the body ``axis`` (3,) in ``seconds`` [s] (the module's
        smooth rate profile); ``throttle`` a level or a (start, end) ramp; ``shift`` (3,) the
        board's NED displacement [m] during the turn, on the same profile (None: none)."""
        axis = np.asarray(axis, float) / np.linalg.norm(axis)
        self.segments.append(Segment(self.duration, seconds, self.end_pose(), axis,
                                     np.radians(angle_deg), label, throttle=_ramp(throttle),
                                     shift=None if shift is None else np.asarray(shift, float)))
        return self

    def acceleration(self, t) -> np.ndarray:
        """Linear acceleration [m/s², NED] (n, 3) at times t (n,): the second derivative of each
        segment's ``shift`` on the smooth profile, shift·2π/T²·sin 2πu; zeros where none."""
        t = np.atleast_1d(np.asarray(t, float))
        out = np.zeros((len(t), 3))
        for s in self.segments:
            if s.shift is None:
                continue
            m = (t >= s.t0) & (t < s.t1)
            if m.any():
                u = (t[m] - s.t0) / s.duration
                out[m] = np.outer(2 * np.pi / s.duration ** 2 * np.sin(2 * np.pi * u), s.shift)
        return out

    def field_disturbance(self, t) -> np.ndarray:
        """The :attr:`disturbance` [mGauss, NED] (n, 3) at times t (n,); zeros without one."""
        t = np.atleast_1d(np.asarray(t, float))
        return np.zeros((len(t), 3)) if self.disturbance is None else self.disturbance(t)

    def throttle(self, t) -> np.ndarray:
        """Throttle (0..1) at times t (n,); beyond the last segment its end value holds."""
        t = np.atleast_1d(np.asarray(t, float))
        table = self._throttle_table()
        if table is None:
            return np.zeros(len(t))          # motors never run: exact zeros, no arithmetic
        t0, duration, start, end = table
        seg = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(t0) - 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(duration[seg] > 0,
                         np.clip((t - t0[seg]) / duration[seg], 0.0, 1.0), 1.0)
        return start[seg] + (end[seg] - start[seg]) * u

    def _throttle_table(self):
        """Segment starts, durations and throttle ends as arrays (cached per segment count;
        the throttle is asked for at every logged sample), or None when no motor runs."""
        cached = getattr(self, "_throttle_cache", None)
        if cached is not None and cached[0] == len(self.segments):
            return cached[1]
        table = None
        if any(any(s.throttle) for s in self.segments):
            table = (np.array([s.t0 for s in self.segments]),
                     np.array([s.duration for s in self.segments]),
                     np.array([s.throttle[0] for s in self.segments], float),
                     np.array([s.throttle[1] for s in self.segments], float))
        self._throttle_cache = (len(self.segments), table)
        return table                       # motors never run: exact zeros, no arithmetic

    def move_to(self, target: np.ndarray, seconds: float, label: str = "transition") -> "Motion":
        """Rotate about one body axis from the current end pose to ``target``."""
        rv = Rotation.from_matrix(self.end_pose().T @ target).as_rotvec()
        ang = np.linalg.norm(rv)
        if ang < 1e-9:
            return self.hold(seconds, label)
        self.rotate(rv / ang, np.degrees(ang), seconds, label)
        self.segments[-1].r1 = np.array(target, dtype=float)
        return self

    def sections(self) -> list[tuple[str, float, float]]:
        """(label, t_start, t_end) of consecutive segments sharing a label."""
        out: list = []
        for s in self.segments:
            if out and out[-1][0] == s.label:
                out[-1] = (s.label, out[-1][1], s.t1)
            else:
                out.append((s.label, s.t0, s.t1))
        return out

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Script attitude R (n,3,3), body rate ω (n,3) [rad/s], segment index (n,) at times t."""
        t = np.atleast_1d(np.asarray(t, float))
        n = len(t)
        rot = np.repeat(self.end_pose()[None], n, axis=0)
        rate = np.zeros((n, 3))
        idx = np.full(n, len(self.segments))
        if not self.segments:
            return rot, rate, idx
        starts = np.array([s.t0 for s in self.segments])
        seg = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.segments) - 1)
        for k in np.unique(seg):
            s = self.segments[k]
            m = (seg == k) & (t < s.t1)      # after the last segment: final pose (default)
            if not m.any():
                continue
            idx[m] = k
            u = np.clip((t[m] - s.t0) / s.duration, 0.0, 1.0)
            # smooth profile: angle(u) = θ(u − sin 2πu / 2π), rate = θ/T (1 − cos 2πu)
            ang = s.angle * (u - np.sin(2 * np.pi * u) / (2 * np.pi))
            rate[m] = np.outer(s.angle / s.duration * (1 - np.cos(2 * np.pi * u)), s.axis)
            rot[m] = s.r0 @ Rotation.from_rotvec(np.outer(ang, s.axis)).as_matrix()
        return rot, rate, idx


class Tremor:
    """Hand-held contamination δ(t) [rad]: sums of sinusoids with seeded phases (smooth, exact δ')."""

    def __init__(self, params: dict, seed: int):
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7E30]))
        comps = []
        for amp_key, band_key, count in (("tremor_deg", "tremor_hz", 4), ("sway_deg", "sway_hz", 3)):
            amp = np.radians(params[amp_key]) / np.sqrt(count)
            lo, hi = params[band_key]
            for _ in range(count):
                comps.append((amp * rng.standard_normal(3), rng.uniform(lo, hi, 3),
                              rng.uniform(0, 2 * np.pi, 3)))
        self.amp = np.array([c[0] for c in comps])     # (k, 3)
        self.freq = np.array([c[1] for c in comps])
        self.phase = np.array([c[2] for c in comps])

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """δ (n,3) [rad] and δ' (n,3) [rad/s]."""
        arg = 2 * np.pi * self.freq[None] * t[:, None, None] + self.phase[None]
        d = (self.amp[None] * np.sin(arg)).sum(axis=1)
        dd = (self.amp[None] * 2 * np.pi * self.freq[None] * np.cos(arg)).sum(axis=1)
        return d, dd


class LaptopField:
    """The slowly changing field of a laptop beside the board [mGauss, NED]: a few sinusoids
    per axis with periods of 20-200 s (its disk and fans, the screen's angle, the hand moving
    nearer and farther), seeded phases, ``mgauss`` the RMS of each axis's sum.

    Parameters
    ----------
    mgauss : float
        RMS per NED axis [mGauss].
    seed : int
    """

    def __init__(self, mgauss: float, seed: int):
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x1A9]))
        self.amp = mgauss * np.sqrt(2.0 / 3.0) * np.ones((3, 3))      # 3 components per axis
        self.freq = 1.0 / rng.uniform(20.0, 200.0, (3, 3))
        self.phase = rng.uniform(0, 2 * np.pi, (3, 3))
        self.offset = rng.normal(0.0, mgauss, 3)       # its mean field where the board is held

    def __call__(self, t) -> np.ndarray:
        """Field [mGauss, NED] (n, 3) at times t [s] (n,)."""
        t = np.atleast_1d(np.asarray(t, float))
        arg = 2 * np.pi * self.freq[None] * t[:, None, None] + self.phase[None]
        return self.offset + (self.amp[None] * np.sin(arg)).sum(axis=1)


def _ramp(throttle) -> tuple[float, float]:
    """(start, end) throttle from a level or a pair, each checked to lie in 0..1."""
    a, b = (throttle, throttle) if np.isscalar(throttle) else throttle
    if not (0.0 <= a <= 1.0 and 0.0 <= b <= 1.0):
        raise ValueError(f"throttle must be within 0..1, got {throttle!r}")
    return float(a), float(b)


def _hat(v: np.ndarray) -> np.ndarray:
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1), np.stack([v[:, 2], z, -v[:, 0]], -1),
                     np.stack([-v[:, 1], v[:, 0], z], -1)], axis=1)


def contaminate(rot, rate, t, tremor: Tremor | None):
    """Apply tremor: R·Exp(δ), body rate Exp(δ)ᵀω + J_r(δ)δ' (exact right Jacobian)."""
    if tremor is None:
        return rot, rate
    d, dd = tremor(t)
    e = Rotation.from_rotvec(d).as_matrix()
    th = np.linalg.norm(d, axis=1)[:, None, None]
    th = np.where(th < 1e-12, 1e-12, th)
    h = _hat(d)
    jr = np.eye(3) - (1 - np.cos(th)) / th ** 2 * h + (th - np.sin(th)) / th ** 3 * (h @ h)
    rate = np.einsum("nji,nj->ni", e, rate) + np.einsum("nij,nj->ni", jr, dd)
    return rot @ e, rate


# ---- the scripts -----------------------------------------------------------------------------
def ferraris(hold: float = 20.0, pause: float = 20.0, step_s: float = 2.0,
             move_s: float = 3.0) -> Motion:
    """[Oppong] §3.1: six faces ~20 s each, then for x, y, z: that axis antiparallel to gravity
    ("_a" face), four −90° steps about it with ~20 s idle after each (imucal expects −360°)."""
    m = Motion(start_pose=pose_matrix("x_p"))
    for face in ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a"):
        if m.segments:
            m.move_to(pose_matrix(face), move_s)
        m.hold(hold, face)
    for ax, face in zip(np.eye(3), ("x_a", "y_a", "z_a")):
        m.move_to(pose_matrix(face), move_s)
        label = face[0] + "_rot"
        m.hold(pause, label)
        for _ in range(4):
            m.rotate(ax, -90.0, step_s, label)
            m.hold(pause, label)
    return m


def ardupilot6(hold: float = 10.0, move_s: float = 3.0) -> Motion:
    """ArduPilot's accelcal order: level, LEFT, RIGHT, nose DOWN, nose UP, BACK."""
    m = Motion()
    for k in range(1, 7):
        name = ACCELCAL_POSES[k]
        if m.segments:
            m.move_to(pose_matrix(name), move_s)
        m.hold(hold, name)
    return m


def onepos(seconds: float = 60.0) -> Motion:
    """[Oppong] one-position method: one minute static, x north, z down."""
    return Motion().hold(seconds, "onepos")


def warmup(seconds: float = 600.0) -> Motion:
    """A board warming up at rest: one hold of ``seconds`` [s]."""
    return Motion().hold(seconds, "warmup")


def tumble(seconds: float = 90.0, seed: int = 0, step_s: float = 1.5) -> Motion:
    """Random rotations about random body axes (90..180° each) — covers the sphere for the
    magnetometer; a 2 s hold at start and end."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x70B1E]))
    m = Motion().hold(2.0, "still")
    while m.duration + step_s + 2.0 <= seconds:
        axis = rng.standard_normal(3)
        m.rotate(axis, rng.uniform(90, 180) * rng.choice([-1, 1]), step_s, "tumble")
    return m.hold(max(seconds - m.duration, 2.0), "still")   # total = ``seconds`` exactly


def handheld(seconds: float = 60.0, seed: int = 0, hold_s: float = 3.0,
             turn_s: float = 2.0) -> Motion:
    """[Chow] §4.2's on-site session: still poses ``hold_s`` long with turns of 60-180° about
    random body axes between them (``turn_s`` each), starting level; ``seconds`` in all."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x4A4D]))
    m = Motion().hold(hold_s, "hold")
    while m.duration + turn_s + hold_s <= seconds:
        axis = rng.standard_normal(3)
        m.rotate(axis, rng.uniform(60, 180) * rng.choice([-1, 1]), turn_s, "turn")
        m.hold(hold_s, "hold")
    return m.hold(max(seconds - m.duration, 0.5), "hold")


# a hand's physiological tremor, 5-12 Hz at about 0.5-2 °/s (0.02° × 2π × 8.5 Hz ≈ 1 °/s per
# axis), and its slow sway
HAND_TREMOR = {"tremor_deg": 0.02, "tremor_hz": [5.0, 12.0], "sway_deg": 0.3, "sway_hz": [0.1, 0.5]}
LAPTOP_MGAUSS = 30.0     # RMS per axis of the laptop's field (3 µT, a laptop some 30 cm away)
NEAR_LAPTOP_MGAUSS = 150.0   # ... held right beside it (handheld_laptop)


def handheld_real(seconds: float = 120.0, seed: int = 0, hold_s=(2.0, 10.0),
                  turn_deg=(90.0, 180.0), rate_dps=(30.0, 200.0), shift_m=(0.05, 0.3),
                  laptop_mgauss: float = LAPTOP_MGAUSS) -> Motion:
    """A hand-held session as people record one at a desk: holds of ``hold_s`` [s] (uniform
    in the range), turns of ``turn_deg`` [deg] about random body axes at a mean rate of
    ``rate_dps`` [deg/s] (peak twice that), each moving the board by ``shift_m`` [m] in a
    random direction (put down elsewhere); the hand's tremor (:data:`HAND_TREMOR`) and a
    laptop's slowly changing field (:class:`LaptopField`, RMS ``laptop_mgauss`` per axis; 0:
    none). Starts level; ``seconds`` in all."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x4A4E]))
    m = Motion(tremor=dict(HAND_TREMOR),
               disturbance=LaptopField(laptop_mgauss, seed) if laptop_mgauss > 0 else None)
    m.hold(rng.uniform(*hold_s), "hold")
    while True:
        angle = rng.uniform(*turn_deg)
        turn_s = angle / rng.uniform(*rate_dps)
        hold = rng.uniform(*hold_s)
        if m.duration + turn_s + hold > seconds:
            break
        direction = rng.standard_normal(3)
        shift = direction / np.linalg.norm(direction) * rng.uniform(*shift_m)
        m.rotate(rng.standard_normal(3), angle * rng.choice([-1, 1]), turn_s, "turn",
                 shift=shift)
        m.hold(hold, "hold")
    return m.hold(max(seconds - m.duration, 0.5), "hold")


def motors(seconds: float = 60.0, idle_s: float = 5.0, full_s: float = 5.0) -> Motion:
    """Motors run while the vehicle is held still and level (like ArduPilot's compassmot):
    idle at throttle 0, a linear ramp to full throttle, a hold at full throttle, a ramp back
    down and idle again. The ramps share what ``seconds`` leaves after the three holds."""
    return motors_section(Motion(), seconds, idle_s, full_s)


def motors_section(m: Motion, seconds: float = 60.0, idle_s: float = 5.0,
                   full_s: float = 5.0) -> Motion:
    """Append the :func:`motors` profile to ``m``, holding its current pose (sections idle,
    throttle_up, full_throttle, throttle_down, idle_end; ``seconds`` in all)."""
    ramp = max((seconds - 2 * idle_s - full_s) / 2.0, 1.0)
    return (m.hold(idle_s, "idle")
            .hold(ramp, "throttle_up", throttle=(0.0, 1.0))
            .hold(full_s, "full_throttle", throttle=1.0)
            .hold(ramp, "throttle_down", throttle=(1.0, 0.0))
            .hold(idle_s, "idle_end"))


CORNER_PITCH_DEG = float(np.degrees(np.arcsin(1.0 / np.sqrt(3.0))))   # 35.26°
CORNER_ROLLS_DEG = (45.0, 135.0, -135.0, -45.0)


def corner_poses() -> list[np.ndarray]:
    """R_nb of the eight cube corners: gravity along (±1, ±1, ±1)/√3 in the body frame."""
    return [euler_matrix(roll, pitch, 0.0) for roll in CORNER_ROLLS_DEG
            for pitch in (CORNER_PITCH_DEG, -CORNER_PITCH_DEG)]


def diagnosis(move_s: float = 3.0, motors_s: float = 60.0, corner_s: float = 10.0,
              duration: float | None = None) -> Motion:
    """The diagnosis benchmark session: :func:`ferraris` (six faces, then −360° about x, y, z),
    then the eight cube corners held ``corner_s`` each (label "corner"), then level and still
    the :func:`motors` section (idle 5 s, ramp up, 5 s full throttle, ramp down, idle 5 s;
    ``motors_s`` in all) — every effect, compass interference included, in one session.

    The corners give the accelerometer fourteen still orientations: with the six faces alone,
    offset and scale (six parameters) and the unknown orientations fit the hold means exactly,
    so nothing beyond them (cross-axis coupling, scale nonlinearity) could show in the holds.
    A ``duration`` beyond the session's own (632 s) adds a still, level hold at the end (the
    speed benchmark's ten minutes)."""
    m = ferraris(move_s=move_s)
    for pose in corner_poses():
        m.move_to(pose, move_s)
        m.hold(corner_s, "corner")
    m.move_to(pose_matrix("level"), move_s)
    m = motors_section(m, motors_s)
    if duration is not None and duration > m.duration:
        m.hold(duration - m.duration, "still")
    return m


def operator() -> Motion:
    """Starts level; the ground station moves it (see :meth:`Motion.move_to`)."""
    return Motion().hold(1.0, "level")


def build(name: str, seed: int = 0, duration: float | None = None) -> Motion:
    """The named script (``SCRIPTS``); ``duration`` stretches onepos, warmup, tumble, motors,
    handheld, handheld_real and handheld_laptop (ignored by the fixed sessions ferraris,
    ardupilot6, operator and diagnosis)."""
    if name == "ferraris":
        return ferraris()
    if name == "ardupilot6":
        return ardupilot6()
    if name == "onepos":
        return onepos(duration or 60.0)
    if name == "warmup":
        return warmup(duration or 600.0)
    if name == "tumble":
        return tumble(duration or 90.0, seed)
    if name == "operator":
        return operator()
    if name == "motors":
        return motors(duration or 60.0)
    if name == "handheld":
        return handheld(duration or 60.0, seed)
    if name == "handheld_real":
        return handheld_real(duration or 120.0, seed)
    if name == "handheld_laptop":
        return handheld_real(duration or 120.0, seed, laptop_mgauss=NEAR_LAPTOP_MGAUSS)
    if name == "diagnosis":              # its own length, or longer with a final still hold
        return diagnosis(duration=duration)
    raise ValueError(f"unknown script {name!r}; known: {', '.join(SCRIPTS)}")
