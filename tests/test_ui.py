"""`apmcal ui` without a browser: the token, Host and Origin checks against requests as another
program or web page sends them, Ctrl-C, the web stack kept out of `apmcal --help`, and the
pieces the page draws from (the compass turn's coverage, the poses asked for)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from ui_browser import UiServer, get

from apmcal.calibration.guided import FACES, detect_face
from apmcal.core.constants import STANDARD_GRAVITY
from apmcal.ui.compass_turn import CompassTurn
from apmcal.ui.vehicle import face_specific_force


@pytest.fixture
def ui(tmp_path):
    server = UiServer(tmp_path)
    yield server
    server.stop()


def test_the_page_and_every_request_need_the_token(ui, tmp_path):
    cookie = {"Cookie": f"apmcal_ui_{ui.port}={ui.token}"}
    # without the token: refused, saying how to get in; nothing else answers either
    for path in ("/", "/api/info", "/api/vehicle", "/static/app.js"):
        status, text = get(ui, path)
        assert status == 403 and "access token" in text, (path, status, text)
    status, text = get(ui, "/api/vehicle/upload", data=b"{}", method="POST",
                       headers={"content-type": "application/json"})
    assert status == 403
    status, _ = get(ui, "/", {"Cookie": f"apmcal_ui_{ui.port}=wrong-{ui.token}"})
    assert status == 403
    # with it: the page, and the cookie after the first visit
    assert get(ui, "/api/info", cookie)[0] == 200
    # a foreign Host (DNS rebinding) or Origin (another web page) is refused even with it
    status, text = get(ui, "/api/info", {**cookie, "Host": f"attacker.example:{ui.port}"})
    assert status == 403 and "own address" in text
    status, text = get(ui, "/api/vehicle/connect", {**cookie, "Origin": "http://attacker.example",
                                                    "content-type": "application/json"},
                       data=json.dumps({"connection": "udp:127.0.0.1:9"}).encode(), method="POST")
    assert status == 403 and "other web pages" in text
    assert json.loads(get(ui, "/api/vehicle", cookie)[1])["status"] == "disconnected"




def test_ctrl_c_stops_it_cleanly(ui):
    assert ui.interrupt() == 0
    assert "apmcal ui: stopped" in ui.text()
    assert "Traceback" not in ui.text()




def test_the_command_line_loads_no_web_stack():
    code = ("import sys; from apmcal.cli import build_parser; build_parser(); "
            "print(sorted(m for m in ('starlette', 'uvicorn', 'multipart', 'apmcal.ui.app') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]", out


def test_a_taken_port_is_one_line(ui, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "apmcal", "ui", "--no-browser", "--port",
                           str(ui.port)], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and f"port {ui.port}" in proc.stderr


# -- what the page draws from ------------------------------------------------------------------
@pytest.mark.parametrize("face", FACES, ids=[f.name for f in FACES])
def test_the_pose_drawn_is_the_pose_the_session_asks_for(face):
    """The specific force the page draws for a face is the one the guided session accepts as
    that face."""
    seen, tilt, _ = detect_face(STANDARD_GRAVITY * np.array(face_specific_force(face.label)))
    assert seen == face and tilt == pytest.approx(0.0)


def field_samples(directions, offset=(120.0, -80.0, 40.0), field=500.0, seed=0):
    """Compass samples [mGauss]: a field of ``field`` in ``directions``, a hard-iron offset
    and 1 mGauss of noise."""
    rng = np.random.default_rng(seed)
    d = np.asarray(directions, float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return field * d + np.asarray(offset) + rng.normal(0, 1.0, d.shape)


def test_the_compass_turn_is_done_on_the_whole_sphere_only():
    rng = np.random.default_rng(1)
    turn = CompassTurn()
    assert not turn.coverage()["done"]                       # nothing yet
    # a turn about one axis: the directions lie in a plane, however many
    a = np.linspace(0, 2 * np.pi, 400)
    for s in field_samples(np.column_stack([np.cos(a), np.sin(a), 0.2 * np.ones_like(a)])):
        turn.add(s)
    flat = turn.coverage()
    assert not flat["done"] and flat["fraction"] < flat["need_fraction"]
    # then every direction: done, and the sphere's every point covered
    for s in field_samples(rng.standard_normal((3000, 3))):
        turn.add(s)
    whole = turn.coverage()
    assert whole["done"] and whole["missing"] == ""
    assert whole["covered"].count("1") / len(whole["covered"]) == pytest.approx(
        whole["fraction"]) and whole["fraction"] > 0.95


def test_the_compass_turn_counts_directions_from_the_fields_centre():
    """Seen from zero, samples around a large hard-iron offset would all point one way; seen
    from the fitted centre, a half sphere covers what a half sphere covers with 20° cones:
    (1 + sin 20°) / 2 of the sphere. Not done all the same: the fit refuses samples that flat
    for their size (its own check, with the reason)."""
    rng = np.random.default_rng(2)
    d = rng.standard_normal((4000, 3))
    d[:, 2] = np.abs(d[:, 2])                  # the upper half only
    turn = CompassTurn()
    for s in field_samples(d, offset=(900.0, 0.0, 0.0)):
        turn.add(s)
    cover = turn.coverage()
    assert cover["fraction"] == pytest.approx((1 + np.sin(np.radians(20))) / 2, abs=0.03)
    assert not cover["done"] and "flattest direction" in cover["missing"]


def test_no_compass_leaves_the_sphere_empty():
    turn = CompassTurn()
    for _ in range(100):
        turn.add((0, 0, 0))            # RAW_IMU of a vehicle without a compass
    assert turn.coverage()["samples"] == 0 and not turn.coverage()["done"]


# -- the vehicle kept whole ---------------------------------------------------------------------
def test_stopping_waits_for_an_upload_under_way_and_leaves_all_or_nothing(tmp_path):
    """The server's stop (Ctrl-C) closes the vehicle's session while an upload writes through a
    lossy link: it returns only once the upload has ended, and the vehicle then holds every
    new value or none of them (rolled back)."""
    import time
    from pathlib import Path

    from lossy_udp import vehicle_behind_lossy_link

    from apmcal.link.params import same_float32
    from apmcal.report.session import calibrate
    from apmcal.ui.jobs import Jobs
    from apmcal.ui.vehicle import VehicleSession

    report = calibrate(Path(__file__).resolve().parents[1] / "logs" / "ferraris.tlog")
    with vehicle_behind_lossy_link(0.2, 3, full_params=True) as (connection, served, _):
        session = VehicleSession(tmp_path / "files", Jobs(tmp_path / "jobs"))
        session.connect(connection, 115200)
        deadline = time.monotonic() + 120
        while session.state["status"] != "idle":
            assert session.state["status"] == "connecting", session.state["error"]
            assert time.monotonic() < deadline
            time.sleep(0.1)
        session.report, session.report_of = report, session._this_vehicle()
        values = report.proposal.values
        before = {n: served.params[n] for n in values}
        session.upload()
        while not served.sets:              # the backup is read; the first write is sent
            time.sleep(0.01)
        assert session.close(wait_s=300)
        assert not session.worker.is_alive() and session.state["status"] == "disconnected"
        after = {n: served.params[n] for n in values}
    written = all(same_float32(after[n], v) for n, v in values.items())
    untouched = all(same_float32(after[n], v) for n, v in before.items())
    assert written or untouched, after
    assert written == (session.state.get("upload") is not None)


def post_files(ui, kind: str, *paths) -> dict:
    """The page's drop, as a multipart POST: the job started."""
    boundary = "apmcal-test-boundary"
    parts = [f'--{boundary}\r\nContent-Disposition: form-data; name="kind"\r\n\r\n{kind}\r\n'.encode()]
    for path in paths:
        parts.append(f'--{boundary}\r\nContent-Disposition: form-data; name="files"; '
                     f'filename="{path.name}"\r\n\r\n'.encode() + path.read_bytes() + b"\r\n")
    data = b"".join(parts) + f"--{boundary}--\r\n".encode()
    status, text = get(ui, "/api/jobs", {"Cookie": f"apmcal_ui_{ui.port}={ui.token}",
                                         "Content-Type": f"multipart/form-data; boundary={boundary}"},
                       data=data, method="POST")
    assert status == 200, text
    return json.loads(text)


def descendants(pid: int) -> set[int]:
    from pathlib import Path

    parent = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        kids = {c for c, pp in parent.items() if pp == p}
        found |= kids
        todo += kids
    return found


def test_ctrl_c_during_a_diagnosis_ends_every_process_it_started(ui):
    import time
    from pathlib import Path

    job = post_files(ui, "gap", Path(__file__).resolve().parents[1] / "logs" / "gap.bin")
    cookie = {"Cookie": f"apmcal_ui_{ui.port}={ui.token}"}
    deadline = time.monotonic() + 120
    while True:
        state = json.loads(get(ui, f"/api/jobs/{job['id']}", cookie)[1])
        assert state["state"] in ("waiting", "running"), state
        if state["current"] >= 1:               # diagnosing
            break
        assert time.monotonic() < deadline
        time.sleep(0.2)
    started = descendants(ui.process.pid)
    assert any(b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes() for p in started)
    tracker = {p for p in started if b"resource_tracker" in Path(f"/proc/{p}/cmdline").read_bytes()}
    assert ui.interrupt() == 0
    alive = lambda: {p: Path(f"/proc/{p}/cmdline").read_bytes()[:80] for p in started
                     if Path(f"/proc/{p}").exists()}
    # the job's process and the workers it forked are gone when apmcal ui is; multiprocessing's
    # resource tracker, once it has read that they are
    assert set(alive()) <= tracker, f"processes outlived it: {alive()}"
    deadline = time.monotonic() + 10
    while alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(), f"processes outlived it: {alive()}"
    out = ui.text()
    assert out.rstrip().endswith("apmcal ui: stopped") and "Traceback" not in out, out
    assert all(line.startswith("apmcal ui:") for line in out.splitlines()), out
