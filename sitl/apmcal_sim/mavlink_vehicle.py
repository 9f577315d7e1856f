"""The network endpoint: paces a :class:`SimVehicle` against the wall clock and exchanges
MAVLink with a ground station over any pymavlink connection string.

On a loaded machine the simulated clock slows down instead of catching up in a burst (as
ArduPilot's SITL does in lock-step): a burst of thousands of UDP messages would overflow the
ground station's receive buffer, and a turn asked for would start late in simulated time.
"""
from __future__ import annotations

import collections
import os
import time
import tty

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from apmcal_sim.logwriter import TlogWriter
from apmcal_sim.vehicle import SimVehicle

PTY = "pty"        # the connection string for a pseudo-terminal: a simulated serial cable
# PARAM_VALUEs per simulated second of the parameter list on a network link: ArduPilot spends at
# most 30 % of a link's bandwidth on it (GCS_MAVLINK::queued_param_send); a burst of 1,349 at
# once would overflow a ground station's UDP receive buffer, which no real vehicle does
PARAM_LIST_RATE_HZ = 1000.0


class PtyLink:
    """The vehicle's end of a new pseudo-terminal pair: to the ground station, whose end is
    :attr:`device` (e.g. /dev/pts/5), it is a serial port, as a USB or telemetry-radio APM is.

    The ground station's end is put in raw mode (no echo, no line editing: MAVLink bytes pass
    unchanged) and kept open here, so that the link survives the station closing and reopening
    it (``apmcal live`` then ``apmcal restore``). Bytes sent while nobody reads are dropped when
    the pseudo-terminal's buffer is full, as a serial line drops them.
    """

    def __init__(self):
        self.master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        self.device = os.ttyname(self._slave_fd)
        os.set_blocking(self.master_fd, False)
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self._pending: list = []

    def write(self, buf: bytes) -> None:
        """Send bytes to the ground station (dropped when its buffer is full)."""
        try:
            os.write(self.master_fd, buf)
        except BlockingIOError:
            pass

    def recv_msg(self):
        """The next complete message from the ground station, or None."""
        if not self._pending:
            try:
                data = os.read(self.master_fd, 4096)
            except (BlockingIOError, OSError):
                data = b""
            self._pending = list(self._parser.parse_buffer(data) or [])
        return self._pending.pop(0) if self._pending else None

    def close(self) -> None:
        """Close both ends of the pseudo-terminal."""
        os.close(self.master_fd)
        os.close(self._slave_fd)


class MavlinkVehicle:
    """Serve ``vehicle`` on ``connection`` (e.g. "udpout:127.0.0.1:14550", "udpin:0.0.0.0:14550",
    "tcpin:0.0.0.0:5760", or "pty": a new pseudo-terminal, its device in ``conn.device``).

    Parameters
    ----------
    speedup : float
        Simulated seconds per wall-clock second (at most: a loaded machine slows it down).
    tlog : path, optional
        Also record everything sent and received to this .tlog.
    """

    def __init__(self, vehicle: SimVehicle, connection: str = "udpout:127.0.0.1:14550",
                 speedup: float = 1.0, tlog=None, step_s: float = 0.02):
        self.vehicle, self.speedup = vehicle, float(speedup)
        if vehicle.param_list_rate_hz is None:
            vehicle.param_list_rate_hz = PARAM_LIST_RATE_HZ
        self.step_s = float(step_s)      # simulated seconds per step (messages sent after each)
        self.conn = (PtyLink() if connection == PTY else
                     mavutil.mavlink_connection(connection, source_system=1, source_component=1))
        self.tlog = TlogWriter(tlog) if tlog else None
        self._wall0 = None
        self._sim0 = vehicle.t
        self._calls: collections.deque = collections.deque()
        #: called with the vehicle after every advance of its clock (a simulated person)
        self.on_poll: list = []

    # wall seconds of simulation one poll may catch up; beyond that the simulated clock lags
    MAX_CATCH_UP_S = 0.1

    def call_soon(self, fn) -> None:
        """Run ``fn(vehicle)`` in the serving loop at its next poll (thread-safe): how another
        thread (an operator, a test) acts on the vehicle while it is being served."""
        self._calls.append(fn)

    def poll(self) -> None:
        """Advance the vehicle to the current wall-clock time, send its messages, read input."""
        now = time.monotonic()
        if self._wall0 is None:
            self._wall0 = now
        target = self._sim0 + (now - self._wall0) * self.speedup
        v = self.vehicle
        cap = v.t + self.MAX_CATCH_UP_S * self.speedup
        if target > cap:             # fell behind: lag, do not burst
            self._sim0 -= target - cap
            target = cap
        while self._calls:
            self._calls.popleft()(v)
        while v.t < target - 0.5 / v.fs:
            v.step(min(self.step_s, target - v.t))
            for person in self.on_poll:
                person(v)
            self._flush()
        self._flush()
        while True:
            msg = self.conn.recv_msg()
            if msg is None:
                break
            if msg.get_type() == "BAD_DATA":
                continue
            if self.tlog:
                self.tlog.write(time.time(), msg.get_msgbuf())
            v.handle(msg)
        self._flush()

    def _flush(self) -> None:
        for _, msg in self.vehicle.pop_messages():
            buf = self.vehicle.encode(msg)
            self.conn.write(buf)
            if self.tlog:
                self.tlog.write(time.time(), buf)

    def serve(self, duration: float | None = None, tick_s: float = 0.005) -> None:
        """Run until ``duration`` simulated seconds have passed (forever when None)."""
        end = None if duration is None else self.vehicle.t + duration
        while end is None or self.vehicle.t < end:
            self.poll()
            time.sleep(tick_s)

    def close(self) -> None:
        """Close the connection and the .tlog."""
        self.conn.close()
        if self.tlog:
            self.tlog.close()
