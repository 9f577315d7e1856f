"""The MAVLink parameter protocol: the whole list, one by name, and writes confirmed by the
value the vehicle reports back (ardupilot-facts.md "Writing parameters").

A lossy link (a telemetry radio) loses PARAM_VALUEs, PARAM_REQUEST_READs and PARAM_SETs. The
missing parameters of the list are asked for by index, a window of requests in flight at a time,
each asked again when its answer is later than the measured round trip allows
(:class:`RoundTrips`, RFC 6298's smoothed round trip); the share of round trips lost sizes how
often a request or a write is tried (:func:`attempts_for`).
"""
from __future__ import annotations

import collections
import math
import time

import numpy as np

from apmcal.core.errors import ApmcalError

# PARAM_REQUEST_READs in flight at once: ArduPilot queues at most 20 pending requests and drops
# the others (ardupilot-facts.md "Writing parameters", GCS_MAVLINK::param_requests); a few
# places are left for the requests of other ground stations
READS_IN_FLIGHT = 16
# a request (or write) is tried until the chance that every try was lost is below this
NEVER_CONFIRMED_P = 1e-6
MIN_READS_PER_INDEX = 8     # requests per missing index at least, by default
MAX_ATTEMPTS = 40           # however bad the link: a dead one must end in an error, not a hang
MIN_ANSWER_WAIT_S = 0.05    # shortest wait for an answer, even on a loopback link [s]
# the reads by index are allowed this long per request expected (with the loss seen) [s], times
# the answer wait, on top of ``timeout_s``: the budget grows with the parameters missing
READ_BUDGET_FACTOR = 3.0
# the list's losses count as this many round trips in the first estimate of the loss
LIST_PRIOR_WEIGHT = 50
# the loss of the last this many round trips counts too (when worse): a radio that starts
# losing packets after the download is believed at once, not after the clean record fades
RECENT_TRIPS = 20
MIN_RECENT_TRIPS = 5
# the list may take ``timeout_s`` or this long per parameter, whichever is longer [s] (a
# 57,600 baud radio carries a few hundred PARAM_VALUEs a second, less beside other streams)
LIST_S_PER_PARAM = 0.03


def float32(value: float) -> float:
    """``value`` as the vehicle stores it (PARAM_VALUE carries float32)."""
    return float(np.float32(value))


def same_float32(a: float, b: float) -> bool:
    """True if ``a`` and ``b`` are the same value once stored as float32."""
    return np.float32(a) == np.float32(b)


def attempts_for(loss: float, minimum: int = 1, target: float = NEVER_CONFIRMED_P) -> int:
    """Tries needed so that all of them fail with probability below ``target`` when each fails
    with probability ``loss`` (independently): ceil(log target / log loss), at least
    ``minimum``, at most MAX_ATTEMPTS.

    Examples: 25 % lost each way (a round trip lost 44 % of the time) → 17; 1 % → 4.
    """
    if loss <= 0.0:
        return max(minimum, 1)
    if loss >= 1.0:
        return MAX_ATTEMPTS
    return int(min(MAX_ATTEMPTS, max(minimum, math.ceil(math.log(target) / math.log(loss)))))


class RoundTrips:
    """What the link's round trips (a request and its answer) have shown: the smoothed round
    trip and its variation (RFC 6298 §2, the TCP retransmission timer; a re-sent request's
    answer is not timed, Karn's rule), how many were answered or lost, and the last
    RECENT_TRIPS of them."""

    def __init__(self):
        self.srtt_s: float | None = None
        self.rttvar_s = 0.0
        self.answered = 0
        self.lost = 0
        self.recent: collections.deque = collections.deque(maxlen=RECENT_TRIPS)  # True: lost

    def answer(self, rtt_s: float | None) -> None:
        """A request answered, after ``rtt_s`` [s] (None: a re-sent one, not timed)."""
        self.answered += 1
        self.recent.append(False)
        if rtt_s is None:
            return
        if self.srtt_s is None:
            self.srtt_s, self.rttvar_s = rtt_s, rtt_s / 2
        else:
            self.rttvar_s = 0.75 * self.rttvar_s + 0.25 * abs(self.srtt_s - rtt_s)
            self.srtt_s = 0.875 * self.srtt_s + 0.125 * rtt_s

    def lose(self) -> None:
        """A request never answered within the wait."""
        self.lost += 1
        self.recent.append(True)

    def wait_s(self, cap_s: float) -> float:
        """How long to wait for an answer [s]: srtt + 4·rttvar, within [MIN_ANSWER_WAIT_S,
        ``cap_s``]; ``cap_s`` until a round trip has been timed."""
        if self.srtt_s is None:
            return cap_s
        return min(cap_s, max(MIN_ANSWER_WAIT_S, self.srtt_s + 4 * self.rttvar_s))

    def loss(self) -> float:
        """The share of round trips lost, estimated on the side of caution: (lost + 1) /
        (tried + 2) (Laplace's rule: one half before any is seen, never 0), over all of them
        or over the recent ones (at least MIN_RECENT_TRIPS), whichever is worse."""
        overall = (self.lost + 1) / (self.answered + self.lost + 2)
        if len(self.recent) < MIN_RECENT_TRIPS:
            return overall
        return max(overall, (sum(self.recent) + 1) / (len(self.recent) + 2))


class ParamProtocol:
    """Parameter reads and writes over a :class:`~apmcal.link.connection.Connection` (a mixin:
    it uses the connection's ``master``, ``recv``, ``_from_target``, ``target_system`` and
    ``target_component``).

    ``answer_timeout_s`` is the longest wait for an answer to one request (PARAM_SET,
    PARAM_REQUEST_READ) before asking again [s]; once round trips have been timed the wait is
    what they show (:meth:`RoundTrips.wait_s`), never longer.
    """

    answer_timeout_s = 1.0

    @property
    def round_trips(self) -> RoundTrips:
        """This link's round-trip record (created at first use)."""
        trips = self.__dict__.get("_round_trips")
        if trips is None:
            trips = self.__dict__["_round_trips"] = RoundTrips()
        return trips

    def answer_wait_s(self) -> float:
        """How long to wait for one answer now [s] (see :class:`RoundTrips`)."""
        return self.round_trips.wait_s(self.answer_timeout_s)

    def attempts(self, minimum: int = 3) -> int:
        """Tries per request or write that the loss seen so far calls for
        (:func:`attempts_for`), at least ``minimum``."""
        return attempts_for(self.round_trips.loss(), minimum)

    def downlink_loss(self) -> float:
        """The share of the vehicle's packets lost on the way here, from the gaps in their
        MAVLink sequence numbers (pymavlink's ``mav_loss`` / ``mav_count``), on the side of
        caution as :meth:`RoundTrips.loss` (one half before anything is seen)."""
        lost = int(getattr(self.master, "mav_loss", 0) or 0)
        count = int(getattr(self.master, "mav_count", 0) or 0)
        return (lost + 1) / (count + lost + 2)

    def fetch_params(self, timeout_s: float = 20.0, idle_s: float | None = None,
                     retries: int | None = None, reads_per_index: int | None = None
                     ) -> dict[str, float]:
        """All parameters: PARAM_REQUEST_LIST, then each lost index asked for by itself.

        PARAM_VALUE travels unacknowledged, so some may be lost: an unanswered list request is
        sent again (up to ``retries`` times; by default as often as the loss seen on the
        vehicle's packets calls for, :meth:`downlink_loss`, the way up assumed as lossy), and
        the missing indices are asked for with
        PARAM_REQUEST_READ (by param_index), READS_IN_FLIGHT at a time, each asked again when
        its answer is later than the round trips measured allow, ``reads_per_index`` times
        (default: as often as the loss seen calls for, :meth:`attempts`). ``idle_s`` (default twice
        ``answer_timeout_s``) ends the wait for the list once nothing arrives for that long.
        The reads may take ``timeout_s`` plus a budget that grows with the number missing and
        the loss. The result is the backup and the correction to undo (ardupilot-facts.md "What
        the telemetry really carries"), so a set still incomplete then raises
        :class:`ApmcalError` rather than being returned partial.

        Parameters
        ----------
        timeout_s : float, optional
            Time allowed for the list (more for a long list), and the least allowed for the
            reads by index [s].
        idle_s : float, optional
            Silence [s] that ends the wait for the list.
        retries : int, optional
            List requests sent again when unanswered (default: by the loss seen, at least 2).
        reads_per_index : int, optional
            PARAM_REQUEST_READs sent per missing index at most (default: by the loss seen, at
            least MIN_READS_PER_INDEX).

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
        started, sent = time.monotonic(), 0
        while True:          # the request itself may be lost, or the vehicle busy
            self.master.mav.param_request_list_send(self.target_system, self.target_component)
            sent += 1
            self._receive_params(got, max(started + timeout_s, time.monotonic() + idle_s),
                                 idle_s)
            allowed = (1 + retries if retries is not None
                       else attempts_for(self.downlink_loss(), minimum=3))
            if got.params or sent >= allowed:
                break
        if not got.params:
            raise ApmcalError("vehicle sent no parameters (PARAM_REQUEST_LIST unanswered)",
                              self.connection)
        self._note_list_losses(got)
        self._read_missing(got, timeout_s, reads_per_index)
        missing = got.missing()
        if missing:
            shown = ", ".join(map(str, missing[:20])) + (" ..." if len(missing) > 20 else "")
            raise ApmcalError(f"{len(missing)} of {got.count} parameters never arrived "
                              f"(param_index {shown}), even when asked for one by one; "
                              f"not working from a partial set: try again", self.connection)
        return got.params

    def _note_list_losses(self, got: "_ParamList") -> None:
        """The list's own losses as the first estimate of the round-trip loss, when nothing was
        timed yet: a PARAM_VALUE lost with probability l, a round trip (request and answer,
        assumed lost alike) is lost 1 − (1 − l)² of the time; weighed as LIST_PRIOR_WEIGHT
        round trips, so that the link's own round trips soon outweigh it."""
        trips = self.round_trips
        if trips.answered + trips.lost or not got.count:
            return
        lost_down = len(got.missing()) / got.count
        trips.lost = round(LIST_PRIOR_WEIGHT * (1 - (1 - lost_down) ** 2))
        trips.answered = LIST_PRIOR_WEIGHT - trips.lost

    def _read_missing(self, got: "_ParamList", timeout_s: float,
                      attempts: int | None) -> None:
        """PARAM_REQUEST_READ by index for every missing index, pipelined: READS_IN_FLIGHT
        requests out at a time, each re-sent once its wait (:meth:`answer_wait_s`) passes,
        until every index is in, each has had ``attempts`` requests (default
        :meth:`attempts`, at least MIN_READS_PER_INDEX), or the budget is spent."""
        missing = got.missing()
        if not missing:
            return
        trips = self.round_trips
        expected_tries = 1 / max(1 - trips.loss(), 1 / MAX_ATTEMPTS)
        budget_s = (len(missing) * expected_tries * self.answer_timeout_s * READ_BUDGET_FACTOR
                    / READS_IN_FLIGHT)
        deadline = time.monotonic() + timeout_s + budget_s
        waiting = collections.deque(missing)
        tries: dict[int, int] = collections.Counter()
        in_flight: dict[int, float] = {}          # index -> when last asked (monotonic)
        while (waiting or in_flight) and time.monotonic() < deadline:
            while waiting and len(in_flight) < READS_IN_FLIGHT:
                index = waiting.popleft()
                if index in got.seen:
                    continue
                self.master.mav.param_request_read_send(self.target_system,
                                                        self.target_component, b"", index)
                tries[index] += 1
                in_flight[index] = time.monotonic()
            wait_s = self.answer_wait_s()
            until = min(min(in_flight.values()) + wait_s, deadline) if in_flight else deadline
            msg = self.recv({"PARAM_VALUE"}, max(until - time.monotonic(), 0.0))
            now = time.monotonic()
            if msg is not None and self._from_target(msg):
                got.add(msg)
                sent = in_flight.pop(msg.param_index, None)
                if sent is not None:
                    trips.answer(now - sent if tries[msg.param_index] == 1 else None)
            for index, sent in list(in_flight.items()):
                if index in got.seen:             # came with the list, or a late answer
                    del in_flight[index]
                elif now - sent >= wait_s:
                    del in_flight[index]
                    trips.lose()
                    if tries[index] < (attempts or self.attempts(MIN_READS_PER_INDEX)):
                        waiting.append(index)

    def _receive_params(self, got: "_ParamList", deadline: float, idle_s: float) -> None:
        """Take PARAM_VALUEs into ``got`` until all are in, nothing arrives for ``idle_s``, or
        ``deadline`` passes (moved later for a long list: LIST_S_PER_PARAM each)."""
        start = time.monotonic()
        while (remaining := max(deadline, start + (got.count or 0) * LIST_S_PER_PARAM)
               - time.monotonic()) > 0:
            msg = self.recv({"PARAM_VALUE"}, min(idle_s, remaining))
            if msg is None:
                return
            if not self._from_target(msg):   # a gimbal's or companion's own parameter list
                continue
            got.add(msg)
            if got.complete():
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
            Wait per request [s] (default :meth:`answer_wait_s`).
        retries : int, optional
            Requests sent.
        expect : float, optional
            The value hoped for.
        """
        reported = None
        for attempt in range(retries):
            wait_s = timeout_s or self.answer_wait_s()
            sent = time.monotonic()
            self.master.mav.param_request_read_send(self.target_system, self.target_component,
                                                    name.encode(), -1)
            value, answered = self._await_param(name, wait_s, expect)
            self._note_round_trip(answered, sent, attempt)
            if value is not None:
                reported = value
                if expect is None or same_float32(value, expect):
                    return value
        return reported

    def set_param(self, name: str, value: float, timeout_s: float | None = None,
                  attempts: int | None = None) -> float | None:
        """PARAM_SET as REAL32, confirmed: returns ``value`` as float32 once the vehicle reports
        holding it; otherwise the last value it reported for ``name``, None when it stayed silent.

        ardupilot-facts.md "Writing parameters": the vehicle answers with PARAM_VALUE carrying
        the stored value, drops unknown names and NaN silently, and the ground station must
        compare the value itself. An answer is therefore matched by name AND value: a set of a
        vector's first element (_X) is answered with PARAM_VALUE for _X, _Y and _Z
        (ArduPilot's AP_Param::send_parameter; seen on an ArduCopter 4.7.0-dev SITL),
        so the echo of an earlier write can arrive first carrying this name's old value. A
        different value keeps us listening until ``timeout_s``; a doubtful write (no matching
        echo) is checked by PARAM_REQUEST_READ and sent again, ``attempts`` times in all (by
        default as many as the loss seen on this link calls for, :meth:`attempts`).

        Parameters
        ----------
        name : str
        value : float
            Finite.
        timeout_s : float, optional
            Wait per request [s] (default :meth:`answer_wait_s`).
        attempts : int, optional
            PARAM_SETs sent at most (default :meth:`attempts`).

        Raises
        ------
        ApmcalError
            A non-finite ``value`` (nothing is sent).
        """
        if not math.isfinite(value):
            raise ApmcalError(f"refusing to send non-finite value {value!r}", self.connection,
                              f"param {name}")
        wanted = float32(value)
        reported = None
        attempt = 0
        while attempt < (attempts or self.attempts()):   # the loss seen may grow meanwhile
            wait_s = timeout_s or self.answer_wait_s()
            sent = time.monotonic()
            self.master.mav.param_set_send(self.target_system, self.target_component,
                                           name.encode(), wanted,
                                           self._mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            echoed, answered = self._await_param(name, wait_s, wanted)
            self._note_round_trip(answered, sent, attempt)
            attempt += 1
            if echoed is not None and same_float32(echoed, wanted):
                return wanted
            # the set or its echo may be lost: ask what the vehicle holds before sending again
            held = self.read_param(name, timeout_s, retries=1, expect=wanted)
            if held is not None and same_float32(held, wanted):
                return wanted
            reported = next((v for v in (held, echoed) if v is not None), reported)
        return reported

    def _note_round_trip(self, answered: float | None, sent: float, attempt: int) -> None:
        """Record one request's round trip: answered at monotonic time ``answered`` (timed only
        for a first attempt, Karn's rule), or lost (None)."""
        if answered is None:
            self.round_trips.lose()
        else:
            self.round_trips.answer(answered - sent if attempt == 0 else None)

    def _await_param(self, name: str, timeout_s: float, expect: float | None = None
                     ) -> tuple[float | None, float | None]:
        """(value, when) of the first PARAM_VALUE for ``name`` from the autopilot within
        ``timeout_s`` (the first equal to ``expect`` at float32, when given; else the last one
        seen), ``when`` its monotonic arrival time; (None, None) when none arrives."""
        seen = when = None
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            msg = self.recv({"PARAM_VALUE"}, remaining)
            if msg is None or _param_name(msg) != name or not self._from_target(msg):
                continue
            seen, when = float(msg.param_value), time.monotonic()
            if expect is None or same_float32(seen, expect):
                return seen, when
        return seen, when


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
