"""The network endpoint: paces a :class:`SimVehicle` against the wall clock and exchanges
MAVLink with a ground station over any pymavlink connection string.

On a loaded machine the simulated clock slows down instead of catching up in a burst (as
ArduPilot's SITL does in lock-step): a burst of thousands of UDP messages would overflow the
ground station's receive buffer, and a turn asked for would start late in simulated time.
"""
from __future__ import annotations

import collections
import time

from pymavlink import mavutil

from sitl.logwriter import TlogWriter
from sitl.vehicle import SimVehicle


class MavlinkVehicle:
    """Serve ``vehicle`` on ``connection`` (e.g. "udpout:127.0.0.1:14550", "udpin:0.0.0.0:14550",
    "tcpin:0.0.0.0:5760").

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
        self.step_s = float(step_s)      # simulated seconds per step (messages sent after each)
        self.conn = mavutil.mavlink_connection(connection, source_system=1, source_component=1)
        self.tlog = TlogWriter(tlog) if tlog else None
        self._wall0 = None
        self._sim0 = vehicle.t
        self._calls: collections.deque = collections.deque()

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
        self.conn.close()
        if self.tlog:
            self.tlog.close()
