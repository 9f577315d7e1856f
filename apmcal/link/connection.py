"""The MAVLink connection to one vehicle (pymavlink for the protocol only): opening it, the
autopilot's HEARTBEAT, receiving, and recording everything received to a telemetry log (.tlog,
the byte layout MAVProxy and Mission Planner write).
"""
from __future__ import annotations

import contextlib
import io
import socket
import struct
import time
from pathlib import Path

from apmcal.core.constants import DEFAULT_BAUD
from apmcal.core.errors import ApmcalError

MAV_AUTOPILOT_INVALID = 8       # HEARTBEAT.autopilot of anything that is not a flight controller

# tcp: a refused connection is tried this many times, this many seconds apart (pymavlink's
# mavtcp ``retries`` counts the attempts)
TCP_ATTEMPTS = 3
TCP_RETRY_DELAY_S = 1.0


class Connection:
    """One MAVLink connection to one vehicle's autopilot.

    Parameters
    ----------
    connection : str
        Any pymavlink connection string ("udp:127.0.0.1:14550", "tcp:...", "/dev/ttyACM0").
    timeout_s : float
        How long to wait for the first HEARTBEAT before giving up [s].
    record_to : path, optional
        Every received message is appended there as a .tlog record.
    baud : int
        Serial links only (ignored by network links, as in MAVProxy).
    announce : callable, optional
        Told (one str) that the heartbeat is awaited, and for how long, so that the wait is
        never a silent hang (the command line passes its console's print).
    on_message : callable, optional
        Called with every message received, whoever receives it (the browser interface
        draws the vehicle's pose from them while a calibration reads the link).
    """

    on_message = None       # (see above) a class default: links made without __init__ too

    def __init__(self, connection: str, timeout_s: float = 10.0,
                 record_to: str | Path | None = None, baud: int = DEFAULT_BAUD,
                 announce=None, on_message=None):
        from pymavlink import mavutil

        self.connection = connection
        self._mavutil = mavutil
        self.on_message = on_message
        self.master = open_connection(connection, baud)
        self._tlog = None
        if announce is not None:
            announce(f"waiting for a heartbeat from {connection} ({timeout_s:g} s) …")
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
        """Next message of ``types`` (or any), recorded to the tlog; None on timeout.

        Parameters
        ----------
        types : set of str, optional
            MAVLink message names; any message when None.
        timeout_s : float, optional
            How long to wait [s].
        """
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            msg = self.master.recv_match(blocking=True, timeout=min(remaining, 0.2))
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            self._record(msg)
            if self.on_message is not None:
                self.on_message(msg)
            if types is None or msg.get_type() in types:
                return msg

    def record_to(self, path: str | Path | None) -> None:
        """Record every message received from now on to ``path`` (a new .tlog; None: stop
        recording), the recording before closed: one file per session on one open link (a
        serial link reopened can reset the board).

        Raises
        ------
        OSError
            When ``path`` cannot be created (the recording before is closed all the same).
        """
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None
        if path is not None:
            self._tlog = open(path, "wb")

    def _record(self, msg) -> None:
        if self._tlog is not None:
            # .tlog record: 8-byte big-endian time in µs since the Unix epoch, then the packet.
            self._tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + msg.get_msgbuf())

    def wait_heartbeat(self, timeout_s: float):
        """The first HEARTBEAT of an autopilot; sets the target system and component from it.

        Ground stations, gimbals and companion computers send HEARTBEAT too, with autopilot
        MAV_AUTOPILOT_INVALID: their parameters are not the vehicle's, so they are passed over.

        Parameters
        ----------
        timeout_s : float
            How long to wait [s].

        Raises
        ------
        ApmcalError
            No autopilot HEARTBEAT within ``timeout_s``.
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

    def _from_target(self, msg) -> bool:
        """True for a message from the vehicle's autopilot (the HEARTBEAT's system/component)."""
        return (msg.get_srcSystem() == self.target_system
                and msg.get_srcComponent() == self.target_component)

    def close(self) -> None:
        """Close the tlog (when recording) and the link."""
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

    Parameters
    ----------
    connection : str
        A pymavlink connection string ("udp:...", "tcp:...", a serial port).
    baud : int, optional
        Serial links only.

    Raises
    ------
    ApmcalError
        A file given, a missing serial module, a refused tcp connection, or any other
        failure to open.
    """
    from pymavlink import mavutil

    if Path(connection).is_file():
        # pymavlink would read a file as a log (and hang at its end) or run it as a program
        raise ApmcalError("a file, not a connection (a serial port, udp:, tcp:): to calibrate "
                          f"a log use `apmcal log {connection}`", connection)
    check_host(connection)
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


NETWORK_PREFIXES = ("udp:", "udpin:", "udpout:", "udpbcast:", "tcp:", "tcpin:")


def check_host(connection: str) -> None:
    """An unresolvable host of a network connection ("udp:HOST:PORT", "tcp:HOST:PORT") said at
    once, instead of a wait for a heartbeat that cannot come.

    Raises
    ------
    ApmcalError
        When the host name does not resolve.
    """
    if not connection.lower().startswith(NETWORK_PREFIXES):
        return
    parts = connection.split(":")
    if len(parts) < 3 or not parts[1]:
        return                                   # pymavlink's own message says what is missing
    host = parts[1]
    try:
        socket.getaddrinfo(host, None)
    except (socket.gaierror, UnicodeError):
        raise ApmcalError(f"cannot resolve host {host!r}: check the name (or use its IP "
                          "address)", connection) from None
