"""The one live vehicle the page drives: connected, watched, calibrated, written and restored.

One thread (the vehicle's worker) alone uses the MAVLink link: it connects, then receives
(and so watches the vehicle) until the page asks for something, which it then does itself —
the guided six-face session of :mod:`apmcal.calibration.guided` (with the page as its
:class:`~apmcal.calibration.guided.Operator`), the compass turn
(:class:`~apmcal.ui.compass_turn.CompassTurn`), the upload and the undo of
:mod:`apmcal.link.upload`. Every message received, whoever receives it, also updates what the
page shows (the vehicle's pose from its accelerometer, the compass's directions): the link's
``on_message``.

What keeps the vehicle whole:

- the upload is :func:`~apmcal.link.upload.upload_params`: every parameter backed up to a file
  first, each write read back, every change put back when one is not confirmed; it runs here,
  not in the page, so a closed tab or a reload changes nothing of it, and stopping the server
  waits for it to end;
- the undo is :func:`~apmcal.link.upload.restore_params` from that backup, of the names the
  upload wrote; after an upload that failed half-way the same button puts the backup back;
- a recording's calibration parameters are fetched before and after it, and a session during
  which they changed is refused (as ``apmcal live`` does);
- one tab drives the vehicle at a time: another tab is told so, and may take over.
"""
from __future__ import annotations

import contextlib
import queue
import threading
import time
from pathlib import Path

from apmcal.core.errors import ApmcalError

RATE_HZ = 50                 # the IMU stream asked for [Hz], as apmcal live's default
QUIET_HZ = 2                 # ... while parameters are read or written: every answer heard
                             # at once, not behind a queue of IMU messages
SILENT_S = 3.0               # no message for this long [s]: the vehicle stopped answering
OWNER_GONE_S = 8.0           # a tab that has not looked for this long [s] no longer holds it
FACE_TIMEOUT_S = 300.0       # per pose [s wall]: time to read the page and walk over
COMPASS_TURN_MAX_S = 600.0   # the longest compass turn [s wall]
ACC_SMOOTHING = 0.2          # weight of a new accelerometer sample in the pose drawn
MESSAGES_KEPT = 40
# shortest hold [s]: the calibration's own hold finder wants 2 s of stillness (Options'
# min_still_s), and a hold of just that can come out too short for it when the turns between
# poses are quick
MIN_HOLD_S = 3.0


class VehicleBusy(ApmcalError):
    """Another tab drives the vehicle."""


class VehicleSession:
    """The page's vehicle: its state (a JSON-ready dict the page draws) and its worker.

    Parameters
    ----------
    files : Path
        Where recordings and backups go (kept after the server stops).
    jobs : apmcal.ui.jobs.Jobs
        Where the recording's calibration runs.
    """

    def __init__(self, files: Path, jobs):
        self.files = Path(files)
        self.jobs = jobs
        self._lock = threading.RLock()
        self.state: dict = {"status": "disconnected", "messages": [], "error": None}
        self.version = 0
        self.link = None
        self.worker: threading.Thread | None = None
        self.commands: queue.Queue = queue.Queue()
        self.stop_worker = threading.Event()
        self.stop_session = threading.Event()      # the page's Stop
        self.finish_turn = threading.Event()       # the page's Finish (compass turn)
        self.owner: str | None = None
        self.seen: dict[str, float] = {}           # tab → when it last looked [monotonic s]
        self.report = None                         # the session's SessionReport
        self.report_of: tuple = (None, None)       # ... of this vehicle (connection, system)
        self.restore: dict | None = None           # {"backup", "names", "sysid", "connection"}
        self._last_message = 0.0
        self._acc = None
        self._published_acc = 0.0
        self._mag_sink = None
        self._session_tlog: Path | None = None

    # -- what the page sees ----------------------------------------------------------------
    def snapshot(self) -> dict:
        """The state, with how long the vehicle has been silent (JSON-ready)."""
        with self._lock:
            out = dict(self.state)
            out["version"] = self.version
            out["owner"] = self.owner
            if out["status"] not in ("disconnected", "connecting"):
                age = time.monotonic() - self._last_message
                out["silent_s"] = round(age, 1) if age > SILENT_S else 0
            out["acc"] = None if self._acc is None else [round(float(a), 3) for a in self._acc]
            out["can_restore"] = self.restore is not None and self._restore_fits()
            return out

    def update(self, **fields) -> None:
        """Change the state the page sees."""
        with self._lock:
            self.state.update(fields)
            self.version += 1

    def say(self, text: str, level: str = "info") -> None:
        """Add a line to the messages the page lists."""
        with self._lock:
            messages = [*self.state["messages"], {"text": text, "level": level,
                                                   "t": time.strftime("%H:%M:%S")}]
            self.state["messages"] = messages[-MESSAGES_KEPT:]
            self.version += 1

    def note_silence(self) -> None:
        """Let the page know, second by second, that the vehicle has gone quiet (no message
        changes the state then)."""
        silent = int(time.monotonic() - self._last_message)
        if silent > SILENT_S and silent != getattr(self, "_silent_said", None):
            self._silent_said = silent
            with self._lock:
                self.version += 1

    def looked(self, tab: str) -> None:
        """Tab ``tab`` follows the state (its event stream is open)."""
        with self._lock:
            self.seen[tab] = time.monotonic()

    # -- which tab drives -------------------------------------------------------------------
    def claim(self, tab: str, take_over: bool = False) -> None:
        """Let ``tab`` drive the vehicle, unless another tab does (VehicleBusy)."""
        with self._lock:
            owner_alive = (self.owner is not None and self.owner != tab
                           and time.monotonic() - self.seen.get(self.owner, 0) < OWNER_GONE_S)
            if owner_alive and not take_over:
                raise VehicleBusy("another tab (or window) drives this vehicle: use that one, "
                                  "or press Take over here")
            if self.owner != tab:
                self.owner = tab
                self.version += 1

    # -- connecting -------------------------------------------------------------------------
    def connect(self, connection: str, baud: int) -> None:
        """Connect (on the worker thread: a heartbeat, every parameter, the IMU stream), then
        watch the vehicle until told otherwise."""
        connection = connection.strip()
        if not connection:
            raise ApmcalError("choose a port or type a connection (udp:127.0.0.1:14550)")
        with self._lock:
            if self.state["status"] != "disconnected":
                raise ApmcalError(f"already connected to {self.state.get('connection')}: "
                                  "disconnect first")
            self.stop_worker.clear()
            self.commands = queue.Queue()
            self.state.update(status="connecting", connection=connection, baud=baud,
                              error=None, vehicle=None, guide=None, compass=None, job=None,
                              upload=None)
            self.version += 1
            self.worker = threading.Thread(target=self._work, args=(connection, baud),
                                           name="apmcal-vehicle", daemon=True)
            self.worker.start()

    def disconnect(self) -> None:
        """Close the link once what runs is over (an upload always ends first)."""
        self.stop_session.set()
        self.stop_worker.set()

    def close(self, wait_s: float = 180.0) -> bool:
        """Stop the session and the worker and close the link (the server stops); True when the
        worker ended within ``wait_s`` (an upload under way finishes or rolls back first)."""
        self.disconnect()
        worker = self.worker
        if worker is None:
            return True
        worker.join(wait_s)
        return not worker.is_alive()

    def busy_writing(self) -> bool:
        """True while parameters are being written or restored."""
        return self.state["status"] in ("uploading", "restoring")

    def _work(self, connection: str, baud: int) -> None:
        try:
            self._open(connection, baud)
        except ApmcalError as err:
            self.update(status="disconnected", error=str(err))
            return
        except Exception as exc:        # pymavlink's many ways of refusing a port
            self.update(status="disconnected", error=f"{connection}: cannot connect "
                                                      f"({' '.join(str(exc).split()) or type(exc).__name__})")
            return
        try:
            self._watch()
        finally:
            link, self.link = self.link, None
            try:
                link.close()
            except Exception:       # a port already gone
                pass
            with self._lock:
                self.state.update(status="disconnected", guide=None, compass=None)
                self.version += 1

    def _open(self, connection: str, baud: int) -> None:
        from apmcal.ardupilot.firmware import firmware_generation
        from apmcal.ardupilot.names import is_correction_param
        from apmcal.sources.live import VehicleLink

        self.say(f"connecting to {connection} (waiting up to 10 s for its heartbeat)")
        self.firmware_text = None
        self.link = VehicleLink(connection, baud=baud, on_message=self._seen)
        self.say("connected; reading its parameters")
        with self._quiet():
            params = self.link.fetch_params()
        in_force = {k: v for k, v in sorted(params.items()) if is_correction_param(k)}
        self.update(status="idle", vehicle={
            "system": self.link.target_system, "type": self._vehicle_type,
            "firmware": self.firmware_text or "not said (no version banner received)",
            "generation": firmware_generation(params, self.firmware_text),
            "param_count": len(params), "in_force": in_force})
        self.say(f"{self._vehicle_type} (system {self.link.target_system}), "
                 f"{len(params)} parameters")

    _vehicle_type = "vehicle"

    def _seen(self, msg) -> None:
        """Every message received: the pose, the compass, the firmware banner, liveness."""
        self._last_message = time.monotonic()
        kind = msg.get_type()
        link = self.link
        target = getattr(link, "target_system", None) if link is not None else None
        if kind == "HEARTBEAT" and msg.autopilot != 8:          # 8: not an autopilot
            self._vehicle_type = vehicle_type_name(msg.type)
        elif kind == "STATUSTEXT":
            from apmcal.sources._common import parse_firmware

            found = parse_firmware(str(msg.text))
            if found and getattr(self, "firmware_text", None) is None:
                self.firmware_text = found[1]
        elif kind in ("RAW_IMU", "HIGHRES_IMU") and msg.get_srcSystem() == target:
            self._imu(msg, kind)

    def _imu(self, msg, kind: str) -> None:
        from apmcal.calibration.guided import imu_sample

        sample = imu_sample(msg)
        acc = sample.acc
        self._acc = acc if self._acc is None else self._acc + ACC_SMOOTHING * (acc - self._acc)
        now = time.monotonic()
        if now - self._published_acc > 0.1:      # the page redraws at 10 Hz at most
            self._published_acc = now
            with self._lock:
                self.version += 1
        sink = self._mag_sink
        if sink is not None and kind == "RAW_IMU":     # mGauss (HIGHRES_IMU's unit varies)
            sink((msg.xmag, msg.ymag, msg.zmag))

    def _watch(self) -> None:
        """Receive until told to stop, doing what the page asks in between."""
        while not self.stop_worker.is_set():
            try:
                command = self.commands.get_nowait()
            except queue.Empty:
                command = None
            if command is not None:
                self._do(*command)
                continue
            try:
                self.link.recv(None, 0.1)
                self.note_silence()
            except Exception as exc:         # the port is gone (unplugged), the socket closed
                self.update(error=f"{self.state['connection']}: the link failed ("
                                  f"{' '.join(str(exc).split()) or type(exc).__name__}): "
                                  "unplugged? Check the cable and connect again")
                return

    @contextlib.contextmanager
    def _quiet(self):
        """The IMU stream slowed to :data:`QUIET_HZ` while parameters are read or written,
        then back to :data:`RATE_HZ`."""
        self.link.request_imu_stream(QUIET_HZ)
        try:
            yield
        finally:
            self.link.request_imu_stream(RATE_HZ)

    def _do(self, name: str, work, status: str) -> None:
        """Run one of the page's requests on this thread; its failure becomes the page's
        error line."""
        self.update(status=status, error=None)
        try:
            work()
        except ApmcalError as err:
            self.update(error=str(err))
            self.say(str(err), "error")
        except Exception as exc:      # the link failed under the work
            why = " ".join(str(exc).split()) or type(exc).__name__
            self.update(error=f"{self.state['connection']}: {name} failed: the link failed "
                              f"({why}); connect again")
            self.say(self.state["error"], "error")
            self.stop_worker.set()
        finally:
            self._mag_sink = None
            with self._lock:       # done, unless its recording is being calibrated now
                if self.state["status"] != "calibrating":
                    self.state["status"] = "idle"
                self.version += 1

    def _queue(self, name: str, work, status: str) -> None:
        with self._lock:
            if self.state["status"] != "idle":
                raise ApmcalError(self._why_not_now())
            self.state["status"] = status       # taken now: a second click finds it busy
            self.version += 1
        self.commands.put((name, work, status))

    def _why_not_now(self) -> str:
        status = self.state["status"]
        return {"disconnected": "no vehicle connected: connect first",
                "connecting": "still connecting",
                "guide": "the six-face session is under way (Stop ends it)",
                "compass": "the compass turn is under way",
                "calibrating": "the session is being calibrated",
                "uploading": "parameters are being written",
                "restoring": "the backup is being restored"}.get(status, f"busy ({status})")

    # -- the calibration session --------------------------------------------------------------
    def start_session(self, faces: bool, compass: bool, hold_s: float, lat, lon) -> None:
        """Record a session (six faces, compass turn, or both), then calibrate it."""
        if not (faces or compass):
            raise ApmcalError("choose the accelerometer (six faces), the compass (turn), or both")
        if not MIN_HOLD_S <= hold_s <= 120:
            raise ApmcalError(f"hold {hold_s:g} s: choose {MIN_HOLD_S:g} to 120 s")
        self._queue("the session", lambda: self._session(faces, compass, hold_s, lat, lon),
                    "guide" if faces else "compass")

    def stop(self) -> None:
        """The page's Stop: the six-face session or the compass turn ends, nothing calibrated."""
        self.stop_session.set()

    def finish(self) -> None:
        """The page's Finish: the compass turn ends and the session is calibrated."""
        self.finish_turn.set()

    def _session(self, faces: bool, compass: bool, hold_s: float, lat, lon) -> None:
        from apmcal.ardupilot.names import changed_correction_params

        self.stop_session.clear()
        self.finish_turn.clear()
        self.report, self.report_of = None, self._this_vehicle()
        self.update(job=None, upload=None, guide=None, compass=None)

        stamp = time.strftime("%Y%m%d-%H%M%S")
        tlog = self.files / f"apmcal-live-{stamp}.tlog"
        self.files.mkdir(parents=True, exist_ok=True)
        self.link.record_to(tlog)
        try:
            self.say(f"recording to {tlog}")
            with self._quiet():
                before = self.link.fetch_params()       # in the recording: what corrected it
            if faces:
                self._six_faces(hold_s)
            if compass:
                self.update(status="compass")
                self._compass_turn()
            with self._quiet():
                after = self.link.fetch_params()
        finally:
            self.link.record_to(None)
        changed = changed_correction_params(before, after)
        if changed:
            raise ApmcalError("calibration parameters changed while recording ("
                              + ", ".join(changed) + "); wait for the vehicle to finish booting "
                              "and record again", self.link.connection)
        self._calibrate(tlog, "ferraris" if faces else "auto", lat, lon)

    def _six_faces(self, hold_s: float) -> None:
        from apmcal.calibration.guided import GuideOptions, record_six_faces

        record_six_faces(self.link, GuideOptions(hold_s, True, FACE_TIMEOUT_S), PageOperator(self))
        self.update(guide=None)

    def _compass_turn(self) -> None:
        from apmcal.calibration.guided import NO_DATA_TIMEOUT_S
        from apmcal.ui.compass_turn import CompassTurn

        turn = CompassTurn()
        self._mag_sink = turn.add
        self.say("turn the vehicle slowly through every direction: the sphere fills where "
                 "the compass has looked")
        started = last_look = time.monotonic()
        seen = 0
        while True:
            if self.stop_session.is_set() or self.stop_worker.is_set():
                raise ApmcalError("compass turn stopped; nothing calibrated")
            if self.finish_turn.is_set():
                break
            if time.monotonic() - started > COMPASS_TURN_MAX_S:
                raise ApmcalError(f"compass turn not finished within {COMPASS_TURN_MAX_S:g} s; "
                                  "nothing calibrated")
            self.link.recv(None, 0.1)
            self.note_silence()
            if time.monotonic() - last_look > 0.5:
                cover = turn.coverage()
                if cover["samples"] == seen and time.monotonic() - last_look > NO_DATA_TIMEOUT_S:
                    raise ApmcalError(f"no compass sample for {NO_DATA_TIMEOUT_S:g} s (link "
                                      "lost, or no compass in RAW_IMU); nothing calibrated")
                if cover["samples"] != seen:
                    seen, last_look = cover["samples"], time.monotonic()
                self.update(compass=cover)
        self._mag_sink = None
        self.say("compass turn finished" + ("" if self.state["compass"]["done"] else
                                            ": before enough directions were seen (the "
                                            "verdict will say so)"))

    def _calibrate(self, tlog: Path, method: str, lat, lon) -> None:
        """The recording calibrated as a job (progress, verdict, figures, downloads); its
        report kept for the upload once it is done."""
        from apmcal.ui.logs import stages_for

        job = self.jobs.start("live", tlog.name, stages_for("log", [tlog.name]),
                              calibrate_recording, (str(tlog), method, lat, lon),
                              on_done=self._calibrated)
        self.update(job=job.id, status="calibrating")
        self.say(f"recorded {tlog.name}; calibrating it")

    def _calibrated(self, job) -> None:
        with self._lock:
            if job.state == "done":
                self.report = job.extra
            if self.state["status"] == "calibrating":
                self.state["status"] = "idle"
            self.version += 1

    # -- upload and undo ------------------------------------------------------------------------
    def upload(self) -> None:
        """Write the session's proposal (backup first, read back, rolled back on failure)."""
        report = self.report
        if report is None or report.proposal is None:
            raise ApmcalError("nothing to upload: calibrate a session first")
        if self.report_of != self._this_vehicle():
            connection, system = self.report_of
            raise ApmcalError(f"this calibration is of the vehicle at {connection} (system "
                              f"{system}), not of the one connected now: connect to that one to "
                              "upload it, or calibrate this one")
        writable = report.writable         # none graded REDO, none out of the firmware's limits
        if not writable.values:
            raise ApmcalError("nothing to upload: every value proposed is withheld (" + "; ".join(
                f"{n}: {why}" for n, why in writable.withheld.items()) + ")")
        values = dict(writable.values)
        self._queue("the upload", lambda: self._upload(values), "uploading")

    def _upload(self, values: dict) -> None:
        from apmcal.link.upload import upload_params

        backup = self.files / f"apmcal-backup-{time.strftime('%Y%m%d-%H%M%S')}.param"
        self.files.mkdir(parents=True, exist_ok=True)
        self.update(upload=None)        # the last upload's outcome is not this one's
        self.say(f"backing up every parameter to {backup}, then writing {len(values)}")
        try:
            with self._quiet():
                result = upload_params(self.link, values, backup)
        except BaseException:
            if backup.exists():       # whatever happened, the backup can be put back
                self.restore = self._restore_point(backup, values)
            raise
        self.restore = self._restore_point(backup, values)
        rows = [[n, result.previous.get(n), v] for n, v in result.written.items()]
        self.update(upload={"backup": str(backup), "rows": rows, "undone": False})
        self.say(f"wrote and read back {len(rows)} parameters; backup in {backup}", "good")

    def _this_vehicle(self) -> tuple:
        """(connection, system id) of the vehicle connected now."""
        return self.state.get("connection"), (self.state.get("vehicle") or {}).get("system")

    def _restore_point(self, backup: Path, values: dict) -> dict:
        return {"backup": str(backup), "names": list(values),
                "connection": self.state.get("connection"),
                "sysid": getattr(self.link, "target_system", None)}

    def _restore_fits(self) -> bool:
        """The backup is this vehicle's: same connection, same system id."""
        r = self.restore
        return (r["connection"] == self.state.get("connection")
                and r["sysid"] == (self.state.get("vehicle") or {}).get("system"))

    def undo(self) -> None:
        """Put back the backup's values of the names the upload wrote."""
        if self.restore is None or not self._restore_fits():
            raise ApmcalError("nothing to undo on this vehicle: no upload was made to it here")
        self._queue("the undo", self._undo, "restoring")

    def _undo(self) -> None:
        from apmcal.link.upload import restore_params

        backup = self.restore["backup"]
        with self._quiet():
            result = restore_params(self.link, backup, names=self.restore["names"])
        self.say(f"restored {len(result.written)} parameters from {backup} "
                 f"({len(self.restore['names']) - len(result.written)} already held it)", "good")
        upload = dict(self.state.get("upload") or {"backup": backup, "rows": []})
        upload["undone"] = True
        self.update(upload=upload)
        self.restore = None


def calibrate_recording(job, tlog: str, method: str, lat, lon) -> dict:
    """A live session's recording calibrated (a job's work, in its own process): the page's
    entry, and the report for the upload (``"_extra"``)."""
    from apmcal.core.options import Options
    from apmcal.ui.logs import calibrate_contents, read_checked, report_entry

    name = Path(tlog).name
    contents = read_checked(job, name, Path(tlog))
    job.stage(f"calibrating {name}")
    report = calibrate_contents(contents, name, Options(method, lat, lon))
    job.stage(f"figures {name}")
    return {"kind": "live", "entries": [report_entry(job, 0, name, report, contents)],
            "_extra": report}


class PageOperator:
    """The person at the vehicle, seen through the page: the guided session's prompts become
    the page's state; its Stop is the abort key (the session waits for stillness itself)."""

    def __init__(self, session: VehicleSession):
        self.session = session

    def ask(self, request) -> None:
        """See :meth:`apmcal.calibration.guided.Operator.ask`."""
        from apmcal.calibration.guided import FACES

        face = request.face
        self.session.update(status="guide", guide={
            "index": request.index, "of": len(FACES), "face": face.name, "words": face.words,
            "attempt": request.attempt, "text": request.text, "held_s": 0,
            "gravity": face_specific_force(face.label),
            "done": [f.name for f in FACES[:request.index - 1]]})
        if request.attempt == 1:
            self.session.say(request.text)

    def tell(self, text: str) -> None:
        """See :meth:`apmcal.calibration.guided.Operator.tell`."""
        self.session.say(text, "warn" if text.startswith("rejected") or "moved" in text
                         else "info")

    def progress(self, text: str) -> None:
        """See :meth:`apmcal.calibration.guided.Operator.progress`: "N of H s held"."""
        import re

        guide = dict(self.session.state.get("guide") or {})
        m = re.search(r"(\d+) of ([\d.]+) s held", text)
        guide["held_s"] = int(m.group(1)) if m else guide.get("held_s", 0)
        guide["progress"] = text
        self.session.update(guide=guide)

    def answer(self, timeout_s: float) -> str | None:
        """The abort word once the page's Stop was pressed (or the server stops), else None
        (the session runs with ``auto``: it needs no key to go on)."""
        if self.session.stop_session.is_set() or self.session.stop_worker.is_set():
            return "q"
        self.session.note_silence()
        if timeout_s > 0:
            time.sleep(min(timeout_s, 0.05))
        return None


def face_specific_force(label: str) -> list[float]:
    """The specific force of a pose label ("x_p" … "z_a", :func:`apmcal.preprocessing.static.
    pose_of`), body frame, in units of g: "_p" reads +g on that axis (level, "z_a": (0, 0, −1))."""
    f = [0.0, 0.0, 0.0]
    f["xyz".index(label[0])] = 1.0 if label.endswith("_p") else -1.0
    return f


def vehicle_type_name(mav_type: int) -> str:
    """MAV_TYPE in words ("quadrotor", "ground rover")."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    entry = mavlink.enums["MAV_TYPE"].get(int(mav_type))
    name = entry.name.removeprefix("MAV_TYPE_") if entry is not None else f"type {mav_type}"
    return name.lower().replace("_", " ")
