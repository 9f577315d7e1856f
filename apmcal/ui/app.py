"""The web application: the page, and the requests it makes (Starlette).

Logs: ``POST /api/jobs`` (the files dropped, and what to do with them) starts a job;
``/api/jobs/ID/events`` follows it (server-sent events), ``/api/jobs/ID/files/...`` downloads a
parameter file, ``/api/jobs/ID/pages/...`` shows a report page. The vehicle: ``/api/ports``,
``/api/vehicle/...`` (connect, session, stop, finish, upload, undo, take over, disconnect) and
``/api/vehicle/events``; the simulated vehicle ``/api/simulator/...``; the fleet
``/api/folders`` and ``POST /api/fleet``. Every request has passed
:class:`~apmcal.ui.security.TokenGuard` first; every refusal of ours is a JSON
``{"error": "one line"}`` the page shows as it is.
"""
from __future__ import annotations

import asyncio
import json
import shutil
from pathlib import Path

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from apmcal.core.errors import ApmcalError
from apmcal.ui import fleet, logs, simulator
from apmcal.ui.jobs import Jobs
from apmcal.ui.vehicle import VehicleBusy, VehicleSession

STATIC = Path(__file__).parent / "static"
STATIC_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
                ".css": "text/css; charset=utf-8", ".png": "image/png", ".svg": "image/svg+xml"}
EVENT_TICK_S = 0.1          # how often an event stream looks for news [s]


class Backend:
    """What the requests act on: the jobs, the vehicle, the simulated vehicle, where files go.

    Parameters
    ----------
    files : Path
        Kept files: recordings, backups, fleet results (``apmcal-files``).
    scratch : Path
        Files of this run only: uploads, job outputs, the simulated vehicle's store.
    start : Path
        Where the folder browser starts.
    """

    def __init__(self, files: Path, scratch: Path, start: Path):
        self.files, self.scratch, self.start = Path(files), Path(scratch), Path(start)
        self.jobs = Jobs(self.scratch / "jobs")
        self.vehicle = VehicleSession(self.files, self.jobs)
        self.simulator: simulator.Simulator | None = None
        self.stopping = False
        self._uploads = 0

    def close(self) -> bool:
        """Stop the vehicle's session (an upload under way ends first) and the simulated
        vehicle; True when the vehicle's link closed in time."""
        self.stopping = True
        self.jobs.close()
        closed = self.vehicle.close()
        if self.simulator is not None:
            self.simulator.stop()
        return closed

    def upload_folder(self) -> Path:
        """A fresh folder for one drop's files."""
        self._uploads += 1
        folder = self.scratch / "uploads" / str(self._uploads)
        folder.mkdir(parents=True, exist_ok=True)
        return folder


def error(message: str, status: int = 400) -> JSONResponse:
    """A refusal the page shows as it is."""
    return JSONResponse({"error": message}, status_code=status)


def handled(endpoint):
    """``endpoint`` whose ApmcalError is a 400 (a VehicleBusy a 409) with its one line."""
    async def wrapper(request: Request):
        try:
            return await endpoint(request)
        except VehicleBusy as err:
            return error(str(err), 409)
        except ApmcalError as err:
            return error(str(err))
    wrapper.__name__ = endpoint.__name__
    return wrapper


async def body(request: Request) -> dict:
    """The request's JSON object (ApmcalError when it is none)."""
    try:
        data = await request.json()
    except (ValueError, UnicodeDecodeError):
        raise ApmcalError("the request is not JSON") from None
    if not isinstance(data, dict):
        raise ApmcalError("the request is not a JSON object")
    return data


def number(value, what: str, kind=float):
    """A number from the page ("" and None: None), or ApmcalError naming the field."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    try:
        out = kind(value)
    except (TypeError, ValueError):
        raise ApmcalError(f"{what}: {value!r} is not a number") from None
    if out != out or out in (float("inf"), float("-inf")):
        raise ApmcalError(f"{what}: {value!r} is not a number")
    return out


def create_app(backend: Backend) -> Starlette:
    """The Starlette application over ``backend`` (without the token guard: see
    :func:`apmcal.ui.server.build`)."""

    # -- the page ---------------------------------------------------------------------------
    async def page(request: Request):
        return static_file("index.html")

    async def static(request: Request):
        return static_file(request.path_params["name"])

    async def info(request: Request):
        return JSONResponse({"files": str(backend.files.resolve()),
                             "max_upload_bytes": logs.MAX_UPLOAD_BYTES,
                             "log_suffixes": list(logs.LOG_SUFFIXES),
                             "simulator": simulator.available(),
                             "simulator_moves": simulator.MOVES,
                             "start": str(backend.start.resolve())})

    # -- logs -------------------------------------------------------------------------------
    @handled
    async def start_job(request: Request):
        size = request.headers.get("content-length")
        if size is None:
            return error("the upload did not say its size", 411)
        if int(size) > logs.MAX_UPLOAD_BYTES:
            return error(f"the files are too large ({int(size) / 2**20:.0f} MB): at "
                         f"most {logs.MAX_UPLOAD_BYTES / 2**20:.0f} MB at a time", 413)
        form = await request.form(max_files=100, max_fields=20)
        try:
            kind = str(form.get("kind", "log"))
            if kind not in logs.KINDS:
                raise ApmcalError(f"unknown calculation {kind!r}")
            lat, lon = logs.check_site(number(form.get("lat"), "latitude"),
                                       number(form.get("lon"), "longitude"))
            files = await save_uploads(form.getlist("files"), backend.upload_folder())
        finally:
            await form.close()
        names = [name for name, _ in files]
        title = ", ".join(names)
        job = backend.jobs.start(kind, title, logs.stages_for(kind, names), logs.run_files,
                                 (kind, files, lat, lon))
        return JSONResponse(job.snapshot())

    async def job_state(request: Request):
        job = backend.jobs.get(request.path_params["job"])
        return error("no such job", 404) if job is None else JSONResponse(job.snapshot())

    async def job_events(request: Request):
        job = backend.jobs.get(request.path_params["job"])
        if job is None:
            return error("no such job", 404)
        return event_stream(job.snapshot, lambda snap: snap["state"] in ("done", "failed"))

    async def job_file(request: Request):
        job = backend.jobs.get(request.path_params["job"])
        key = f"{request.path_params['index']}/{request.path_params['name']}"
        if job is None or key not in job.files:
            return error("no such file", 404)
        path = job.files[key]
        return FileResponse(path, filename=path.name, media_type="text/plain; charset=utf-8",
                            content_disposition_type="attachment")

    async def job_page(request: Request):
        job = backend.jobs.get(request.path_params["job"])
        folder = None if job is None else job.pages.get(request.path_params["key"])
        if folder is None:
            return error("no such page", 404)
        path = (folder / request.path_params["path"]).resolve()
        if not path.is_relative_to(folder.resolve()) or not path.is_file():
            return error("no such page", 404)
        return FileResponse(path, media_type=STATIC_TYPES.get(path.suffix, "text/plain"))

    # -- the vehicle ------------------------------------------------------------------------
    v = backend.vehicle

    async def ports(request: Request):
        return JSONResponse(port_list())

    @handled
    async def connect(request: Request):
        data = await body(request)
        v.claim(str(data.get("tab")), bool(data.get("take_over")))
        v.connect(str(data.get("connection", "")), number(data.get("baud"), "baud", int)
                  or 115200)
        return JSONResponse(v.snapshot())

    def vehicle_action(act):
        @handled
        async def endpoint(request: Request):
            data = await body(request)
            v.claim(str(data.get("tab")), act == "take_over")
            if act == "session":
                lat, lon = logs.check_site(number(data.get("lat"), "latitude"),
                                           number(data.get("lon"), "longitude"))
                v.start_session(bool(data.get("faces")), bool(data.get("compass")),
                                number(data.get("hold_s"), "hold") or 10.0, lat, lon)
            elif act != "take_over":
                getattr(v, act)()
            return JSONResponse(v.snapshot())
        endpoint.__name__ = f"vehicle_{act}"
        return endpoint

    async def vehicle_state(request: Request):
        return JSONResponse(v.snapshot())

    async def vehicle_events(request: Request):
        tab = request.query_params.get("tab", "")

        def snap():
            v.looked(tab)
            return v.snapshot()
        return event_stream(snap, lambda s: False)

    # -- the simulated vehicle ---------------------------------------------------------------
    @handled
    async def simulator_start(request: Request):
        data = await body(request)
        v.claim(str(data.get("tab")))
        if backend.simulator is None or not backend.simulator.running():
            backend.simulator = simulator.Simulator(backend.scratch / "simulated-vehicle")
        return JSONResponse({"connection": backend.simulator.connection})

    @handled
    async def simulator_move(request: Request):
        data = await body(request)
        v.claim(str(data.get("tab")))
        if backend.simulator is None:
            raise ApmcalError("no simulated vehicle: start one first")
        backend.simulator.move(str(data.get("move")))
        return JSONResponse({"ok": True})

    @handled
    async def simulator_stop(request: Request):
        data = await body(request)
        v.claim(str(data.get("tab")))
        if backend.simulator is not None:
            backend.simulator.stop()
        return JSONResponse({"ok": True})

    # -- the fleet --------------------------------------------------------------------------
    @handled
    async def folders(request: Request):
        return JSONResponse(fleet.list_folder(request.query_params.get("path"), backend.start))

    @handled
    async def start_fleet(request: Request):
        data = await body(request)
        folder = str(data.get("folder") or "")
        if not folder:
            raise ApmcalError("choose a folder first")
        job = backend.jobs.start("fleet", folder, fleet.stages(), fleet.run,
                                 (folder, backend.files))
        return JSONResponse(job.snapshot())

    def event_stream(snapshot, finished) -> StreamingResponse:
        """Server-sent events: ``snapshot()`` whenever its version changes, until
        ``finished(snapshot)`` or the server stops."""
        async def stream():
            last = None
            while not backend.stopping:
                snap = snapshot()
                if snap["version"] != last:
                    last = snap["version"]
                    yield f"data: {json.dumps(snap)}\n\n"
                    if finished(snap):
                        return
                await asyncio.sleep(EVENT_TICK_S)
        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"cache-control": "no-store"})

    routes = [
        Route("/", page), Route("/static/{name}", static), Route("/api/info", info),
        Route("/api/jobs", start_job, methods=["POST"]),
        Route("/api/jobs/{job}", job_state), Route("/api/jobs/{job}/events", job_events),
        Route("/api/jobs/{job}/files/{index}/{name}", job_file),
        Route("/api/jobs/{job}/pages/{key}/{path:path}", job_page),
        Route("/api/ports", ports),
        Route("/api/vehicle", vehicle_state), Route("/api/vehicle/events", vehicle_events),
        Route("/api/vehicle/connect", connect, methods=["POST"]),
        *[Route(f"/api/vehicle/{act.replace('_', '')}", vehicle_action(act), methods=["POST"])
          for act in ("session", "stop", "finish", "upload", "undo", "disconnect",
                      "take_over")],
        Route("/api/simulator/start", simulator_start, methods=["POST"]),
        Route("/api/simulator/move", simulator_move, methods=["POST"]),
        Route("/api/simulator/stop", simulator_stop, methods=["POST"]),
        Route("/api/folders", folders), Route("/api/fleet", start_fleet, methods=["POST"]),
    ]
    return Starlette(routes=routes)


def static_file(name: str) -> Response:
    """One of the page's own files (never a path out of the static folder)."""
    path = (STATIC / name).resolve()
    if not path.is_relative_to(STATIC.resolve()) or not path.is_file():
        return error("no such file", 404)
    return FileResponse(path, media_type=STATIC_TYPES.get(path.suffix, "text/plain"))


async def save_uploads(uploads, folder: Path) -> list[tuple[str, Path]]:
    """The dropped files saved under their own names into ``folder``: (name, path) each.

    Raises
    ------
    ApmcalError
        When nothing was dropped, or a file is empty.
    """
    files = [u for u in uploads if hasattr(u, "filename")]
    if not files:
        raise ApmcalError("no file chosen: drop a log here, or choose one")
    out, used = [], set()
    for upload in files:
        name = logs.safe_name(upload.filename or "log")
        while name in used:
            name = f"_{name}"
        used.add(name)
        path = folder / name
        with open(path, "wb") as target:
            await asyncio.to_thread(shutil.copyfileobj, upload.file, target, 1 << 20)
        if path.stat().st_size == 0:
            raise ApmcalError("the file is empty", name)
        out.append((name, path))
    return out


def port_list() -> dict:
    """The serial ports with their descriptions (pyserial), and the network presets."""
    found = []
    try:
        from serial.tools import list_ports

        for p in sorted(list_ports.comports(), key=lambda p: p.device):
            words = p.description if p.description and p.description != "n/a" else ""
            found.append({"connection": p.device, "label": f"{p.device}"
                          + (f" — {words}" if words else ""), "serial": True})
    except ImportError:          # pyserial is a dependency; said rather than failing
        found.append({"connection": "", "label": "(serial ports unknown: pip install "
                                                 "pyserial)", "serial": True})
    presets = [
        {"connection": "udp:127.0.0.1:14550", "label": "UDP 14550 — SITL, MAVProxy's output, "
                                                       "the simulated vehicle", "serial": False},
        {"connection": "udpin:0.0.0.0:14550", "label": "UDP 14550 from the network — a WiFi "
                                                       "telemetry bridge", "serial": False},
        {"connection": "tcp:127.0.0.1:5760", "label": "TCP 5760 — ArduPilot SITL",
         "serial": False},
        {"connection": "tcp:127.0.0.1:5762", "label": "TCP 5762 — ArduPilot SITL's second "
                                                      "port", "serial": False},
    ]
    return {"ports": found + presets}
