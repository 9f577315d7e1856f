"""Guided recording of ArduPilot's six accelerometer-calibration poses, checked pose by pose.

It runs the way ArduPilot's own accel cal (and Mission Planner with it) does: each pose is
prompted in the firmware's order (ardupilot-facts.md "ArduPilot's own calibrators": level,
LEFT, RIGHT, nose DOWN, nose UP, BACK); the operator places the vehicle and presses Enter (or,
with ``auto``, apmcal waits for the vehicle to be still in the pose); the pose is read from
gravity and a wrong or repeated one is rejected and asked for again. Every wait has a timeout;
an abort or a timeout stops the session with the reason, so no face is ever silently missing.

The pose comes from the mean specific force of a still second (ardupilot-facts.md "Frames and
signs": level reads (0, 0, −g), nose down acc_x ≈ −g, left side down acc_y ≈ +g, upside down
acc_z ≈ +g) with the tolerance the calibration's own hold labelling uses
(:data:`apmcal.preprocessing.static.MAX_TILT_DEG`), so an accepted hold is one the calibration
recognises. The faces are axis-aligned, 90° apart: a pose within 25° of one face is more than
45° from every other, ArduPilot's rule for rejecting a face too close to an earlier one.

No MAV_CMD_ACCELCAL_VEHICLE_POS is sent. That command confirms a pose to the firmware's own
calibration, and ArduPilot (AP_AccelCal::gcs_vehicle_position) accepts it only while that
calibration waits for exactly that pose, answering MAV_RESULT_FAILED otherwise. apmcal runs no
onboard calibration: it records the telemetry and checks the pose itself.

Vehicle time (the IMU messages' time_usec) measures the holds, so how fast this machine or the
link is does not change what is accepted; wall-clock time only bounds the waits.
"""
from __future__ import annotations

import queue
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Protocol, TextIO

import numpy as np

from apmcal.core.constants import MG_TO_MS2, MRAD_TO_RAD
from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.static import ARDUPILOT_FACE, MAX_TILT_DEG, pose_of

STILL_WINDOW_S = 1.0        # vehicle seconds of stillness before a pose is judged
STILL_MIN_SAMPLES = 3       # ... and at least this many samples in them
# a hand-held vehicle trembles (a few °/s at 4-9 Hz) but does not turn: the window's mean rate
# is small, and no sample is fast
STILL_ACC_STD = 0.3         # m/s², per axis, over the window: no rocking, no knocks
STILL_MEAN_RATE = 0.05      # rad/s (≈ 3°/s), norm of the window's mean rate: not turning
STILL_PEAK_RATE = 0.35      # rad/s (≈ 20°/s), every sample of the window: no jerk
WRONG_POSE_GRACE_S = 3.0    # --auto: vehicle seconds still in a wrong pose before it is rejected
NO_DATA_TIMEOUT_S = 10.0    # wall seconds without an IMU message: the stream stopped
ABORT_WORDS = {"q", "quit", "abort", "stop"}


@dataclass(frozen=True)
class Face:
    """One of ArduPilot's six accelerometer-calibration poses (see :data:`FACES`)."""
    name: str        # ArduPilot's name of the pose
    words: str       # as the prompt says it ("place the vehicle ...")
    label: str       # the calibration's pose label (apmcal.preprocessing.static)


# ardupilot-facts.md "ArduPilot's own calibrators": the firmware's order
FACES = tuple(Face(name, words, label) for name, words, label in (
    ("level", "level", "z_a"), ("left", "on its LEFT side", "y_p"),
    ("right", "on its RIGHT side", "y_a"), ("nosedown", "nose DOWN", "x_a"),
    ("noseup", "nose UP", "x_p"), ("back", "on its BACK", "z_p")))
FACE_BY_LABEL = {f.label: f for f in FACES}
assert all(ARDUPILOT_FACE[f.label] == f.name for f in FACES)


@dataclass(frozen=True)
class FaceRequest:
    """One prompt: pose ``index`` of 6, ``face``, the ``attempt``-th time it is asked for."""
    index: int
    face: Face
    attempt: int
    text: str


class Operator(Protocol):
    """The person at the vehicle: sees the prompts, presses the keys (injectable for tests)."""

    def ask(self, request: FaceRequest) -> None:
        """Show the prompt for a pose (and forget keys typed before it)."""

    def tell(self, text: str) -> None:
        """Show one line: a rejection, an accepted pose."""

    def progress(self, text: str) -> None:
        """Show how far the current hold is."""

    def answer(self, timeout_s: float) -> str | None:
        """A line typed (without its newline), None when none came within ``timeout_s``;
        raises EOFError when the input is closed."""


@dataclass(frozen=True)
class GuideOptions:
    """How the guided session runs.

    Attributes
    ----------
    hold_s : float
        Vehicle seconds [s] held still in each pose.
    auto : bool
        Wait for the pose instead of a key press.
    face_timeout_s : float
        Wall seconds [s] per prompt (key press, stillness, hold).
    """
    hold_s: float = 10.0             # vehicle seconds held still in each pose
    auto: bool = False               # wait for the pose instead of a key press
    face_timeout_s: float = 120.0    # wall seconds per prompt (key press, stillness, hold)


@dataclass
class Hold:
    """An accepted pose: first and last sample time [s, vehicle clock] and the mean [m/s²]."""
    face: Face
    start: float
    end: float
    acc_mean: np.ndarray

    @property
    def seconds(self) -> float:
        """How long the pose was held [s, vehicle clock]."""
        return self.end - self.start


@dataclass
class GuideResult:
    """What a completed session recorded.

    Attributes
    ----------
    holds : dict of str to Hold
        Face name → accepted hold, all six.
    n_imu : int
        IMU messages received.
    """
    holds: dict[str, Hold] = field(default_factory=dict)     # face name -> accepted hold
    n_imu: int = 0                                           # IMU messages received


class GuideAborted(ApmcalError):
    """The session stopped before the six poses were in: the reason, and what was recorded."""


@dataclass
class ImuSample:
    """One IMU sample of the stream: vehicle time [s], acc (3,) [m/s², body frame],
    gyr (3,) [rad/s]."""
    t: float            # vehicle time [s]
    acc: np.ndarray     # m/s², body frame
    gyr: np.ndarray     # rad/s


def imu_sample(msg) -> ImuSample | None:
    """The body-frame sample of a RAW_IMU (mG, mrad/s; ardupilot-facts.md "What the telemetry
    really carries") or HIGHRES_IMU (SI) message, else None.

    Parameters
    ----------
    msg : pymavlink message
        Any received message.

    Returns
    -------
    ImuSample or None
        Time [s], acc (3,) [m/s²], gyr (3,) [rad/s].
    """
    kind = msg.get_type()
    acc = np.array([msg.xacc, msg.yacc, msg.zacc], float)
    gyr = np.array([msg.xgyro, msg.ygyro, msg.zgyro], float)
    if kind == "RAW_IMU":
        return ImuSample(msg.time_usec * 1e-6, acc * MG_TO_MS2, gyr * MRAD_TO_RAD)
    if kind == "HIGHRES_IMU":
        return ImuSample(msg.time_usec * 1e-6, acc, gyr)
    return None


class ImuFeed:
    """Receives (and so records) everything from the link; hands on the autopilot's IMU
    samples and counts the IMU messages."""

    IMU_TYPES = {"RAW_IMU", "SCALED_IMU2", "HIGHRES_IMU"}
    SAMPLE_TYPES = {"RAW_IMU", "HIGHRES_IMU"}

    def __init__(self, link):
        self.link = link
        self.n_imu = 0
        self.last_sample_wall = time.monotonic()

    def receive(self, duration_s: float) -> list[ImuSample]:
        """Everything that arrives within ``duration_s`` (wall); the IMU samples of it.

        Parameters
        ----------
        duration_s : float
            Wall-clock time to listen [s].

        Returns
        -------
        list of ImuSample
            The autopilot's RAW_IMU/HIGHRES_IMU samples, in arrival order.
        """
        samples = []
        deadline = time.monotonic() + duration_s
        while (left := deadline - time.monotonic()) > 0:
            msg = self.link.recv(None, left)
            if msg is None:
                break
            if msg.get_type() in self.IMU_TYPES:
                self.n_imu += 1
            if (msg.get_type() in self.SAMPLE_TYPES
                    and msg.get_srcSystem() == self.link.target_system):
                samples.append(imu_sample(msg))
        if samples:
            self.last_sample_wall = time.monotonic()
        return samples

    def silent_for(self) -> float:
        """Wall seconds [s] since the last batch with an IMU sample (or since the feed began)."""
        return time.monotonic() - self.last_sample_wall


class StillWindow:
    """The samples of the last :data:`STILL_WINDOW_S` of vehicle time."""

    def __init__(self):
        self.samples: deque[ImuSample] = deque()

    def add(self, s: ImuSample) -> None:
        """Append a sample and drop those older than the window (all of them when the clock went back)."""
        if self.samples and s.t < self.samples[-1].t:     # clock went back: a reboot
            self.samples.clear()
        self.samples.append(s)
        while self.samples[-1].t - self.samples[0].t > STILL_WINDOW_S:
            self.samples.popleft()

    def full(self) -> bool:
        """True when the window spans (nearly) :data:`STILL_WINDOW_S` with enough samples."""
        return (len(self.samples) >= STILL_MIN_SAMPLES
                and self.samples[-1].t - self.samples[0].t >= 0.9 * STILL_WINDOW_S)

    def still(self) -> bool:
        """True when the window is full and the vehicle still in it: acc std per axis
        below :data:`STILL_ACC_STD` [m/s²], |mean rate| below :data:`STILL_MEAN_RATE` and every
        sample's |rate| below :data:`STILL_PEAK_RATE` [rad/s]."""
        if not self.full():
            return False
        acc = np.array([s.acc for s in self.samples])
        gyr = np.array([s.gyr for s in self.samples])
        return bool(acc.std(axis=0).max() < STILL_ACC_STD
                    and np.linalg.norm(gyr.mean(axis=0)) < STILL_MEAN_RATE
                    and np.linalg.norm(gyr, axis=1).max() < STILL_PEAK_RATE)

    def mean_acc(self) -> np.ndarray:
        """Mean specific force of the window [m/s²], shape (3,)."""
        return np.mean([s.acc for s in self.samples], axis=0)


def detect_face(acc_mean: np.ndarray) -> tuple[Face | None, float, Face]:
    """(face within the tolerance or None, tilt [deg] from the nearest face, nearest face).

    Parameters
    ----------
    acc_mean : numpy.ndarray, shape (3,)
        Mean specific force of a still window [m/s², body frame].

    Returns
    -------
    face : Face or None
        The face within :data:`MAX_TILT_DEG` of ``acc_mean``, or None.
    tilt : float
        Angle [deg] from the nearest face.
    nearest : Face
    """
    label, tilt = pose_of(acc_mean, max_tilt_deg=90.0)
    nearest = FACE_BY_LABEL[label]
    return (nearest if tilt <= MAX_TILT_DEG else None), tilt, nearest


def rejection(wanted: Face, seen: Face | None, tilt: float, nearest: Face,
              done: dict[str, Hold]) -> str:
    """Why the pose is not taken, and what to do, in one line."""
    order = [f.name for f in FACES]
    if seen is None:
        return (f"rejected: the vehicle is in none of the six poses ({tilt:.0f}° from "
                f"{nearest.words}, more than {MAX_TILT_DEG:g}°): place it {wanted.words}")
    if seen.name in done:
        return (f"rejected: the vehicle is {seen.words}, pose {order.index(seen.name) + 1} "
                f"of 6, already recorded (a repeated pose): place it {wanted.words}")
    return (f"rejected: the vehicle is {seen.words}, not {wanted.words}: ArduPilot's order is "
            f"level, LEFT, RIGHT, nose DOWN, nose UP, BACK; place it {wanted.words}")


def prompt_text(index: int, face: Face, options: GuideOptions) -> str:
    """The prompt for pose ``index`` (1..6): where to place the vehicle, how to confirm."""
    how = ("and keep it still: recording starts by itself" if options.auto
           else "keep it still, then press Enter (q and Enter to stop)")
    return (f"pose {index} of 6: place the vehicle {face.words}, {how} "
            f"({options.hold_s:g} s hold)")


class FaceSession:
    """Asking for one pose until it is held: the prompt, the wait and the checks."""

    def __init__(self, feed: ImuFeed, operator: Operator, options: GuideOptions, index: int,
                 face: Face, done: dict[str, Hold]):
        self.feed, self.operator, self.options = feed, operator, options
        self.index, self.face, self.done = index, face, done
        self.attempt = 0
        self.deadline = 0.0

    def run(self) -> Hold:
        """Prompt until the pose is held; the accepted hold (GuideAborted stops it)."""
        while True:
            self.ask()
            if not self.options.auto:
                self.wait_for_enter()
            hold = self.hold()
            if hold is not None:
                return hold

    def ask(self) -> None:
        """Show the prompt (again) and restart the wait's timeout."""
        self.attempt += 1
        self.deadline = time.monotonic() + self.options.face_timeout_s
        self.operator.ask(FaceRequest(self.index, self.face, self.attempt,
                                      prompt_text(self.index, self.face, self.options)))

    def where(self) -> str:
        """The pose in words for messages, e.g. "pose 2 of 6 (on its LEFT side)"."""
        return f"pose {self.index} of 6 ({self.face.words})"

    def check_keys(self) -> str | None:
        """A line typed since the last look; raises GuideAborted on q, or on closed input
        unless --auto (which needs no keyboard: a script, ``</dev/null``)."""
        try:
            line = self.operator.answer(0.0)
        except EOFError:
            if self.options.auto:
                return None
            raise self.stopped("keyboard input closed") from None
        if line is not None and line.strip().lower() in ABORT_WORDS:
            raise self.stopped("stopped by the operator")
        return line

    def stopped(self, why: str) -> GuideAborted:
        """The GuideAborted for ``why``, naming the pose and the poses recorded."""
        done = ", ".join(self.done) or "none"
        return GuideAborted(f"guided calibration stopped at {self.where()}: {why}; poses "
                            f"recorded: {done}; nothing calibrated (all six are needed)")

    def check_time(self, waiting_for: str) -> None:
        """Raise GuideAborted when the prompt's wait timed out or the IMU stream
        has been silent for :data:`NO_DATA_TIMEOUT_S`."""
        if time.monotonic() > self.deadline:
            raise self.stopped(f"no {waiting_for} within {self.options.face_timeout_s:g} s "
                               f"(--face-timeout)")
        if self.feed.silent_for() > NO_DATA_TIMEOUT_S:
            raise self.stopped(f"no RAW_IMU/HIGHRES_IMU message for {NO_DATA_TIMEOUT_S:g} s "
                               f"(link lost, or the stream stopped: check SRn_RAW_SENS)")

    def wait_for_enter(self) -> None:
        """Keep recording until the operator presses Enter."""
        while self.check_keys() is None:
            self.check_time("key press")
            self.feed.receive(0.05)

    def hold(self) -> Hold | None:
        """The accepted hold, or None after telling why the pose was rejected (the caller asks
        again). With --auto a rejection is told once per still spell and the prompt repeated,
        and the wait goes on."""
        window, held = StillWindow(), []
        wrong_since, rejected_spell, shown = None, False, -1
        # the pose just recorded, while the vehicle has not moved since: not a wrong pose, the
        # operator has not turned it yet (with --auto nobody says when they start)
        resting_in = next(reversed(self.done), None) if self.options.auto else None
        while True:
            self.check_keys()
            self.check_time("still hold in the pose" if held else
                            "still vehicle in the pose")
            for s in self.feed.receive(0.05):
                window.add(s)
                if not window.still():
                    if window.full():      # moving (a window still filling says nothing)
                        resting_in = None
                    if held and held[-1].t - held[0].t >= 1.0:
                        self.operator.tell(f"{self.where()}: the vehicle moved after "
                                           f"{held[-1].t - held[0].t:.1f} s: hold it still")
                    held, wrong_since, rejected_spell = [], None, False
                    continue
                seen, tilt, nearest = detect_face(window.mean_acc())
                if seen == self.face:
                    held = held or list(window.samples)[:-1]
                    held.append(s)
                    seconds = held[-1].t - held[0].t
                    if int(seconds) != shown:     # whole seconds, each shown once
                        shown = int(seconds)
                        self.operator.progress(f"{self.where()}: {shown} of "
                                               f"{self.options.hold_s:g} s held")
                    if seconds >= self.options.hold_s:
                        return Hold(self.face, held[0].t, held[-1].t,
                                    np.mean([h.acc for h in held], axis=0))
                    continue
                held = []
                if seen is not None and seen.name == resting_in:
                    continue
                wrong_since = s.t if wrong_since is None else wrong_since
                grace = WRONG_POSE_GRACE_S if self.options.auto else 0.0
                if rejected_spell or s.t - wrong_since < grace:
                    continue
                self.operator.tell(rejection(self.face, seen, tilt, nearest, self.done))
                if not self.options.auto:
                    return None
                rejected_spell = True
                self.ask()


def record_six_faces(link, options: GuideOptions, operator: Operator) -> GuideResult:
    """Ask for ArduPilot's six poses in its order; every one held ``options.hold_s`` still.

    Raises :class:`GuideAborted` (an ApmcalError: one line, exit status 2) when the operator
    stops, the input closes, a wait times out or the IMU stream stops.
    """
    feed = ImuFeed(link)
    result = GuideResult()
    for index, face in enumerate(FACES, 1):
        hold = FaceSession(feed, operator, options, index, face, result.holds).run()
        result.holds[face.name] = hold
        operator.tell(f"pose {index} of 6 ({face.words}) recorded: {hold.seconds:.1f} s "
                      f"still, vehicle clock {hold.start:.1f}-{hold.end:.1f} s")
    result.n_imu = feed.n_imu
    operator.tell("all six poses recorded")
    return result


class TerminalOperator:
    """Prompts on ``out``; key presses are lines read from ``keys`` (the terminal's stdin) on a
    background thread, so the link keeps being read (and recorded) while nobody types."""

    _EOF = object()

    def __init__(self, keys: TextIO = sys.stdin, out: TextIO = sys.stdout):
        self.out = out
        self.lines: queue.Queue = queue.Queue()
        self._progress_shown = False
        threading.Thread(target=self._read, args=(keys,), daemon=True).start()

    def _read(self, keys: TextIO) -> None:
        try:
            for line in keys:
                self.lines.put(line.rstrip("\r\n"))
        except (OSError, ValueError):     # stdin closed under us
            pass
        self.lines.put(self._EOF)

    def ask(self, request: FaceRequest) -> None:
        """See :meth:`Operator.ask`."""
        self._drop_typed_ahead()
        self.tell(request.text)

    def tell(self, text: str) -> None:
        """See :meth:`Operator.tell`."""
        if self._progress_shown:
            self.out.write("\n")
            self._progress_shown = False
        print(text, file=self.out, flush=True)

    def progress(self, text: str) -> None:
        """See :meth:`Operator.progress` (updated in place on a terminal)."""
        if self.out.isatty():      # one line, updated in place
            self.out.write("\r" + text)
            self.out.flush()
            self._progress_shown = True
        else:
            print(text, file=self.out, flush=True)

    def answer(self, timeout_s: float) -> str | None:
        """See :meth:`Operator.answer`."""
        try:
            line = self.lines.get(timeout=timeout_s) if timeout_s > 0 else self.lines.get_nowait()
        except queue.Empty:
            return None
        if line is self._EOF:
            self.lines.put(self._EOF)        # closed stays closed
            raise EOFError
        return line

    def _drop_typed_ahead(self) -> None:
        """Enter pressed before the prompt was shown must not confirm the new pose."""
        kept_eof = False
        while True:
            try:
                line = self.lines.get_nowait()
            except queue.Empty:
                break
            kept_eof = kept_eof or line is self._EOF
        if kept_eof:
            self.lines.put(self._EOF)
