"""Drive ArduPilot's own firmware, built as SITL, for apmcal's tests and benchmarks.

Not part of the installed apmcal (it sits beside the simulator in ``sitl/`` and is not
packaged): the tests and benchmarks import it from there. It speaks to the firmware with
pymavlink alone, never with apmcal's link code, so that what it sets up is a truth independent of
the code under test.

One :class:`ArduPilotSitl` is one firmware process:

- started in a scratch folder of its own (a fresh parameter store, ``eeprom.bin``, and a fresh
  ``logs/`` for the dataflash logs), on an instance number (``-I``, ports 5760 + 10 I ...) that
  no other instance on the machine holds (a lock file per instance);
- its parameters set by name, each write confirmed by the firmware's PARAM_VALUE echo
  (:meth:`set_params`), or given at boot as an extra defaults file (``boot_params``);
- posed and spun (the ``calibration`` model: :meth:`pose`, :meth:`spin`), flown (copter:
  :meth:`takeoff`, :meth:`fly_to`, :meth:`land`) or driven (rover: :meth:`drive`);
- timed in simulated seconds (:meth:`run_for`), whatever ``--speedup`` makes of them;
- every message it sends on SERIAL0 recorded in a .tlog (:attr:`tlog`), its dataflash logs
  collected (:meth:`dataflash_logs`);
- stopped by its PID (SIGTERM, then SIGKILL), by :meth:`stop`, by leaving the ``with`` block
  (an exception and Ctrl-C included), at interpreter exit, and by the kernel when the process
  that started it dies in any other way (``PR_SET_PDEATHSIG``): no firmware process is ever left
  behind.

The firmware's own README (``../shared/ardupilot-sitl/README.md``) says how the models are posed
and which SIM_* parameter injects which error; :data:`EXACT_CALIBRATION` carries its table.
"""
from __future__ import annotations

import atexit
import ctypes
import fcntl
import math
import os
import signal
import socket
import subprocess
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SITL_DIR = Path(os.environ.get("APMCAL_ARDUPILOT_SITL", ROOT.parent / "shared" / "ardupilot-sitl"))

BINARIES = {"copter": "arducopter", "rover": "ardurover", "plane": "arduplane"}
DEFAULTS = {"copter": ["copter.parm"], "rover": ["rover.parm"], "plane": ["plane.parm"],
            "motorboat": ["rover.parm", "motorboat.parm"]}

BASE_TCP_PORT = 5760        # SERIAL0; SERIAL1 = +2, SERIAL2 = +3; every port + 10 × instance
RC_IN_UDP_PORT = 5501
MAX_INSTANCES = 60

GCS_SYSTEM_ID = 255         # the id the firmware takes RC overrides from (MAV_GCS_SYSID)
GCS_COMPONENT_ID = 191      # apmcal's own link uses 190

# MAVLink numbers used here (common.xml)
MAV_CMD_DO_SET_SERVO = 183
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_RESULT_ACCEPTED = 0
FORCE_ARM_MAGIC = 21196
MAV_FRAME_LOCAL_NED = 1
MAV_CMD_PREFLIGHT_CALIBRATION = 241
MAV_CMD_ACCELCAL_VEHICLE_POS = 42429
MAV_CMD_DO_START_MAG_CAL = 42424
ACCELCAL_SUCCESS = 16777215     # ACCELCAL_VEHICLE_POS_SUCCESS
MAG_CAL_SUCCESS = 4
# the poses ArduPilot's accelerometer calibration asks for (ACCELCAL_VEHICLE_POS 1-6) as the
# calibration model's attitude [deg]: level, left side down, right side down, nose down, nose
# up, on its back
ACCELCAL_ATTITUDES = {1: (0, 0, 0), 2: (-90, 0, 0), 3: (90, 0, 0), 4: (0, -90, 0),
                      5: (0, 90, 0), 6: (180, 0, 0)}
# SET_POSITION_TARGET_LOCAL_NED type_mask bits (POSITION_TARGET_TYPEMASK)
IGNORE_VELOCITY = 8 | 16 | 32
IGNORE_ACCELERATION = 64 | 128 | 256
IGNORE_YAW = 1024
IGNORE_YAW_RATE = 2048

# the calibration model's servo 5 (libraries/SITL/SIM_Calibration.cpp, SITL::Calibration::update)
SERVO_MODE = 5
MODE_STOP_PWM = 1050            # < 1100: damp every rotation
MODE_ATTITUDE_PWM = 1150        # 1100-1200: hold the attitude of servos 6, 7, 8
MODE_RATE_BASE_PWM = 1300       # >= 1300: turn at 2π (PWM - 1300) / 700 rad/s about servos 6-8
MAX_SPIN_RATE = 2 * math.pi     # rad/s at PWM 2000


def unavailable_reason() -> str | None:
    """Why ArduPilot's SITL cannot run here (one line), or None when it can."""
    if not SITL_DIR.is_dir():
        return f"ArduPilot SITL binaries absent ({SITL_DIR}): real-firmware checks skipped"
    missing = [b for b in BINARIES.values() if not os.access(SITL_DIR / b, os.X_OK)]
    if missing:
        return f"ArduPilot SITL binaries {missing} not executable in {SITL_DIR}"
    return None


class SitlError(RuntimeError):
    """The firmware did not do what it was asked (no echo, no acknowledgement, it exited)."""


@dataclass(frozen=True)
class Attitude:
    """An attitude as Euler angles [deg] (ArduPilot's 321 order: yaw, then pitch, then roll)."""

    roll: float
    pitch: float
    yaw: float


def pwm_of_angle(degrees: float) -> int:
    """The calibration model's servo PWM for an angle [deg], taken into [-180, 180)
    (1000 ↔ -180°, 1500 ↔ 0°)."""
    if not math.isfinite(degrees):
        raise ValueError(f"angle {degrees} deg")
    wrapped = (degrees + 180.0) % 360.0 - 180.0
    return int(round(1500 + wrapped * 500.0 / 180.0))


def pwm_of_rate(rate_rad_s: float) -> int:
    """The calibration model's servo 5 PWM for a turn at ``rate_rad_s`` (0 < rate ≤ 2π)."""
    if not 0.0 < rate_rad_s <= MAX_SPIN_RATE:
        raise ValueError(f"turn rate {rate_rad_s} rad/s outside (0, 2π]")
    return int(round(MODE_RATE_BASE_PWM + rate_rad_s / (2 * math.pi) * 700.0))


# -- processes that must not outlive us ---------------------------------------------------------
_RUNNING: set["ArduPilotSitl"] = set()


def _stop_all_at_exit() -> None:
    for sitl in list(_RUNNING):
        sitl.stop()


atexit.register(_stop_all_at_exit)


def _die_with(parent_pid: int):
    """A preexec function: the child gets SIGKILL when the thread that started it ends (Linux
    PR_SET_PDEATHSIG), so a test process killed outright leaves no firmware running."""
    def preexec():
        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
        except OSError:
            pass                     # not glibc: atexit and the with-block still stop it
        if os.getppid() != parent_pid:      # the parent died before prctl took effect
            os._exit(1)
    return preexec


def _port_free(port: int, kind=socket.SOCK_STREAM) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def _claim_instance(first: int = 1):
    """An instance number whose ports are free, and the lock file that holds it for us."""
    for instance in range(first, MAX_INSTANCES):
        lock = open(Path(tempfile.gettempdir()) / f"apmcal-ardupilot-sitl-{instance}.lock", "w")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        tcp = [BASE_TCP_PORT + 10 * instance + k for k in (0, 2, 3)]
        if all(_port_free(p) for p in tcp) and _port_free(RC_IN_UDP_PORT + 10 * instance,
                                                           socket.SOCK_DGRAM):
            return instance, lock
        lock.close()
    raise SitlError("no free SITL instance (ports 5760 + 10 I taken for every I)")


class ArduPilotSitl:
    """One ArduPilot SITL firmware process and this driver's MAVLink link to it (SERIAL0).

    Parameters
    ----------
    workdir : path
        Scratch folder (created; must not hold an ``eeprom.bin`` unless ``keep_eeprom``): the
        firmware's parameter store, dataflash ``logs/``, its console output and the .tlog.
    vehicle : str
        "copter", "rover", "plane" or "motorboat" (the binary and its default parameter files).
    model : str
        The physics model (``--model``): "calibration", "quad", "rover", "motorboat", "plane".
    speedup : float
        Simulated seconds per wall-clock second (``--speedup``); timestamps stay simulated.
    boot_params : dict, optional
        Parameters loaded as defaults at boot (a defaults file written into ``workdir``):
        for values that must hold from the first sample (SIM_DRIFT_SPEED, LOG_DISARMED).
    home : (lat, lon, alt_m, yaw_deg), optional
    sysid : int, optional
        MAV_SYSID (``--sysid``).
    start_time : float, optional
        The simulated clock's Unix time at boot (``--start-time``): the dates in the logs.
    serial1 : str, optional
        SERIAL1's device (e.g. "udpclient:127.0.0.1:14550"); by default tcp port 5762 + 10 I,
        where a ground station (apmcal live) connects as ``tcp:127.0.0.1:PORT``.
    keep_eeprom : bool
        Boot on the parameter store already in ``workdir`` (a vehicle between flights).
    """

    def __init__(self, workdir, vehicle: str = "copter", model: str = "calibration",
                 speedup: float = 20.0, boot_params: dict | None = None, home=None,
                 sysid: int | None = None, start_time: float | None = None,
                 serial1: str | None = None, keep_eeprom: bool = False):
        reason = unavailable_reason()
        if reason:
            raise SitlError(reason)
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        if (self.workdir / "eeprom.bin").exists() and not keep_eeprom:
            raise SitlError(f"{self.workdir} already holds a parameter store (eeprom.bin): "
                            "use a fresh folder, or keep_eeprom=True")
        self.vehicle = vehicle
        self.model = model
        self.speedup = speedup
        self.boot_params = dict(boot_params or {})
        self.home = home
        self.sysid = sysid
        self.start_time = start_time
        self._serial1 = serial1
        self.process: subprocess.Popen | None = None
        self.master = None
        self.instance: int | None = None
        self._lock = None
        self.tlog = self.workdir / "sitl.tlog"
        self.time_boot_s = 0.0          # the firmware's clock, from its timestamped messages
        self._last_simstate = None

    # -- start and stop -----------------------------------------------------------------------
    @property
    def binary(self) -> Path:
        """The firmware binary this instance runs."""
        return SITL_DIR / BINARIES["rover" if self.vehicle == "motorboat" else self.vehicle]

    @property
    def port(self) -> int:
        """SERIAL0's tcp port (this driver's link)."""
        return BASE_TCP_PORT + 10 * self.instance

    @property
    def gcs_port(self) -> int:
        """SERIAL1's tcp port: the one a ground station under test connects to."""
        return BASE_TCP_PORT + 2 + 10 * self.instance

    @property
    def gcs_connection(self) -> str:
        """SERIAL1 as a pymavlink connection string (``tcp:127.0.0.1:PORT``)."""
        return f"tcp:127.0.0.1:{self.gcs_port}"

    def command_line(self) -> list[str]:
        """The firmware's command line (after an instance is claimed)."""
        defaults = [str(SITL_DIR / f) for f in DEFAULTS[self.vehicle]]
        if self.boot_params:
            boot = self.workdir / "boot.parm"
            boot.write_text("".join(f"{k} {v!r}\n" for k, v in self.boot_params.items()))
            defaults.append(str(boot))
        cmd = [str(self.binary), "--model", self.model, "--speedup", f"{self.speedup:g}",
               "--defaults", ",".join(defaults), "-I", str(self.instance), "--serial0", "tcp:0"]
        if self._serial1:
            cmd += ["--serial1", self._serial1]
        if self.home is not None:
            cmd += ["--home", ",".join(f"{v:.8g}" for v in self.home)]
        if self.sysid is not None:
            cmd += ["--sysid", str(int(self.sysid))]
        if self.start_time is not None:
            cmd += ["--start-time", str(int(self.start_time))]
        return cmd

    def start(self, timeout_s: float = 60.0) -> "ArduPilotSitl":
        """Start the firmware, connect, wait for its heartbeat and readable parameters."""
        from pymavlink import mavutil

        self.instance, self._lock = _claim_instance()
        console = open(self.workdir / "sitl-console.txt", "ab")
        self.process = subprocess.Popen(self.command_line(), cwd=self.workdir, stdout=console,
                                        stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                        preexec_fn=_die_with(os.getpid()),
                                        start_new_session=True)
        console.close()
        _RUNNING.add(self)
        try:
            self.master = self._connect(mavutil, timeout_s)
            self.master.setup_logfile(str(self.tlog), mode="wb")
            self._await_heartbeat(timeout_s)
            self.get_param("SIM_SPEEDUP", timeout_s=timeout_s)    # the parameter table is up
            self._start_clock(timeout_s)
        except BaseException:
            self.stop()
            raise
        return self

    def _connect(self, mavutil, timeout_s: float):
        deadline = time.monotonic() + timeout_s
        while True:
            self._check_alive()
            try:
                return mavutil.mavlink_connection(f"tcp:127.0.0.1:{self.port}", retries=0,
                                                  source_system=GCS_SYSTEM_ID,
                                                  source_component=GCS_COMPONENT_ID,
                                                  autoreconnect=False, dialect="ardupilotmega")
            except OSError:
                if time.monotonic() > deadline:
                    raise SitlError(f"SITL never listened on tcp port {self.port}") from None
                time.sleep(0.1)

    def _await_heartbeat(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self.recv({"HEARTBEAT"}, timeout_s=1.0)
            if msg is not None and msg.get_srcComponent() == 1:
                self.master.target_system = msg.get_srcSystem()
                self.master.target_component = 1
                return
        raise SitlError(f"no heartbeat from SITL within {timeout_s:g} s")

    def _check_alive(self) -> None:
        if self.process is None or self.process.poll() is not None:
            tail = ""
            console = self.workdir / "sitl-console.txt"
            if console.exists():
                tail = " | ".join(console.read_text(errors="replace").splitlines()[-3:])
            raise SitlError(f"SITL is not running (exit {self.process and self.process.poll()}): "
                            f"{tail}")

    def stop(self) -> None:
        """Stop the firmware (SIGTERM to its process group, SIGKILL after 5 s) and close the
        link and the .tlog. Safe to call twice."""
        _RUNNING.discard(self)
        if self.master is not None:
            try:
                self.master.close()
            except OSError:
                pass
            logfile = getattr(self.master, "logfile", None)
            if logfile is not None:
                logfile.close()
            self.master = None
        if self.process is not None and self.process.poll() is None:
            for sig, wait_s in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
                try:
                    os.killpg(self.process.pid, sig)
                except ProcessLookupError:
                    break
                try:
                    self.process.wait(wait_s)
                    break
                except subprocess.TimeoutExpired:
                    continue
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    @property
    def pid(self) -> int | None:
        """The firmware's process id (None before start)."""
        return None if self.process is None else self.process.pid

    def __enter__(self):
        return self.start() if self.process is None else self

    def __exit__(self, *exc):
        self.stop()

    # -- messages and time --------------------------------------------------------------------
    def recv(self, types=None, timeout_s: float = 1.0):
        """The next message of ``types`` (a set of names, or any) within ``timeout_s`` [s wall];
        every message received goes to the .tlog and advances :attr:`time_boot_s`."""
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._check_alive()
                return None
            msg = self.master.recv_match(blocking=True, timeout=min(remaining, 0.5))
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            self._note(msg)
            if types is None or msg.get_type() in types:
                return msg

    def catch_up(self) -> None:
        """Read every message already waiting (none is waited for): what was received is then
        the firmware's present, not a queue of its past."""
        while (msg := self.master.recv_match(blocking=False)) is not None:
            self._note(msg)

    def _note(self, msg) -> None:
        """The firmware's clock and true attitude, from every message received."""
        stamp = getattr(msg, "time_boot_ms", None)
        if stamp is not None and msg.get_srcComponent() == 1:
            self.time_boot_s = max(self.time_boot_s, stamp / 1000.0)
        if msg.get_type() == "SIMSTATE":
            self._last_simstate = msg

    def request_message(self, message_id: int, rate_hz: float) -> None:
        """Ask for a message at ``rate_hz`` (SET_MESSAGE_INTERVAL), acknowledged."""
        interval_us = -1 if rate_hz <= 0 else 1e6 / rate_hz
        self.command(MAV_CMD_SET_MESSAGE_INTERVAL, message_id, interval_us)

    def _start_clock(self, timeout_s: float) -> None:
        """SYSTEM_TIME at 10 Hz from now on, and the first one read: :attr:`time_boot_s` is
        the firmware's clock from the start (no other message is sure to carry it)."""
        self.request_message(2, 10.0)
        self.request_message(164, 10.0)         # SIMSTATE: the true attitude, from the start
        if self.recv({"SYSTEM_TIME"}, timeout_s=timeout_s) is None:
            raise SitlError("no SYSTEM_TIME from the firmware")

    def run_for(self, seconds: float, on_message=None) -> None:
        """Let ``seconds`` of simulated time pass, receiving (and recording) all the while.

        The firmware's clock is read from its timestamped messages (SYSTEM_TIME at 10 Hz at
        least). ``on_message(msg)`` sees every message.
        """
        end = self.time_boot_s + seconds
        wall_limit = time.monotonic() + 30.0 + 3.0 * seconds / max(self.speedup, 0.1)
        while self.time_boot_s < end:
            if time.monotonic() > wall_limit:
                raise SitlError(f"the firmware's clock stalled at {self.time_boot_s:.1f} s")
            msg = self.recv(timeout_s=1.0)
            if msg is not None and on_message is not None:
                on_message(msg)

    # -- commands and parameters --------------------------------------------------------------
    def command(self, command: int, *params: float, timeout_s: float = 10.0,
                attempts: int = 3) -> None:
        """COMMAND_LONG ``command`` with up to 7 ``params``, until COMMAND_ACK accepts it."""
        values = list(params) + [0.0] * (7 - len(params))
        for _ in range(attempts):
            self.master.mav.command_long_send(self.master.target_system, 1, command, 0, *values)
            deadline = time.monotonic() + timeout_s / attempts
            while time.monotonic() < deadline:
                ack = self.recv({"COMMAND_ACK"}, timeout_s=deadline - time.monotonic())
                if ack is not None and ack.command == command:
                    if ack.result == MAV_RESULT_ACCEPTED:
                        return
                    raise SitlError(f"command {command} {values} refused (MAV_RESULT "
                                    f"{ack.result})")
        raise SitlError(f"command {command} never acknowledged")

    def get_param(self, name: str, timeout_s: float = 10.0) -> float:
        """The firmware's value of parameter ``name`` (PARAM_REQUEST_READ by name)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.master.mav.param_request_read_send(self.master.target_system, 1,
                                                    name.encode(), -1)
            msg = self._param_echo(name, min(1.0, deadline - time.monotonic()))
            if msg is not None:
                return float(msg.param_value)
        raise SitlError(f"parameter {name} not readable: does this firmware have it?")

    def all_params(self, timeout_s: float = 60.0) -> dict[str, float]:
        """Every parameter the firmware holds (PARAM_REQUEST_LIST, then each index that did
        not arrive asked for by index): name -> value, as stored (float32)."""
        got: dict[int, tuple[str, float]] = {}
        count = None
        deadline = time.monotonic() + timeout_s
        self.master.mav.param_request_list_send(self.master.target_system, 1)
        while count is None or len(got) < count:
            if time.monotonic() > deadline:
                raise SitlError(f"parameter list incomplete: {len(got)} of {count}")
            msg = self.recv({"PARAM_VALUE"}, timeout_s=1.0)
            if msg is not None:
                count = msg.param_count
                got[msg.param_index] = (_param_name(msg), float(msg.param_value))
            elif count is not None:
                for index in sorted(set(range(count)) - set(got))[:20]:
                    self.master.mav.param_request_read_send(self.master.target_system, 1, b"",
                                                            index)
        return dict(got.values())

    def _param_echo(self, name: str, timeout_s: float):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self.recv({"PARAM_VALUE"}, timeout_s=deadline - time.monotonic())
            if msg is not None and _param_name(msg) == name:
                return msg
        return None

    def set_params(self, values: dict, attempts: int = 5) -> None:
        """Write each parameter by name and confirm it from the firmware's PARAM_VALUE echo
        (the float32 value it now holds); a parameter it does not echo raises SitlError.

        Simulated time runs on during each round trip (at speedup 200, twenty writes can take
        a simulated minute or more): what must hold from the first sample goes in
        ``boot_params`` instead (and may be confirmed here afterwards)."""
        for name, value in values.items():
            self._set_param(name, float(value), attempts)

    def _set_param(self, name: str, value: float, attempts: int) -> None:
        want = float(np.float32(value))
        for _ in range(attempts):
            self.master.mav.param_set_send(self.master.target_system, 1, name.encode(), value, 9)
            msg = self._param_echo(name, 2.0)
            if msg is not None and float(np.float32(msg.param_value)) == want:
                return
            if msg is not None and _is_integer_type(msg.param_type) and msg.param_value == round(value):
                raise SitlError(f"{name} is an integer parameter: {value} cannot be set")
        raise SitlError(f"{name} = {value} not confirmed by the firmware after {attempts} tries")

    # -- the calibration model ----------------------------------------------------------------
    def set_servo(self, servo: int, pwm: int) -> None:
        """MAV_CMD_DO_SET_SERVO, acknowledged."""
        self.command(MAV_CMD_DO_SET_SERVO, servo, pwm)

    def pose(self, roll: float, pitch: float, yaw: float, settle_s: float = 3.0,
             rate_deg_s: float | None = None) -> None:
        """Turn the ``calibration`` model to an attitude [deg] and hold it; returns after
        ``settle_s`` simulated seconds (its attitude loop settles in about 1 s).

        The model's own attitude loop snaps to a new attitude at up to ~20 rad/s; with
        ``rate_deg_s`` the attitude asked for moves there along the shortest rotation at that
        rate instead (steps of 0.1 s), as a person turns a vehicle.
        """
        if rate_deg_s is not None:
            self._sweep_to(roll, pitch, yaw, rate_deg_s)
        self._hold_attitude(roll, pitch, yaw, stop_first=rate_deg_s is None)
        if settle_s > 0:
            self.run_for(settle_s)

    def _hold_attitude(self, roll: float, pitch: float, yaw: float, stop_first: bool,
                       acknowledged: bool = True) -> None:
        send = self.set_servo if acknowledged else self._send_servo
        if stop_first:
            send(SERVO_MODE, MODE_STOP_PWM)
        for servo, angle in ((6, roll), (7, pitch), (8, yaw)):
            send(servo, pwm_of_angle(angle))
        send(SERVO_MODE, MODE_ATTITUDE_PWM)

    def _send_servo(self, servo: int, pwm: int) -> None:
        """MAV_CMD_DO_SET_SERVO without waiting for its acknowledgement (over tcp it arrives)."""
        self.master.mav.command_long_send(self.master.target_system, 1, MAV_CMD_DO_SET_SERVO, 0,
                                          servo, pwm, 0, 0, 0, 0, 0)

    def _sweep_to(self, roll: float, pitch: float, yaw: float, rate_deg_s: float) -> None:
        from scipy.spatial.transform import Rotation, Slerp

        now = self.true_attitude()
        ends = Rotation.from_euler("ZYX", [[now.yaw, now.pitch, now.roll], [yaw, pitch, roll]],
                                   degrees=True)
        angle = math.degrees((ends[1] * ends[0].inv()).magnitude())
        step_s = 0.1          # the clock ticks at SYSTEM_TIME's 10 Hz
        steps = max(1, int(math.ceil(angle / rate_deg_s / step_s)))
        path = Slerp([0.0, 1.0], ends)(np.linspace(0.0, 1.0, steps + 1)[1:])
        with warnings.catch_warnings():     # at ±90° pitch roll and yaw are one angle: any split
            warnings.simplefilter("ignore", UserWarning)
            angles = path.as_euler("ZYX", degrees=True)
        for y, p, r in angles:      # unacknowledged: a step waits for nothing but the clock
            self._hold_attitude(r, p, y, stop_first=False, acknowledged=False)
            self.run_for(step_s)

    def spin(self, rate_rad_s: float, axis=(1.0, 0.0, 0.0)) -> None:
        """Turn the ``calibration`` model at ``rate_rad_s`` about ``axis`` (body frame) until
        told otherwise. The axis is given to the model as PWM offsets of up to ±400 from 1500."""
        norm = math.sqrt(sum(a * a for a in axis))
        if norm == 0:
            raise ValueError("the axis of a turn must not be zero")
        self.set_servo(SERVO_MODE, MODE_STOP_PWM)
        for servo, a in zip((6, 7, 8), axis):
            self.set_servo(servo, int(round(1500 + 400 * a / norm)))
        self.set_servo(SERVO_MODE, pwm_of_rate(rate_rad_s))

    def halt(self) -> None:
        """Stop any turn (damped) and leave the model where it is."""
        self.set_servo(SERVO_MODE, MODE_STOP_PWM)

    def true_attitude(self, timeout_s: float = 5.0) -> Attitude:
        """The simulation's true attitude now [deg]: the latest SIMSTATE (10 Hz from the start)
        once every message waiting has been read, so a driver that fell behind its link does
        not act on an attitude of seconds ago."""
        self._last_simstate = None
        self.catch_up()
        msg = self._last_simstate or self.recv({"SIMSTATE"}, timeout_s=timeout_s)
        if msg is None:
            raise SitlError("no SIMSTATE from the firmware")
        return Attitude(math.degrees(msg.roll), math.degrees(msg.pitch), math.degrees(msg.yaw))

    # -- ArduPilot's own calibrators ---------------------------------------------------------
    def onboard_accel_calibration(self, rate_deg_s: float = 90.0, settle_s: float = 2.0,
                                  timeout_sim_s: float = 600.0) -> float:
        """ArduPilot's own six-pose accelerometer calibration, as a ground station runs it:
        MAV_CMD_PREFLIGHT_CALIBRATION (accelerometer), then for each pose the firmware asks for
        (COMMAND_LONG MAV_CMD_ACCELCAL_VEHICLE_POS to us) the model is turned there at
        ``rate_deg_s``, left ``settle_s`` and the pose confirmed with the same command. The
        firmware saves INS_ACCOFFS/INS_ACCSCAL itself. Returns the simulated seconds it took.
        """
        start = self.time_boot_s
        self.command(MAV_CMD_PREFLIGHT_CALIBRATION, 0, 0, 0, 0, 1)
        while self.time_boot_s - start < timeout_sim_s:
            msg = self.recv({"COMMAND_LONG"}, timeout_s=1.0)
            if msg is None or msg.command != MAV_CMD_ACCELCAL_VEHICLE_POS:
                continue
            position = int(msg.param1)
            if position == ACCELCAL_SUCCESS:
                return self.time_boot_s - start
            if position not in ACCELCAL_ATTITUDES:
                raise SitlError(f"the firmware's accelerometer calibration failed ({position})")
            self.pose(*ACCELCAL_ATTITUDES[position], settle_s=settle_s, rate_deg_s=rate_deg_s)
            self.master.mav.command_long_send(self.master.target_system, 1,
                                              MAV_CMD_ACCELCAL_VEHICLE_POS, 0, position,
                                              0, 0, 0, 0, 0, 0)
        raise SitlError("the firmware's accelerometer calibration did not finish")

    def onboard_compass_calibration(self, axes, seconds_per_axis: float = 8.0,
                                    rate_rad_s: float = 1.2, compass_mask: int = 1,
                                    timeout_sim_s: float = 900.0):
        """ArduPilot's own compass calibration: MAV_CMD_DO_START_MAG_CAL (autosave on) for the
        compasses of ``compass_mask``, the model turned about ``axes`` in turn (and round again)
        until MAG_CAL_REPORT says it succeeded. Returns (the report, simulated seconds)."""
        start = self.time_boot_s
        self.request_message(192, 5.0)                          # MAG_CAL_REPORT
        self.command(MAV_CMD_DO_START_MAG_CAL, compass_mask, 0, 1, 0, 0)
        k = 0
        while self.time_boot_s - start < timeout_sim_s:
            self.spin(rate_rad_s, axes[k % len(axes)])
            k += 1
            end = self.time_boot_s + seconds_per_axis
            while self.time_boot_s < end:
                msg = self.recv({"MAG_CAL_REPORT"}, timeout_s=1.0)
                if msg is None:
                    continue
                if msg.cal_status == MAG_CAL_SUCCESS:
                    self.halt()
                    self.request_message(192, 0)
                    return msg, self.time_boot_s - start
                raise SitlError(f"the firmware's compass calibration failed (status "
                                f"{msg.cal_status}, fitness {msg.fitness:.1f})")
        raise SitlError("the firmware's compass calibration did not finish")

    # -- flying and driving -------------------------------------------------------------------
    def set_mode(self, name: str, timeout_s: float = 10.0) -> None:
        """Switch to flight mode ``name`` (e.g. "GUIDED", "MANUAL") and see the heartbeat say so."""
        mapping = self.master.mode_mapping()
        if name not in mapping:
            raise SitlError(f"mode {name} unknown to {self.vehicle}")
        number = mapping[name]
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.master.set_mode(number)
            hb = self.recv({"HEARTBEAT"}, timeout_s=1.0)
            if hb is not None and hb.get_srcComponent() == 1 and hb.custom_mode == number:
                return
        raise SitlError(f"mode {name} not entered")

    def arm(self, force: bool = False, timeout_s: float = 120.0) -> None:
        """Arm, retried while the firmware refuses (EKF not ready yet) up to ``timeout_s`` [s]."""
        deadline = time.monotonic() + timeout_s
        last = None
        while time.monotonic() < deadline:
            try:
                self.command(MAV_CMD_COMPONENT_ARM_DISARM, 1, FORCE_ARM_MAGIC if force else 0)
                return
            except SitlError as exc:
                last = exc
                self.run_for(1.0)
        raise SitlError(f"not armed: {last}")

    def disarm(self) -> None:
        """Disarm (forced: also in flight, for tests that end there)."""
        self.command(MAV_CMD_COMPONENT_ARM_DISARM, 0, FORCE_ARM_MAGIC)

    def wait_position_estimate(self, timeout_sim_s: float = 120.0) -> None:
        """Wait until the EKF gives a horizontal position (GLOBAL_POSITION_INT with a fix, and
        EKF_STATUS_REPORT's flags for a horizontal absolute position)."""
        end = self.time_boot_s + timeout_sim_s
        self.request_message(193, 2.0)      # EKF_STATUS_REPORT
        while self.time_boot_s < end:
            msg = self.recv({"EKF_STATUS_REPORT"}, timeout_s=2.0)
            if msg is not None and msg.flags & 0x10:        # EKF_POS_HORIZ_ABS
                return
            self.run_for(0.5)
        raise SitlError("the EKF never reached a horizontal position estimate")

    def takeoff(self, altitude_m: float) -> None:
        """Copter: GUIDED, arm, take off to ``altitude_m`` above home and wait to reach it."""
        self.wait_position_estimate()
        self.request_message(33, 5.0)           # GLOBAL_POSITION_INT: the height above home
        self.set_mode("GUIDED")
        self.arm()
        self.command(MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m)
        self._wait_altitude(altitude_m * 0.95)

    def _wait_altitude(self, altitude_m: float, timeout_sim_s: float = 60.0) -> None:
        end = self.time_boot_s + timeout_sim_s
        while self.time_boot_s < end:
            msg = self.recv({"GLOBAL_POSITION_INT"}, timeout_s=2.0)
            if msg is not None and msg.relative_alt / 1000.0 >= altitude_m:
                return
        raise SitlError(f"altitude {altitude_m:g} m not reached")

    def fly_to(self, north_m: float, east_m: float, up_m: float, seconds: float,
               yaw_deg: float | None = None, yaw_rate_deg_s: float | None = None) -> None:
        """Copter in GUIDED: fly to a point [m] from home (NED frame, ``up_m`` above home) and
        hold it for ``seconds`` of simulated time, facing ``yaw_deg`` or turning at
        ``yaw_rate_deg_s`` (neither: the autopilot's own choice)."""
        type_mask = IGNORE_VELOCITY | IGNORE_ACCELERATION
        type_mask |= IGNORE_YAW_RATE if yaw_rate_deg_s is None else IGNORE_YAW
        if yaw_deg is None and yaw_rate_deg_s is None:
            type_mask |= IGNORE_YAW
        yaw = math.radians(yaw_deg or 0.0)
        yaw_rate = math.radians(yaw_rate_deg_s or 0.0)
        end = self.time_boot_s + seconds
        while self.time_boot_s < end:
            self.master.mav.set_position_target_local_ned_send(
                0, self.master.target_system, 1, MAV_FRAME_LOCAL_NED, type_mask,
                north_m, east_m, -up_m, 0, 0, 0, 0, 0, 0, yaw, yaw_rate)
            self.run_for(min(1.0, end - self.time_boot_s))

    def land(self, timeout_sim_s: float = 120.0) -> None:
        """Copter: LAND and wait until it has disarmed by itself."""
        self.set_mode("LAND")
        end = self.time_boot_s + timeout_sim_s
        while self.time_boot_s < end:
            hb = self.recv({"HEARTBEAT"}, timeout_s=2.0)
            if hb is not None and hb.get_srcComponent() == 1 and not hb.base_mode & 0x80:
                return
        raise SitlError("did not land and disarm")

    def drive(self, steering_pwm: int, throttle_pwm: int, seconds: float) -> None:
        """Rover in MANUAL: hold RC1 (steering) and RC3 (throttle) for ``seconds`` of simulated
        time (RC_CHANNELS_OVERRIDE sent at 5 Hz simulated)."""
        end = self.time_boot_s + seconds
        while self.time_boot_s < end:
            channels = [steering_pwm, 0, throttle_pwm] + [0] * 5
            self.master.mav.rc_channels_override_send(self.master.target_system, 1, *channels)
            self.run_for(min(0.2, end - self.time_boot_s))
        self.master.mav.rc_channels_override_send(self.master.target_system, 1, 1500, 0, 1500,
                                                  *([0] * 5))

    # -- what it recorded ---------------------------------------------------------------------
    def flush_logs(self, wall_s: float = 1.0) -> None:
        """Let the dataflash logger catch up with the simulation before the logs are taken: at
        a high speedup its writer runs seconds of simulated time behind (measured: a log of a
        245 s session covered 237 s on a busy machine), and what it has not written when the
        firmware stops is lost. The simulation runs at real time (SIM_SPEEDUP 1) for ``wall_s``
        wall seconds (and stays at it), so the logs end past the session, not short of it."""
        self.set_params({"SIM_SPEEDUP": 1})
        deadline = time.monotonic() + wall_s
        while time.monotonic() < deadline:
            self.recv(timeout_s=0.1)

    def dataflash_logs(self) -> list[Path]:
        """The dataflash logs the firmware wrote in its scratch folder, oldest first."""
        return sorted((self.workdir / "logs").glob("*.BIN"), key=lambda p: p.stat().st_mtime)


def _param_name(msg) -> str:
    name = msg.param_id
    if isinstance(name, bytes):
        name = name.decode(errors="replace")
    return name.rstrip("\x00")


def _is_integer_type(param_type: int) -> bool:
    return 1 <= param_type <= 8
