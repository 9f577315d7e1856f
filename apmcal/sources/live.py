"""A live vehicle over MAVLink (pymavlink for the protocol only).

The link records everything it receives to a telemetry log (.tlog, the same byte layout MAVProxy
and Mission Planner write), and the IMU samples are then read back with the ordinary tlog reader:
one conversion path for live and logged data, and the user keeps the raw recording.
"""
from __future__ import annotations

import contextlib
import io
import math
import struct
import time
from pathlib import Path

import numpy as np

from apmcal.constants import DEFAULT_BAUD
from apmcal.errors import ApmcalError

# ardupilot-facts.md "What the telemetry really carries": stream 1 = RAW_SENSORS carries RAW_IMU,
# SCALED_IMU2/3 and SCALED_PRESSURE; newer firmware also honours SET_MESSAGE_INTERVAL (511),
# through which HIGHRES_IMU (SI floats, free of RAW_IMU's 1 mG / 1 mrad/s steps) is asked for.
IMU_MESSAGE_IDS = {"RAW_IMU": 27, "SCALED_IMU2": 116, "HIGHRES_IMU": 105}
STREAMED_MESSAGE_IDS = {**IMU_MESSAGE_IDS, "SCALED_PRESSURE": 29}

# PARAM_REQUEST_READs sent before waiting for their answers: a bounded batch, so that the
# vehicle's request queue (small on a flight controller) is not overrun
READS_IN_FLIGHT = 20
MAV_AUTOPILOT_INVALID = 8       # HEARTBEAT.autopilot of anything that is not a flight controller

# tcp: a refused connection is tried this many times, this many seconds apart (pymavlink's
# mavtcp ``retries`` counts the attempts)
TCP_ATTEMPTS = 3
TCP_RETRY_DELAY_S = 1.0


def float32(value: float) -> float:
    """``value`` as the vehicle stores it (PARAM_VALUE carries float32)."""
    return float(np.float32(value))


def same_float32(a: float, b: float) -> bool:
    """True if ``a`` and ``b`` are the same value once stored as float32."""
    return np.float32(a) == np.float32(b)


class VehicleLink:
    """One MAVLink connection to one vehicle.

    ``answer_timeout_s`` is how long an answer to one request (PARAM_SET, PARAM_REQUEST_READ)
    is waited for before asking again.

    Parameters
    ----------
    connection : str
        Any pymavlink connection string ("udp:127.0.0.1:14550", "tcp:...", "/dev/ttyACM0").
    timeout_s : float
        How long to wait for the first HEARTBEAT before giving up.
    record_to : path, optional
        Every received message is appended there as a .tlog record.
    baud : int
        Serial links only (ignored by network links, as in MAVProxy).
    """

    answer_timeout_s = 1.0

    def __init__(self, connection: str, timeout_s: float = 10.0,
                 record_to: str | Path | None = None, baud: int = DEFAULT_BAUD):
        from pymavlink import mavutil

        self.connection = connection
        self._mavutil = mavutil
        self.master = open_connection(connection, baud)
        self._tlog = None
        try:
            heartbeat = self.wait_heartbeat(timeout_s)
        except ApmcalError:
            self.master.close()
            raise
        if record_to:       # only once a vehicle answered: no empty log files on failure
            self._tlog = open(record_to, "wb")
            self._record(heartbeat)

    # -- receiving --------------------------------------------------------------------------
    def recv(self, types=None, timeout_s: float = 1.0):
        """Next message of ``types`` (or any), recorded to the tlog; None on timeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            msg = self.master.recv_match(blocking=True, timeout=min(remaining, 0.2))
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            self._record(msg)
            if types is None or msg.get_type() in types:
                return msg

    def _record(self, msg) -> None:
        if self._tlog is not None:
            # .tlog record: 8-byte big-endian time in µs since the Unix epoch, then the packet.
            self._tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + msg.get_msgbuf())

    def wait_heartbeat(self, timeout_s: float):
        """The first HEARTBEAT of an autopilot; sets the target system and component from it.

        Ground stations, gimbals and companion computers send HEARTBEAT too, with autopilot
        MAV_AUTOPILOT_INVALID: their parameters are not the vehicle's, so they are passed over.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self.recv({"HEARTBEAT"}, max(deadline - time.monotonic(), 0.0))
            if msg is None:
                raise ApmcalError(f"no autopilot HEARTBEAT within {timeout_s:g} s: is the "
                                  "vehicle connected?", self.connection)
            if msg.autopilot != MAV_AUTOPILOT_INVALID:
                break
        self.target_system = msg.get_srcSystem()
        self.target_component = msg.get_srcComponent()
        return msg

    # -- parameters -------------------------------------------------------------------------
    def fetch_params(self, timeout_s: float = 20.0, idle_s: float | None = None,
                     retries: int = 2, reads_per_index: int = 8) -> dict[str, float]:
        """All parameters: PARAM_REQUEST_LIST, then each lost index asked for by itself.

        PARAM_VALUE travels unacknowledged, so some may be lost: an unanswered list request is
        sent again (up to ``retries`` times), and each missing index is asked for with
        PARAM_REQUEST_READ (by param_index), each up to ``reads_per_index`` times (a link
        losing a quarter of its packets each way loses about half of these round trips).
        ``idle_s`` (default twice ``answer_timeout_s``) ends the wait for the list once nothing
        arrives for that long. The result is the backup and the correction to undo
        (ardupilot-facts.md "What the telemetry really carries"), so a set still incomplete
        then raises :class:`ApmcalError` rather than being returned partial.
        """
        idle_s = idle_s or 2 * self.answer_timeout_s
        got = _ParamList()
        deadline = time.monotonic() + timeout_s
        for _ in range(1 + retries):      # the request itself may be lost, or the vehicle busy
            self.master.mav.param_request_list_send(self.target_system, self.target_component)
            self._receive_params(got, deadline, idle_s)
            if got.params:
                break
        if not got.params:
            raise ApmcalError("vehicle sent no parameters (PARAM_REQUEST_LIST unanswered)",
                              self.connection)
        deadline = time.monotonic() + timeout_s
        for _ in range(reads_per_index):
            if not got.missing() or time.monotonic() >= deadline:
                break
            # an answer to a read comes within one round trip: no need to wait the list's idle_s
            self._request_missing(got, deadline, min(idle_s, self.answer_timeout_s))
        missing = got.missing()
        if missing:
            shown = ", ".join(map(str, missing[:20])) + (" ..." if len(missing) > 20 else "")
            raise ApmcalError(f"{len(missing)} of {got.count} parameters never arrived "
                              f"(param_index {shown}), even when asked for one by one; "
                              f"not working from a partial set: try again", self.connection)
        return got.params

    def _request_missing(self, got: "_ParamList", deadline: float, idle_s: float) -> None:
        """One PARAM_REQUEST_READ by index for every missing index, a batch at a time."""
        missing = got.missing()
        for i in range(0, len(missing), READS_IN_FLIGHT):
            batch = missing[i:i + READS_IN_FLIGHT]
            for index in batch:
                self.master.mav.param_request_read_send(self.target_system,
                                                        self.target_component, b"", index)
            self._receive_params(got, deadline, idle_s, until=set(batch))

    def _receive_params(self, got: "_ParamList", deadline: float, idle_s: float,
                        until: set[int] | None = None) -> None:
        """Take PARAM_VALUEs into ``got`` until the indices ``until`` (default: all) are in,
        nothing arrives for ``idle_s``, or ``deadline`` passes."""
        while (remaining := deadline - time.monotonic()) > 0:
            msg = self.recv({"PARAM_VALUE"}, min(idle_s, remaining))
            if msg is None:
                return
            if not self._from_target(msg):   # a gimbal's or companion's own parameter list
                continue
            got.add(msg)
            if got.complete() if until is None else until <= got.seen:
                return

    def _from_target(self, msg) -> bool:
        """True for a message from the vehicle's autopilot (the HEARTBEAT's system/component)."""
        return (msg.get_srcSystem() == self.target_system
                and msg.get_srcComponent() == self.target_component)

    def read_param(self, name: str, timeout_s: float | None = None, retries: int = 3,
                   expect: float | None = None) -> float | None:
        """One parameter by name (PARAM_REQUEST_READ); None if the vehicle does not answer.

        With ``expect``, an answer of another value does not end the wait (it may be a stale
        echo of an earlier write, see :meth:`set_param`): the first answer equal to ``expect``
        at float32 is returned, else the last value the vehicle reported.
        """
        timeout_s = timeout_s or self.answer_timeout_s
        reported = None
        for _ in range(retries):
            self.master.mav.param_request_read_send(self.target_system, self.target_component,
                                                    name.encode(), -1)
            value = self._await_param(name, timeout_s, expect)
            if value is not None:
                reported = value
                if expect is None or same_float32(value, expect):
                    return value
        return reported

    def set_param(self, name: str, value: float, timeout_s: float | None = None,
                  attempts: int = 3) -> float | None:
        """PARAM_SET as REAL32, confirmed: returns ``value`` as float32 once the vehicle reports
        holding it; otherwise the last value it reported for ``name``, None when it stayed silent.

        ardupilot-facts.md "Writing parameters": the vehicle answers with PARAM_VALUE carrying
        the stored value, drops unknown names and NaN silently, and the ground station must
        compare the value itself. An answer is therefore matched by name AND value: a set of a
        vector's first element (_X) is answered with PARAM_VALUE for _X, _Y and _Z
        (ArduPilot's AP_Param::send_parameter; seen in issue 9 on ArduCopter 4.7.0-dev SITL),
        so the echo of an earlier write can arrive first carrying this name's old value. A
        different value keeps us listening until ``timeout_s``; a doubtful write (no matching
        echo) is checked by PARAM_REQUEST_READ and sent again, ``attempts`` times in all.
        """
        if not math.isfinite(value):
            raise ApmcalError(f"refusing to send non-finite value {value!r}", self.connection,
                              f"param {name}")
        timeout_s = timeout_s or self.answer_timeout_s
        wanted = float32(value)
        reported = None
        for _ in range(attempts):
            self.master.mav.param_set_send(self.target_system, self.target_component,
                                           name.encode(), wanted,
                                           self._mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            echoed = self._await_param(name, timeout_s, wanted)
            if echoed is not None and same_float32(echoed, wanted):
                return wanted
            # the set or its echo may be lost: ask what the vehicle holds before sending again
            held = self.read_param(name, timeout_s, retries=1, expect=wanted)
            if held is not None and same_float32(held, wanted):
                return wanted
            reported = next((v for v in (held, echoed) if v is not None), reported)
        return reported

    def _await_param(self, name: str, timeout_s: float,
                     expect: float | None = None) -> float | None:
        """The first value of a PARAM_VALUE for ``name`` from the autopilot within ``timeout_s``
        (the first equal to ``expect`` at float32, when given; else the last one seen); None
        when none arrives."""
        seen = None
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            msg = self.recv({"PARAM_VALUE"}, remaining)
            if msg is None or _param_name(msg) != name or not self._from_target(msg):
                continue
            seen = float(msg.param_value)
            if expect is None or same_float32(seen, expect):
                return seen
        return seen

    # -- IMU streaming ----------------------------------------------------------------------
    def request_imu_stream(self, rate_hz: int) -> None:
        """Ask for RAW_SENSORS at ``rate_hz`` both ways (old firmware and MAVLink 2 intervals)."""
        mav, mavlink = self.master.mav, self._mavutil.mavlink
        mav.request_data_stream_send(self.target_system, self.target_component,
                                     mavlink.MAV_DATA_STREAM_RAW_SENSORS, int(rate_hz), 1)
        for msg_id in STREAMED_MESSAGE_IDS.values():
            mav.command_long_send(self.target_system, self.target_component,
                                  mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                  msg_id, 1e6 / rate_hz, 0, 0, 0, 0, 0)

    def collect(self, duration_s: float, progress=None) -> int:
        """Receive (and record) for ``duration_s``; returns the number of IMU messages seen."""
        n_imu = 0
        end = time.monotonic() + duration_s
        while (now := time.monotonic()) < end:
            msg = self.recv(None, min(1.0, end - now))
            if msg is not None and msg.get_type() in IMU_MESSAGE_IDS:
                n_imu += 1
            if progress is not None:
                progress(min(duration_s, duration_s - (end - time.monotonic())))
        return n_imu

    def close(self) -> None:
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None
        self.master.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_connection(connection: str, baud: int = DEFAULT_BAUD):
    """pymavlink's connection for ``connection``, or ApmcalError saying why not.

    pymavlink prints its tcp retries ("[Errno 111] Connection refused sleeping") on stdout, where
    the report goes: they are swallowed, and a refusal after TCP_ATTEMPTS ends in one error.
    """
    from pymavlink import mavutil

    if Path(connection).is_file():
        # pymavlink would read a file as a log (and hang at its end) or run it as a program
        raise ApmcalError("a file, not a connection (a serial port, udp:, tcp:): to calibrate "
                          f"a log use `apmcal log {connection}`", connection)
    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter):
            return mavutil.mavlink_connection(connection, baud=int(baud), source_system=255,
                                              source_component=190, autoreconnect=False,
                                              retries=TCP_ATTEMPTS,
                                              reconnect_delay=TCP_RETRY_DELAY_S)
    except ModuleNotFoundError as exc:      # pyserial is a dependency, but may be missing
        raise ApmcalError(f"cannot open connection: serial links need the {exc.name} module "
                          f"(pip install pyserial)", connection) from None
    except ConnectionRefusedError:
        raise ApmcalError(f"cannot open connection: refused {TCP_ATTEMPTS} times, "
                          f"{TCP_RETRY_DELAY_S:g} s apart: is the vehicle (SITL, MAVProxy's "
                          "output) listening there?", connection) from None
    except Exception as exc:  # pymavlink raises many types for a bad connection string
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise ApmcalError(f"cannot open connection ({why})", connection) from None


class _ParamList:
    """The PARAM_VALUEs received so far: values by name, and which of the indices
    0..param_count-1 have arrived."""

    def __init__(self):
        self.params: dict[str, float] = {}
        self.seen: set[int] = set()
        self.count: int | None = None

    def add(self, msg) -> None:
        self.params[_param_name(msg)] = float(msg.param_value)
        self.count = msg.param_count
        if 0 <= msg.param_index < msg.param_count:   # 65535: an answer not from the list
            self.seen.add(msg.param_index)

    def complete(self) -> bool:
        return self.count is not None and len(self.seen) >= self.count

    def missing(self) -> list[int]:
        return [] if self.count is None else sorted(set(range(self.count)) - self.seen)


def _param_name(msg) -> str:
    name = msg.param_id
    if isinstance(name, bytes):
        name = name.decode("ascii", "replace")
    return name.rstrip("\x00")
