"""The simulated APM 2.8 vehicle, in-process: motion → IMU errors → firmware → MAVLink messages.

:class:`SimVehicle` has no clock of its own: :meth:`SimVehicle.step` advances simulated time by
``dt`` as fast as numpy allows, so tests and the log maker need no real time. The network endpoint
(:mod:`apmcal_sim.mavlink_vehicle`) paces it against the wall clock.
"""
from __future__ import annotations

import collections
import re
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from apmcal.core.constants import earth_rate_ned
from apmcal.sensor_model.imu import ImuErrorModel
from apmcal.sensor_model.truth import FULL_THROTTLE_CURRENT_A, Truth
from apmcal_sim import firmware, motion
from apmcal_sim.geomag import decimal_year, earth_field_ned
from apmcal_sim.params_store import ParamStore

VERSION_TEXT = {"3.2": "ArduCopter V3.2.1 (sitl)", "3.3": "ArduCopter V3.3.3 (sitl)"}
RAW_SENSORS_MSGS = {"3.2": ("RAW_IMU", "SCALED_PRESSURE"),
                    "3.3": ("RAW_IMU", "SCALED_IMU2", "SCALED_PRESSURE")}
STATS_FLUSH_S = 30.0          # AP_Stats flush_interval_ms: STAT_RUNTIME saved every 30 s
STREAM_MAX_HZ = 50.0          # ArduPilot caps SRn_* stream rates (ardupilot-facts.md: ≤ 50 Hz)
INTERVAL_MAX_HZ = 400.0       # MAV_CMD_SET_MESSAGE_INTERVAL fastest rate simulated
MSG_IDS = {"RAW_IMU": 27, "SCALED_IMU2": 116, "HIGHRES_IMU": 105, "SCALED_PRESSURE": 29,
           "HEARTBEAT": 0, "SYS_STATUS": 1}
ACC_MG = 1000.0 / 9.80665     # RAW_IMU: get_accel()*1000/9.80665 (ardupilot-facts.md)
# HIGHRES_IMU xmag/ymag/zmag per mGauss of field: MAVLink says gauss. ArduPilot firmware of about
# May 2024 - Feb 2026 sent mGauss×1000 instead, 1e6 times too much: --highres-mag-bug
# (docs/ardupilot-facts.md "What the telemetry really carries")
HIGHRES_GAUSS_PER_MGAUSS = 1e-3
FAULTY_HIGHRES_MAG_PER_MGAUSS = 1e3


def _int16(x, truncate: bool = True) -> list[int]:
    """RAW_IMU int16 truncation toward zero (C float → int16 cast), saturated.

    With the quantization effect off the message still carries integers, but rounded to the
    nearest (unbiased) instead of truncated toward zero.
    """
    return [int(v) for v in np.clip(np.trunc(x) if truncate else np.round(x), -32768, 32767)]


class SimVehicle:
    """A simulated ArduCopter 3.2 / 3.3 on an APM 2.8-like board.

    Parameters
    ----------
    truth : Truth
        The injected errors.
    script : str
        Motion script name (:data:`apmcal_sim.motion.SCRIPTS`).
    generation : "3.2" or "3.3"
    param_file : path, optional
        Parameter persistence (JSON); created / updated on PARAM_SET.
    fs : float
        Internal sensor rate [Hz].
    seed : int
        Noise seed (also the tumble script's seed).
    record : bool
        Keep the per-sample truth/raw/reported time series (:meth:`history`).
    duration : float, optional
        Script length for stretchable scripts (onepos, warmup, tumble, motors).
    full_params : bool
        A real vehicle's full-size parameter table (about 1,350 names,
        :data:`apmcal_sim.params_store.FULL_SIZE_PARAM_COUNT`), not only those simulated.
    """

    #: HIGHRES_IMU magnetic field units per mGauss (FAULTY_HIGHRES_MAG_PER_MGAUSS: the bug)
    highres_mag_per_mgauss = HIGHRES_GAUSS_PER_MGAUSS
    #: True: the compass's raw readings are rounded to whole mGauss before the firmware's
    #: correction, as a real ArduPilot SITL's are (every message then carries whole mGauss
    #: while the corrections are neutral)
    whole_mgauss_compass = False
    #: PARAM_VALUEs per simulated second of the answer to PARAM_REQUEST_LIST; None: all at
    #: once (in-process use). ArduPilot paces the list to its link (at most 30 % of the
    #: bandwidth, GCS_MAVLINK::queued_param_send): the network endpoint sets a rate
    param_list_rate_hz: float | None = None

    def __init__(self, truth: Truth | None = None, script: str = "onepos", generation: str = "3.2",
                 param_file=None, fs: float = 1000.0, seed: int = 0, record: bool = False,
                 duration: float | None = None, gyro_boot_s: float = 1.0,
                 start_unix: float | None = None, full_params: bool = False):
        if generation not in firmware.GENERATIONS:
            raise ValueError(f"firmware generation must be one of {firmware.GENERATIONS}")
        self.truth = truth if truth is not None else Truth.random(seed)
        self.generation, self.fs, self.script = generation, float(fs), script
        self.params = ParamStore(generation, param_file, full_params)
        self.motion = motion.build(script, seed, duration)
        self.model = ImuErrorModel(self.truth, fs, seed)
        # the script's hand tremor (handheld_real) in place of the truth's figures
        self.tremor = (motion.Tremor(self.motion.tremor or self.truth.motion_contamination, seed)
                       if self.truth.on("motion_contamination") else None)
        site = self.truth.site
        self.gravity = self.truth.gravity()
        self.earth_rate = earth_rate_ned(site["lat"]) if self.truth.on("earth_rate") else np.zeros(3)
        # the WMM epoch: the site's year if given, else the date of the vehicle's clock
        self.start_unix = time.time() if start_unix is None else float(start_unix)
        self.wmm_year = (decimal_year(self.start_unix) if site.get("year") is None
                         else float(site["year"]))
        self.field_ned = earth_field_ned(site["lat"], site["lon"], site["alt"], self.wmm_year)
        self.board_rot = firmware.rotation_matrix(self.truth.board_orientation)
        # the compass chip: on the board (internal) or mounted on its own (external)
        mount = self.truth.compass_orientation
        self.compass_rot = self.board_rot if mount is None else firmware.rotation_matrix(mount)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.tick = 0                         # index of the next sensor sample
        self.throttle = 0.0                   # 0..1 added to the script's throttle profile
        self.outbox: list = []                # (time [s], pymavlink message)
        self.streams: dict[str, float] = {}   # message name → interval [s]
        self.next_due: dict[str, float] = {}
        self.gyro_boot_s = gyro_boot_s
        self._boot_gyro: list = [] if self.params["INS_GYR_CAL"] == 1 else None
        self.record, self._hist = record, []
        self.commands: list = []              # (time [s], COMMAND_LONG) received, for tests
        self.stream_requested_at = None       # simulated time [s] a ground station first asked
                                              # for the IMU stream (None: not yet)
        self.last: dict = {}
        self._next_1hz = 0.0
        self._param_stream: collections.deque = collections.deque()   # list still to send
        self._param_tokens = 0.0
        self._count_boot()
        sr = self.params["SR0_RAW_SENS"]
        if sr > 0:
            self.request_stream(1, sr)
        self.send_text(VERSION_TEXT[generation])

    # ---- time -----------------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Simulated time since boot [s] (time of the next sample)."""
        return self.tick / self.fs

    def run_for(self, seconds: float, chunk: float = 0.1) -> None:
        """Advance ``seconds`` of simulated time in chunks (no real time needed)."""
        end = self.tick + int(round(seconds * self.fs))
        while self.tick < end:
            self.step(min(chunk, (end - self.tick) / self.fs))

    def step(self, dt: float) -> None:
        """Simulate the sensor samples in [t, t + dt) and queue the messages due in it."""
        n = int(round(dt * self.fs))
        if n <= 0:
            return
        boot_tick = int(round(self.gyro_boot_s * self.fs))
        if self._boot_gyro is not None and self.tick < boot_tick < self.tick + n:
            # split at the end of the boot gyro calibration so the new INS_GYROFFS apply from
            # exactly that sample whatever the chunking
            first = boot_tick - self.tick
            self.step(first / self.fs)
            self.step((n - first) / self.fs)
            return
        t = (self.tick + np.arange(n)) / self.fs
        s = self._sense(t)
        self._report(s)                         # with the parameters in force now
        self._boot_calibration(t, s["raw_gyr"])
        if self.record:
            self._hist.append(s)
        self._emit(t, s)
        self.tick += n
        self._stream_params(n / self.fs)
        self._flush_stats()

    # ---- running counters -----------------------------------------------------------------
    def _count_boot(self) -> None:
        """AP_Stats::init: STAT_BOOTCNT + 1, saved (tables with STAT_* only)."""
        if "STAT_BOOTCNT" in self.params:
            self.params.set("STAT_BOOTCNT", self.params["STAT_BOOTCNT"] + 1)
        self._runtime_at_boot = self.params.get("STAT_RUNTIME")
        self._next_stats_flush = STATS_FLUSH_S

    def _flush_stats(self) -> None:
        """AP_Stats::update: STAT_RUNTIME saved every STATS_FLUSH_S, from the firmware's own
        count (a value a ground station wrote is overwritten)."""
        if self._runtime_at_boot is None or self.t < self._next_stats_flush:
            return
        self.params.set("STAT_RUNTIME", self._runtime_at_boot + int(self.t))
        self._next_stats_flush += STATS_FLUSH_S

    # ---- physics --------------------------------------------------------------------------
    def _attitude(self, t: np.ndarray):
        rot, rate, idx = self.motion.evaluate(t)
        rot, rate = motion.contaminate(rot, rate, t, self.tremor)
        return rot, rate, idx

    def _sense(self, t: np.ndarray) -> dict:
        rot, rate, idx = self._attitude(t)
        g_ned = np.array([0.0, 0.0, self.gravity])
        # specific force f = a − g (ardupilot-facts.md): still → R_nbᵀ·(0, 0, −g); a the
        # script's linear acceleration (hand-held turns that move the board)
        f_body = np.einsum("nji,nj->ni", rot, self.motion.acceleration(t) - g_ned)
        tau = self.truth.time_offset if self.truth.on("time_offset") else 0.0
        f_acc_body = f_body
        if tau:
            rot_a, _, _ = self._attitude(t - tau)   # the accelerometer samples the past
            f_acc_body = np.einsum("nji,nj->ni", rot_a, self.motion.acceleration(t - tau) - g_ned)
        w_body = rate + np.einsum("nji,j->ni", rot, self.earth_rate)
        # the Earth's field and, near a laptop, its slowly changing one (handheld_real)
        b_body = np.einsum("nji,nj->ni", rot, self.field_ned + self.motion.field_disturbance(t))
        to_board = self.board_rot                   # v_board = Rᵀ v_body, as rows: v @ R
        thr = self.throttle_at(t)
        raw_acc = self.model.accel(t, f_acc_body @ to_board)
        raw_gyr = self.model.gyro(t, w_body @ to_board, f_body @ to_board)
        raw_mag = self.model.mag(b_body @ self.compass_rot, thr)
        if self.whole_mgauss_compass:
            raw_mag = np.round(raw_mag)
        return {"t": t, "rot": rot, "rate": rate, "w_body": w_body, "f_body": f_body,
                "b_body": b_body, "segment": idx, "throttle": thr,
                "temp": self.model.temperature(t),
                "raw_acc": raw_acc, "raw_gyr": raw_gyr, "raw_mag": raw_mag}

    def throttle_at(self, t) -> np.ndarray:
        """Throttle (0..1) at times t: the script's profile plus :attr:`throttle`, clipped."""
        thr = self.motion.throttle(t)
        if self.throttle:
            thr = np.clip(thr + self.throttle, 0.0, 1.0)
        return thr

    def current_at(self, t) -> np.ndarray:
        """Battery current [A] at times t: modelled as FULL_THROTTLE_CURRENT_A (20 A) × throttle."""
        return self.throttle_at(t) * FULL_THROTTLE_CURRENT_A

    def motor_offset(self, t) -> np.ndarray:
        """The firmware's COMPASS_MOT·(throttle or current) at times t (MAG MOX..Z) [mGauss]."""
        return firmware.compass_motor_offset(self.params.as_dict(), self.throttle_at(t),
                                             self.current_at(t), len(np.atleast_1d(t)))

    def reset_zero_compass_diagonals(self) -> None:
        """3.3: COMPASS_DIA_X/Y/Z all 0 become 1 at the next compass sample, in RAM only.

        Copter 3.3 ``apply_corrections`` (see :func:`apmcal_sim.firmware.soft_iron_matrix` for the
        sources): ``if (state.diagonals.get().is_zero())
        state.diagonals.set(Vector3f(1.0f,1.0f,1.0f));``, so a PARAM_VALUE read afterwards
        says 1. Not saved by the firmware; here a later save of another parameter writes the
        whole table, 1s included.
        """
        if self.generation != "3.2" and firmware.dia_all_zero(self.params.as_dict()):
            for axis in "XYZ":
                self.params.set(f"COMPASS_DIA_{axis}", 1.0, save=False)

    def _boot_calibration(self, t: np.ndarray, raw_gyr: np.ndarray) -> None:
        """INS_GYR_CAL=1: average the first ``gyro_boot_s`` of gyro, store INS_GYROFFS."""
        if self._boot_gyro is None:
            return
        boot_tick = int(round(self.gyro_boot_s * self.fs))
        self._boot_gyro.append(raw_gyr[: max(boot_tick - self.tick, 0)])
        if self.tick + len(t) >= boot_tick:      # step() splits chunks at boot_tick
            offs = firmware.gyro_boot_offsets(np.concatenate(self._boot_gyro),
                                              self.params.as_dict(), self.generation)
            for axis, v in zip("XYZ", offs):
                self.params.set(f"INS_GYROFFS_{axis}", v)
            self._boot_gyro = None

    def _report(self, s: dict) -> None:
        gen = self.generation
        self.reset_zero_compass_diagonals()
        p = self.params.as_dict()
        s["acc"] = firmware.apply_accel(s["raw_acc"], p, gen, s["temp"])
        s["gyr"] = firmware.apply_gyro(s["raw_gyr"], p, gen, s["temp"])
        # battery current modelled as FULL_THROTTLE_CURRENT_A × throttle (also in SYS_STATUS)
        s["mag"] = firmware.apply_compass(s["raw_mag"], p, gen, s["throttle"],
                                          s["throttle"] * FULL_THROTTLE_CURRENT_A)
        if gen != "3.2":   # second IMU: same sensor, its own INS_ACC2*/INS_GYR2* parameters
            p2 = {k.replace("INS_ACC2", "INS_ACC").replace("INS_GYR2OFFS", "INS_GYROFFS"): v
                  for k, v in p.items() if "2" in k}
            p2["AHRS_ORIENTATION"] = p["AHRS_ORIENTATION"]
            s["acc2"] = firmware.apply_accel(s["raw_acc"], p2, gen)
            s["gyr2"] = firmware.apply_gyro(s["raw_gyr"], p2, gen)

    def history(self) -> dict:
        """Concatenated per-sample series recorded so far (``record=True``)."""
        if not self._hist:
            return {}
        return {k: np.concatenate([h[k] for h in self._hist]) for k in self._hist[0]}

    # ---- messages out ---------------------------------------------------------------------
    def queue(self, t: float, msg) -> None:
        """Queue ``msg`` to be sent at simulated time ``t`` [s]."""
        self.outbox.append((t, msg))

    def pop_messages(self) -> list:
        """Queued (time [s], message) pairs in time order; empties the queue."""
        out = sorted(self.outbox, key=lambda m: m[0])
        self.outbox = []
        return out

    def encode(self, msg) -> bytes:
        """Pack a message with this vehicle's MAVLink 2 sequence counter."""
        return bytes(msg.pack(self.mav))

    def send_text(self, text: str, severity: int = 6) -> None:
        """Queue a STATUSTEXT (cut to 50 bytes) at the current time."""
        self.queue(self.t, mavlink.MAVLink_statustext_message(severity, text.encode()[:50]))

    def _emit(self, t: np.ndarray, s: dict) -> None:
        t1 = t[-1] + 1.0 / self.fs
        while self._next_1hz < t1:
            self._queue_1hz(self._next_1hz)
            self._next_1hz += 1.0
        end = self.tick + len(t)
        for name, interval in self.streams.items():
            due = self.next_due[name]
            # a message reports the last sample at or before its time; it belongs to this step
            # when that sample does (comparing times instead would, with a time summed up in
            # floating point just short of the step's end, report this step's last sample twice
            # and the next step's first never)
            while (k := int(np.floor(due * self.fs + 1e-6))) < end:
                j = max(k - self.tick, 0)
                self.queue(due, self._build(name, due, s, j))
                due += interval
            self.next_due[name] = due

    def _queue_1hz(self, when: float) -> None:
        self.queue(when, mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
            mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0, mavlink.MAV_STATE_STANDBY, 3))
        present = 0x1 | 0x2 | 0x4 | 0x8          # 3D gyro, accel, mag, abs pressure
        current_ca = int(self.current_at(when)[0] * 100)      # SYS_STATUS current in cA
        self.queue(when, mavlink.MAVLink_sys_status_message(
            present, present, present, 200, 12600, current_ca, 90, 0, 0, 0, 0, 0, 0))

    def _build(self, name: str, when: float, s: dict, j: int):
        acc, gyr, mag, temp = s["acc"][j], s["gyr"][j], s["mag"][j], s["temp"][j]
        usec, ms = int(round(when * 1e6)), int(round(when * 1e3)) & 0xFFFFFFFF
        q = self.truth.on("quantization")
        if name == "RAW_IMU":
            a, g, m = _int16(acc * ACC_MG, q), _int16(gyr * 1000.0, q), _int16(mag, q)
            return mavlink.MAVLink_raw_imu_message(usec, *a, *g, *m, 0, int(temp * 100))
        if name == "SCALED_IMU2":
            a, g = _int16(s["acc2"][j] * ACC_MG, q), _int16(s["gyr2"][j] * 1000.0, q)
            return mavlink.MAVLink_scaled_imu2_message(ms, *a, *g, *_int16(mag, q),
                                                       int(temp * 100))
        if name == "HIGHRES_IMU":
            return mavlink.MAVLink_highres_imu_message(
                usec, *acc, *gyr, *(mag * self.highres_mag_per_mgauss), self._pressure_hpa(), 0.0,
                float(self.truth.site["alt"]), float(temp), 0x1FFF, 0)
        if name == "SCALED_PRESSURE":
            return mavlink.MAVLink_scaled_pressure_message(ms, self._pressure_hpa(), 0.0,
                                                           int(temp * 100))
        raise ValueError(name)

    def _pressure_hpa(self) -> float:
        """ISA pressure at the site height [hPa]."""
        return 1013.25 * (1 - 2.25577e-5 * self.truth.site["alt"]) ** 5.25588

    # ---- stream control -------------------------------------------------------------------
    def set_interval(self, name: str, rate_hz: float) -> None:
        """Stream ``name`` at ``rate_hz`` (0 stops); first message at the current time."""
        if rate_hz <= 0:
            self.streams.pop(name, None)
            self.next_due.pop(name, None)
            return
        self.streams[name] = 1.0 / rate_hz
        self.next_due[name] = self.t

    def request_stream(self, stream_id: int, rate_hz: float, start: bool = True) -> None:
        """REQUEST_DATA_STREAM: RAW_SENSORS (1) or ALL (0); the rate is stored in SR0_RAW_SENS."""
        if stream_id not in (mavlink.MAV_DATA_STREAM_ALL, mavlink.MAV_DATA_STREAM_RAW_SENSORS):
            return
        rate = min(float(rate_hz), STREAM_MAX_HZ) if start else 0.0
        for name in RAW_SENSORS_MSGS[self.generation]:
            self.set_interval(name, rate)
        self.params.set("SR0_RAW_SENS", rate)

    # ---- messages in ----------------------------------------------------------------------
    def handle(self, msg) -> None:
        """React to one message from the ground station."""
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            self.send_text(VERSION_TEXT[self.generation])
            if self.param_list_rate_hz is None:
                for name in self.params.names:
                    self._param_value(name)
            else:       # a new request restarts the list, as the firmware's does
                self._param_stream = collections.deque(self.params.names)
        elif kind == "PARAM_REQUEST_READ":
            name = msg.param_id if msg.param_index < 0 else (
                self.params.names[msg.param_index] if msg.param_index < len(self.params) else None)
            if name in self.params:
                self._param_value(name)
        elif kind == "PARAM_SET":
            if self.params.set(msg.param_id, msg.param_value) is not None:
                for name in self.params.answered_set_with(msg.param_id):
                    self._param_value(name)
        elif kind == "REQUEST_DATA_STREAM":
            self.request_stream(msg.req_stream_id, msg.req_message_rate, bool(msg.start_stop))
            if msg.start_stop and self.stream_requested_at is None:
                self.stream_requested_at = self.t
        elif kind == "COMMAND_LONG":
            self.commands.append((self.t, msg))
            self._command(msg)

    def _stream_params(self, dt: float) -> None:
        """Send the list's next PARAM_VALUEs, ``param_list_rate_hz`` per simulated second."""
        if not self._param_stream:
            self._param_tokens = 0.0
            return
        self._param_tokens += dt * self.param_list_rate_hz
        while self._param_stream and self._param_tokens >= 1.0:
            self._param_value(self._param_stream.popleft())
            self._param_tokens -= 1.0

    def _param_value(self, name: str) -> None:
        self.queue(self.t, mavlink.MAVLink_param_value_message(
            name.encode(), self.params[name], mavlink.MAV_PARAM_TYPE_REAL32, len(self.params),
            self.params.index(name)))

    def _command(self, msg) -> None:
        cmd, result = msg.command, mavlink.MAV_RESULT_UNSUPPORTED
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and self.generation != "3.2":
            name = {v: k for k, v in MSG_IDS.items()}.get(int(msg.param1))
            if name in ("RAW_IMU", "SCALED_IMU2", "HIGHRES_IMU", "SCALED_PRESSURE"):
                us = msg.param2
                rate = 0.0 if us < 0 else (STREAM_MAX_HZ if us == 0 else 1e6 / us)
                self.set_interval(name, min(rate, INTERVAL_MAX_HZ))
                result = mavlink.MAV_RESULT_ACCEPTED
            else:
                result = mavlink.MAV_RESULT_DENIED
        elif cmd == mavlink.MAV_CMD_ACCELCAL_VEHICLE_POS:
            # the firmware takes it only while its own accel cal waits for that very pose
            # (AP_AccelCal::gcs_vehicle_position), else MAV_RESULT_FAILED; no onboard accel
            # cal runs here, and the vehicle does not move on a command
            result = mavlink.MAV_RESULT_FAILED
        self.queue(self.t, mavlink.MAVLink_command_ack_message(cmd, result))

    # ---- operator mode --------------------------------------------------------------------
    def goto_pose(self, pose, move_s: float = 3.0, label: str | None = None) -> None:
        """Operator mode: turn to ``pose`` (a :data:`apmcal_sim.motion.POSES` name, or an attitude
        matrix R_nb) starting now, or when the turns asked for before are done."""
        m = self.motion
        if self.t > m.duration:
            m.hold(self.t - m.duration, m.segments[-1].label if m.segments else "level")
        target = motion.pose_matrix(pose) if isinstance(pose, str) else pose
        m.move_to(target, move_s)
        # the pose label continues through the implicit final hold
        m.hold(0.5, label or (pose if isinstance(pose, str) else "pose"))

    def tumble(self, seconds: float = 40.0, step_s: float = 2.0) -> None:
        """Operator mode: turn slowly through every direction, as a compass calibration asks:
        turns of 90-180° about random body axes, ``step_s`` [s] each, for ``seconds`` [s] in
        all, then rest; starting now, or when the turns asked for before are done."""
        m = self.motion
        if self.t > m.duration:
            m.hold(self.t - m.duration, m.segments[-1].label if m.segments else "level")
        self._tumbles = getattr(self, "_tumbles", 0) + 1
        rng = np.random.default_rng(np.random.SeedSequence([self._tumbles, 0x70B1E]))
        for _ in range(max(1, int(seconds // step_s))):
            m.rotate(rng.standard_normal(3), rng.uniform(90, 180) * rng.choice([-1, 1]),
                     step_s, "tumble")
        m.hold(0.5, "tumble")

    def stay(self, seconds: float) -> None:
        """Operator mode: keep the current pose ``seconds`` longer before the next turn."""
        m = self.motion
        if self.t > m.duration:
            m.hold(self.t - m.duration, m.segments[-1].label if m.segments else "level")
        m.hold(seconds, m.segments[-1].label if m.segments else "level")

    def motion_done(self) -> bool:
        """True once every turn asked for is over (the vehicle rests in its last pose)."""
        return self.t >= self.motion.duration


class SixPosePerson:
    """The person at the vehicle during ``apmcal live --guide ardupilot6 --auto``: from the
    moment a ground station first asks for the IMU stream (when ``apmcal live`` starts
    recording), turns the vehicle through ArduPilot's six accelerometer-calibration poses in
    the firmware's order (level, LEFT, RIGHT, nose DOWN, nose UP, BACK), each held still for
    ``hold_s`` simulated seconds after a ``move_s`` turn, and starts over after the sixth.

    ``hold_s`` must exceed the guide's ``--hold`` by the guide's second of stillness before a
    pose is judged and some margin: the default 15 s serves the guide's default ``--hold 10``.
    Call :meth:`step` after every advance of the vehicle (the network endpoint's ``on_poll``).
    """

    ORDER = tuple(motion.ACCELCAL_POSES[k] for k in range(1, 7))

    def __init__(self, hold_s: float = 15.0, move_s: float = 3.0):
        self.hold_s, self.move_s = float(hold_s), float(move_s)
        self.poses_done = 0          # poses held so far (the first, level, counts once held)

    def step(self, vehicle: SimVehicle) -> None:
        """Start when the stream was asked for; turn to the next pose once the last is held."""
        if vehicle.stream_requested_at is None or not vehicle.motion_done():
            return
        if self.poses_done == 0:       # the vehicle rests level: hold it from now
            vehicle.stay(self.hold_s)
        else:
            vehicle.goto_pose(self.ORDER[self.poses_done % 6], self.move_s)
            vehicle.stay(self.hold_s - 0.5)      # goto_pose holds 0.5 s itself
        self.poses_done += 1


_TEXT_POSES = (("nose down", "nosedown"), ("nosedown", "nosedown"), ("nose up", "noseup"),
               ("noseup", "noseup"), ("left", "left"), ("right", "right"), ("back", "back"),
               ("level", "level"))


def parse_pose_text(text: str) -> str | None:
    """Pose named in an operator's words ("nose DOWN", "on its LEFT side", "x_p"), else None."""
    low = text.lower()
    face = re.search(r"\b([xyz]_[pa])\b", low)
    if face:
        return face.group(1)
    for key, pose in _TEXT_POSES:
        if key in low:
            return pose
    return None
