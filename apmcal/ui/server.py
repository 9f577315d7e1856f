"""``apmcal ui`` running: the address with its token, the server on 127.0.0.1 (uvicorn), the
browser opened, and a clean stop on Ctrl-C.

Stopping closes the event streams at once, then the vehicle's link; a parameter upload under
way is never cut off — the stop waits for it to end (written and read back, or rolled back),
and says so. The files of the run (the logs dropped, their reports) are deleted; recordings
and backups stay in ``apmcal-files/``.
"""
from __future__ import annotations

import shutil
import socket
import tempfile
import threading
import time
import webbrowser
from pathlib import Path

from apmcal.core.errors import ApmcalError

HOST = "127.0.0.1"
DEFAULT_PORT = 8347
PORTS_TRIED = 20            # without --port: the first free one from DEFAULT_PORT on
FILES = "apmcal-files"      # as the command line's: recordings and backups


def bind(port: int | None) -> socket.socket:
    """A listening socket on 127.0.0.1: ``port``, or the first free one from
    :data:`DEFAULT_PORT` on (``port`` None).

    Raises
    ------
    ApmcalError
        When ``port`` is taken, or none of the ports tried is free.
    """
    tried = [port] if port is not None else range(DEFAULT_PORT, DEFAULT_PORT + PORTS_TRIED)
    for p in tried:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.bind((HOST, p))
        except OSError as exc:
            sock.close()
            if port is not None:
                raise ApmcalError(f"port {port} on {HOST} is not free ({exc.strerror or exc}): "
                                  "choose another with --port, or leave --port out") from None
            continue
        sock.listen(64)
        return sock
    raise ApmcalError(f"no free port from {DEFAULT_PORT} to {DEFAULT_PORT + PORTS_TRIED - 1} on "
                      f"{HOST}: choose one with --port")


def build(backend, token: str, port: int):
    """The application behind its token guard."""
    from apmcal.ui.app import create_app
    from apmcal.ui.security import TokenGuard

    return TokenGuard(create_app(backend), token, port)


def serve(port: int | None = None, open_browser: bool = True, say=print,
          files: str | Path = FILES, token: str | None = None, ready=None) -> int:
    """Run the interface until Ctrl-C (or ``ready``'s server is told to stop); exit status.

    Parameters
    ----------
    port : int, optional
        The port (default: the first free one from :data:`DEFAULT_PORT`).
    open_browser : bool
        Open the address in the default browser.
    say : callable
        Where the address and the stop are told (one str each).
    files : path
        Where recordings and backups go.
    token : str, optional
        The access token (default: a fresh random one).
    ready : callable, optional
        Called with (the address with its token, the uvicorn server) once it listens (tests).
    """
    import uvicorn

    from apmcal.ui.app import Backend
    from apmcal.ui.security import new_token

    sock = bind(port)
    port = sock.getsockname()[1]
    token = token or new_token()
    scratch = Path(tempfile.mkdtemp(prefix="apmcal-ui-"))
    backend = Backend(Path(files).resolve(), scratch, Path.cwd())
    try:
        url = f"http://{HOST}:{port}/?token={token}"
        config = uvicorn.Config(build(backend, token, port), log_level="warning",
                                lifespan="off", timeout_graceful_shutdown=3)
        server = make_server(config, backend)
        threading.Thread(target=announce, args=(server, url, open_browser, say, ready,
                                                backend.files), daemon=True).start()
        server.run(sockets=[sock])
    except KeyboardInterrupt:     # uvicorn hands the Ctrl-C on once it has stopped
        pass
    finally:
        stop(backend, say)
        sock.close()
        shutil.rmtree(scratch, ignore_errors=True)
    say("apmcal ui: stopped")
    return 0


def make_server(config, backend):
    """uvicorn's server, telling the application at once that it stops (so that the page's
    event streams end, instead of holding the stop up)."""
    import uvicorn

    class StoppingServer(uvicorn.Server):
        def handle_exit(self, sig, frame):
            backend.stopping = True
            super().handle_exit(sig, frame)

    return StoppingServer(config)


def announce(server, url: str, open_browser: bool, say, ready, files: Path) -> None:
    """Once the server answers (and Ctrl-C stops it cleanly): the address, where files go,
    the browser opened (or how to), ``ready`` told."""
    while not server.started:
        if server.should_exit:
            return
        time.sleep(0.05)
    say(f"apmcal ui: open {url} in your browser (Ctrl-C here stops it)")
    say(f"apmcal ui: recordings and parameter backups go into {files}")
    if ready is not None:
        ready(url, server)
    if open_browser and not webbrowser.open(url):
        say("apmcal ui: no browser could be opened here: open the address above yourself")


def stop(backend, say) -> None:
    """Close the vehicle's link and the simulated vehicle; an upload under way ends first,
    whatever the keyboard says."""
    if backend.vehicle.busy_writing():
        say("apmcal ui: parameters are being written: stopping once they are written and read "
            "back, or rolled back")
    done = threading.Thread(target=backend.close, daemon=True)
    done.start()
    while done.is_alive():
        try:
            done.join(0.5)
        except KeyboardInterrupt:
            if backend.vehicle.busy_writing():
                say("apmcal ui: still writing parameters: the vehicle is never left "
                    "half-written, a moment more")
            else:
                break
