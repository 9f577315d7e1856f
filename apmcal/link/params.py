"""The MAVLink parameter protocol: the whole list, one by name, and writes confirmed by the
value the vehicle reports back (ardupilot-facts.md "Writing parameters").
"""
from __future__ import annotations

import math
import time

import numpy as np

from apmcal.core.errors import ApmcalError

# PARAM_REQUEST_READs sent before waiting for their answers: a bounded batch, so that the
# vehicle's request queue (small on a flight controller) is not overrun
READS_IN_FLIGHT = 20


def float32(value: float) -> float:
    """``value`` as the vehicle stores it (PARAM_VALUE carries float32)."""
    return float(np.float32(value))


def same_float32(a: float, b: float) -> bool:
    """True if ``a`` and ``b`` are the same value once stored as float32."""
    return np.float32(a) == np.float32(b)


class ParamProtocol:
    """Parameter reads and writes over a :class:`~apmcal.link.connection.Connection` (a mixin:
    it uses the connection's ``master``, ``recv``, ``_from_target``, ``target_system`` and
    ``target_component``).

    ``answer_timeout_s`` is how long an answer to one request (PARAM_SET, PARAM_REQUEST_READ)
    is waited for before asking again [s].
    """

    answer_timeout_s = 1.0

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

        Parameters
        ----------
        timeout_s : float, optional
            Time allowed for the list, and again for the reads by index [s].
        idle_s : float, optional
            Silence [s] that ends the wait for the list.
        retries : int, optional
            List requests sent again when unanswered.
        reads_per_index : int, optional
            PARAM_REQUEST_READ rounds for the missing indices.

        Returns
        -------
        dict of str to float
            Every parameter by name.

        Raises
        ------
        ApmcalError
            No parameter at all, or some index still missing at the end.
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

    def read_param(self, name: str, timeout_s: float | None = None, retries: int = 3,
                   expect: float | None = None) -> float | None:
        """One parameter by name (PARAM_REQUEST_READ); None if the vehicle does not answer.

        With ``expect``, an answer of another value does not end the wait (it may be a stale
        echo of an earlier write, see :meth:`set_param`): the first answer equal to ``expect``
        at float32 is returned, else the last value the vehicle reported.

        Parameters
        ----------
        name : str
        timeout_s : float, optional
            Wait per request [s] (default ``answer_timeout_s``).
        retries : int, optional
            Requests sent.
        expect : float, optional
            The value hoped for.
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
        (ArduPilot's AP_Param::send_parameter; seen on an ArduCopter 4.7.0-dev SITL),
        so the echo of an earlier write can arrive first carrying this name's old value. A
        different value keeps us listening until ``timeout_s``; a doubtful write (no matching
        echo) is checked by PARAM_REQUEST_READ and sent again, ``attempts`` times in all.

        Parameters
        ----------
        name : str
        value : float
            Finite.
        timeout_s : float, optional
            Wait per request [s] (default ``answer_timeout_s``).
        attempts : int, optional
            PARAM_SETs sent at most.

        Raises
        ------
        ApmcalError
            A non-finite ``value`` (nothing is sent).
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
