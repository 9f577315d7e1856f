"""A simulated vehicle served from a thread of the test process, and a simulated operator who
turns it when apmcal prompts (not a test module).

Nothing here waits on a wall-clock schedule: the operator acts on each prompt, and presses
Enter once the vehicle has come to rest in simulated time, so what apmcal sees does not depend
on how fast the machine runs.
"""
from __future__ import annotations

import socket
import threading
import time

import numpy as np

from apmcal.sensor_model.truth import Truth
from apmcal_sim.firmware import euler_matrix
from apmcal_sim.mavlink_vehicle import MavlinkVehicle
from apmcal_sim.vehicle import SimVehicle

# the truth's effects no six-face method models, off so that the accelerometer result can be
# compared with the injected values
UNMODELLED = ["motion_contamination", "temperature_drift", "scale_nonlinearity"]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ThreadedSim:
    """An operator-mode SimVehicle on udpout:127.0.0.1:<free port>, served until ``close``."""

    def __init__(self, tmp_path, seed: int = 22, speedup: float = 10.0, generation="3.3",
                 site: dict | None = None, effects_off=()):
        self.port = free_udp_port()
        self.truth = Truth.random(seed, site).with_effects(disable=[*UNMODELLED, *effects_off])
        self.vehicle = SimVehicle(self.truth, "operator", generation,
                                  param_file=tmp_path / "sitl-params.json", seed=seed)
        # 0.1 s steps: a step's cost is mostly per call, and this keeps up with 10x real time
        self.endpoint = MavlinkVehicle(self.vehicle, f"udpout:127.0.0.1:{self.port}", speedup,
                                       step_s=0.1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    @property
    def connection(self) -> str:
        return f"udp:127.0.0.1:{self.port}"

    def _serve(self) -> None:
        while not self._stop.is_set():
            self.endpoint.poll()
            time.sleep(0.002)

    def act(self, fn) -> None:
        """``fn(vehicle)`` in the serving thread."""
        self.endpoint.call_soon(fn)

    def wait(self, condition, what: str, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition(self.vehicle):
            if time.monotonic() > deadline:
                raise TimeoutError(f"simulated vehicle: {what} not within {timeout_s:g} s")
            time.sleep(0.01)

    def turn_and_wait(self, pose: str) -> None:
        """Turn the vehicle to ``pose`` and wait until it rests there."""
        turned = threading.Event()
        self.act(lambda v: (v.goto_pose(pose), turned.set()))
        self.wait(lambda v: turned.is_set() and v.motion_done(), f"turn to {pose}")

    def wait_for_boot(self) -> None:
        """Until the boot gyro calibration has stored INS_GYROFFS (a recording across it is
        refused, rightly)."""
        self.wait(lambda v: v._boot_gyro is None, "boot gyro calibration")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)
        self.endpoint.close()


TILTED_45 = euler_matrix(45.0, 0.0, 0.0)       # halfway between level and the right side


class SimOperator:
    """apmcal's Operator, played against a ThreadedSim.

    On each prompt it turns the vehicle to the pose asked for, except where ``first`` says
    otherwise: ``first[face]`` is a list of what to do on the first prompts for that face, each
    a pose name (turn there and rest), or ("via", R, seconds) (turn to attitude R, rest there
    ``seconds`` of simulated time, then turn to the face asked for), or ("wobble", seconds)
    (rest ``seconds`` in the face, then rock 20° and back, then rest). Enter is pressed once the
    vehicle rests after the turns (unless ``press_enter`` is False: ``--auto``).
    """

    def __init__(self, sim: ThreadedSim, first: dict | None = None, press_enter: bool = True,
                 move_s: float = 3.0):
        self.sim, self.first = sim, {k: list(v) for k, v in (first or {}).items()}
        self.move_s = move_s        # how long a turn to a pose takes [s simulated]
        self.press_enter = press_enter
        self.lines: list[str] = []
        self.requests: list = []
        self._enter_due = False
        self._ready = threading.Event()

    # -- apmcal's Operator protocol ---------------------------------------------------------
    def ask(self, request) -> None:
        self.requests.append(request)
        self.lines.append(request.text)
        plan = self.first.get(request.face.name)
        action = plan.pop(0) if plan else request.face.name
        self._ready.clear()
        self.sim.act(lambda v: self._do(v, action, request.face.name))
        self._enter_due = self.press_enter

    def tell(self, text: str) -> None:
        self.lines.append(text)

    def progress(self, text: str) -> None:
        self.lines.append(text)

    def answer(self, timeout_s: float) -> str | None:
        if (self._enter_due and self._ready.is_set()
                and self.sim.vehicle.motion_done()):
            self._enter_due = False
            return ""
        if timeout_s > 0:
            time.sleep(min(timeout_s, 0.01))
        return None

    # -- what the operator does with the vehicle (in the serving thread) --------------------
    def _do(self, v: SimVehicle, action, face: str) -> None:
        if isinstance(action, str):
            v.goto_pose(action, self.move_s)
        elif action[0] == "via":
            v.goto_pose(action[1], label="via")
            v.stay(action[2])
            v.goto_pose(face)
        elif action[0] == "wobble":
            v.goto_pose(face)
            v.stay(action[1])
            rocked = v.motion.end_pose() @ euler_matrix(20.0, 0.0, 0.0)
            v.goto_pose(rocked, move_s=0.5, label="wobble")
            v.goto_pose(face, move_s=0.5)
        self._ready.set()

    # -- for the checks ---------------------------------------------------------------------
    def said(self, words: str) -> list[str]:
        return [line for line in self.lines if words in line]

    def asked(self) -> list[tuple[int, str]]:
        return [(r.index, r.face.name) for r in self.requests]


def arrival_times(v: SimVehicle, label: str) -> list[float]:
    """Simulated times at which the vehicle came to rest in a pose labelled ``label``."""
    return [t0 for name, t0, _ in v.motion.sections() if name == label]


def pose_error_deg(v: SimVehicle, acc_mean, face: str) -> float:
    """Angle between a measured mean specific force and the face's true one."""
    from apmcal_sim.motion import pose_matrix

    f = -pose_matrix(face).T @ np.array([0.0, 0.0, 1.0])
    a = np.asarray(acc_mean) / np.linalg.norm(acc_mean)
    return float(np.degrees(np.arccos(np.clip(f @ a, -1, 1))))
