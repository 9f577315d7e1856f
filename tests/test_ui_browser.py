"""`apmcal ui` in a real browser: headless Chromium driven by Selenium on the page of the
command run as a user runs it.

The page is refused without its token (and to foreign Host and Origin headers); a log chosen on
the page gives the verdict and the very parameter files `apmcal log --param-file` writes; the
guided calibration runs end to end against the bundled simulator, posed as the page asks, and
against ArduPilot's own firmware (SITL); the result is uploaded and undone; bad input gets a
message on the page. Screenshots of every screen go into the folder tests/ui_browser.py names.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from ui_browser import Page, UiServer, browser_missing, chromium, element_shot, get

from apmcal.ardupilot.paramfile import read_param_file
from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
FERRARIS = ROOT / "logs" / "ferraris.tlog"

pytestmark = pytest.mark.skipif(browser_missing() is not None, reason=browser_missing() or "")


@pytest.fixture
def ui(tmp_path):
    server = UiServer(tmp_path)
    yield server
    server.stop()


@pytest.fixture
def page(request, tmp_path, ui):
    (tmp_path / "downloads").mkdir()
    driver = chromium(tmp_path / "profile", tmp_path / "downloads")
    p = Page(driver, request.node.name)
    p.downloads = tmp_path / "downloads"
    try:
        driver.get(ui.url)
        p.wait(lambda: p.visible("#tab-logs"), "the page")
        yield p
    finally:
        driver.quit()


# -- the token ---------------------------------------------------------------------------------
def test_the_browser_is_refused_without_the_token_and_let_in_with_it(ui, tmp_path):
    driver = chromium(tmp_path / "profile", tmp_path)
    p = Page(driver, "token")
    try:
        driver.get(ui.base + "/")
        assert "needs its access token" in driver.find_element("tag name", "body").text
        p.screenshot("without-token")
        driver.get(ui.url)
        p.wait(lambda: p.visible("#drop"), "the logs tab")
        assert "token=" not in driver.current_url       # the address bar forgets it
        driver.get(ui.base + "/")                        # the cookie lets the page in again
        p.wait(lambda: p.visible("#drop"), "the page again")
        p.screenshot("with-token")
    finally:
        driver.quit()


# -- logs --------------------------------------------------------------------------------------
def cli_params(tmp_path, fmt: str) -> dict:
    return read_param_file(cli_param_file(tmp_path, fmt))


def cli_param_file(tmp_path, fmt: str) -> Path:
    out = tmp_path / f"cli.{fmt}"
    args = ["log", str(FERRARIS), "--param-file", str(out), "--quiet"]
    assert main(args + (["--param-format", "qgc"] if fmt == "qgc" else [])) == 0
    return out


def same_file_but_its_title(a: Path, b: Path) -> bool:
    """The same lines, the first comment (it names the file as each was given) aside."""
    return a.read_text().splitlines()[1:] == b.read_text().splitlines()[1:]


def downloaded(p: Page, name: str) -> Path:
    path = p.downloads / name
    p.wait(lambda: path.exists() and not (p.downloads / f"{name}.crdownload").exists(),
           f"download of {name}", 30)
    return path


def test_a_log_chosen_on_the_page_gives_the_verdict_and_the_files_of_apmcal_log(page, tmp_path,
                                                                                 capsys):
    page.find("#files").send_keys(str(FERRARIS))
    page.wait(lambda: page.all(".entry .verdict-block"), "the verdict")
    page.screenshot("verdict")
    verdict = page.text(".entry .verdict-block")
    # the verdict the command line prints first, in the same words
    assert main(["log", str(FERRARIS)]) == 0
    first = capsys.readouterr().out.splitlines()[0]        # "verdict: USABLE (...)"
    assert verdict.startswith(first.split(" (")[0]), (verdict[:80], first)
    assert len(page.all(".entry figure img")) == 3         # accelerometer, compass, gyroscope
    stages = [li.text for li in page.all(".stages li")]
    assert stages and all(s.startswith("✓") for s in stages), stages
    # the downloads hold exactly what apmcal log --param-file writes, in both formats
    for suffix, fmt in ((".param", "param"), (".params", "qgc")):
        page.find(f".downloads a[href$='ferraris{suffix}']").click()
        assert same_file_but_its_title(downloaded(page, f"ferraris{suffix}"),
                                       cli_param_file(tmp_path, fmt))
    # the proposal table shows the same values beside those in force
    shown = {r.find_elements("tag name", "td")[0].text: float(r.find_elements("tag name", "td")[3].text)
             for r in page.all("table.params tr:not(.withheld)")[1:]}
    assert shown == pytest.approx(cli_params(tmp_path, "param"), rel=1e-5)


def test_a_flight_log_gets_the_compass_check_of_apmcal_log(page, tmp_path):
    from apmcal_sim import flight as simulated

    flight = tmp_path / "flight.bin"
    simulated.write_flight(flight, seed=1, orient_error=2)
    page.find("#files").send_keys(str(flight))
    page.wait(lambda: page.all("#logs-job .entry iframe.report"), "the flight's compass check")
    text, images = report_frame_text(page, "#logs-job .entry")
    assert "heading" in text and images >= 1
    cli = tmp_path / "cli.param"
    assert main(["log", str(flight), "--param-file", str(cli), "--quiet"]) == 0
    page.find(".downloads a[href$='flight.param']").click()
    assert read_param_file(downloaded(page, "flight.param")) == read_param_file(cli)
    assert "COMPASS_ORIENT" in read_param_file(cli)        # the wrong orientation found
    page.screenshot("flight")


def test_bad_files_get_a_message_on_the_page(page, ui, tmp_path):
    not_a_log = tmp_path / "holiday.jpg"
    not_a_log.write_bytes(b"\xff\xd8\xff\xe0" + bytes(range(256)) * 40)
    page.find("#files").send_keys(str(not_a_log))
    page.wait(lambda: page.all(".entry-error"), "the error of a file that is no log")
    error = page.text(".entry-error")
    assert error.startswith("holiday.jpg: ") and "\n" not in error, error
    page.screenshot("not-a-log")
    # a file beyond the limit: said at once, nothing sent
    huge = tmp_path / "huge.bin"
    with open(huge, "wb") as f:
        f.truncate(600 * 2**20)            # sparse: no disk used
    page.find("#files").send_keys(str(huge))
    page.wait(lambda: page.visible("#logs-error"), "the size limit")
    assert "at most 512 MB" in page.text("#logs-error")
    page.screenshot("too-large")
    # and the server says the same to a request that skips the page's check
    cookie = {"Cookie": f"apmcal_ui_{ui.port}={ui.token}"}
    status, text = get(ui, "/api/jobs", {**cookie, "Content-Length": str(600 * 2**20),
                                         "Content-Type": "multipart/form-data; boundary=x"},
                       data=b"", method="POST")
    assert status == 413 and "at most 512 MB" in text


# -- a live vehicle: the bundled simulator, posed as the page asks -------------------------------
@pytest.fixture
def sim(tmp_path):
    from sim_operator import ThreadedSim

    s = ThreadedSim(tmp_path)
    s.wait_for_boot()
    yield s
    s.close()


def connect(page: Page, connection: str) -> None:
    page.click("#tab-live")
    page.type("#connection", connection)
    page.click("#connect")
    page.wait(lambda: page.visible("#vehicle-card") and page.all(".in-force tr"), "connected")


def page_face(page: Page) -> str | None:
    """The pose the page asks for now (None: it asks for none)."""
    card = page.all("#guide-card")
    return card[0].get_attribute("data-face") if card and card[0].is_displayed() else None


def run_guided_session(page: Page, pose, tumble, hold_s: float = 3) -> None:
    """The page's six-face session and compass turn, the vehicle posed with ``pose(face)`` as
    the page asks, and turned with ``tumble()`` when the page asks for the compass."""
    page.type("#hold", f"{hold_s:g}")
    page.click("#start-session")
    asked, shot = None, set()
    while not page.visible("#compass-card"):
        face = page_face(page)
        if face and face != asked:       # asked again after a rejection: it is on its way
            asked = face
            if face == "left":             # asked for, beside the vehicle still level
                page.wait(lambda: "from the pose" in page.text("#pose-now-caption"),
                          "the drawings", 10)
                element_shot(page, "#guide-card", "guide-card")
            pose(face)
            if face in ("level", "back") and face not in shot:     # two of the six screens
                shot.add(face)
                page.wait(lambda face=face: "in the pose" in page.text("#pose-now-caption")
                          or page_face(page) != face, f"the drawing of the vehicle {face}", 60)
                if page_face(page) == face:           # not yet held and gone
                    page.screenshot(f"pose-{face}")
        assert not page.visible("#live-error"), page.text("#live-error")
        time.sleep(0.1)
    deadline = time.monotonic() + 180
    while "done" not in page.text("#compass-status"):
        assert time.monotonic() < deadline, page.text("#compass-status")
        tumble()
    page.screenshot("compass-done")
    page.click("#finish-turn")
    page.wait(lambda: page.all("#live-job .entry .verdict-block"), "the live verdict", 120)
    page.wait(lambda: page.visible("#upload"), "the upload button")
    page.screenshot("live-verdict")


def page_proposal(page: Page) -> dict[str, float]:
    """The values the page will write (those it withholds left out)."""
    return {r.find_elements("tag name", "td")[0].text: float(r.find_elements("tag name", "td")[3].text)
            for r in page.all("#live-job table.params tr:not(.withheld)")[1:]}


def test_guided_calibration_upload_and_undo_against_the_simulator(page, sim, ui, tmp_path):
    from apmcal.report.session import calibrate

    connect(page, sim.connection)
    page.screenshot("connected")
    before = {n: sim.vehicle.params[n] for n in ("INS_ACCOFFS_X", "INS_ACCSCAL_Z", "COMPASS_OFS_X")}

    def tumble():
        sim.act(lambda v: v.tumble(20))
        sim.wait(lambda v: v.motion_done(), "tumble", 120)

    run_guided_session(page, lambda face: sim.act(lambda v: v.goto_pose(face)), tumble)
    proposed = page_proposal(page)
    # the recording the page made, calibrated by the library: the page's proposal, and the
    # accelerometer the simulator was given (within 4σ, as apmcal live --guide achieves)
    recording, = (tmp_path / "apmcal-files").glob("apmcal-live-*.tlog")
    report = calibrate(recording, method="ferraris")
    assert proposed == pytest.approx(report.writable.values, rel=1e-5)
    acc = report.calibration.sensors["acc"]
    truth = np.asarray(sim.truth.to_dict()["acc"]["offset"])
    assert np.all(np.abs(acc.offset - truth) < 4 * np.asarray(acc.sigma["offset"]))
    assert {"INS_ACCOFFS_X", "COMPASS_OFS_X"} <= set(proposed)
    assert report.verdict["mag"].measured
    # upload, and the tab closed while it writes: the upload goes on to the end all the same
    first = page.d.current_window_handle
    page.d.switch_to.new_window("tab")
    second = page.d.current_window_handle
    page.d.get(ui.base + "/#live")
    page.d.switch_to.window(first)
    # the parameter list at a telemetry radio's pace (40 a simulated second, 3 s here), so the
    # tab is closed while the upload still writes: at the simulator's network pace the whole
    # upload can end before the page has shown it under way
    sim.act(lambda v: setattr(v, "param_list_rate_hz", 40.0))
    page.click("#upload")
    page.wait(lambda: "writing" in page.text("#upload-result"), "the upload under way")
    page.d.close()
    page.d.switch_to.window(second)
    page.wait(lambda: page.all(".upload-done"), "the upload, in the other tab", 120)
    page.screenshot("uploaded")
    # every proposed value now on the vehicle, and a backup of what was there
    for name, value in proposed.items():
        assert float(np.float32(sim.vehicle.params[name])) == pytest.approx(value, rel=1e-5), name
    backup, = (tmp_path / "apmcal-files").glob("apmcal-backup-*.param")
    assert {n: read_param_file(backup)[n] for n in before} == pytest.approx(before)
    # undo from this tab (the closed one drove the vehicle: this one takes over)
    page.click("#undo")
    page.wait(lambda: page.visible("#live-busy") or "Undone" in page.text(".upload-done"),
              "the undo or the other tab's message", 30)
    if page.visible("#live-busy"):
        page.click("#takeover")
    page.wait(lambda: "Undone" in page.text(".upload-done"), "the undo", 120)
    page.screenshot("undone")
    for name, value in before.items():
        assert sim.vehicle.params[name] == pytest.approx(value), name
    # a write the vehicle never confirms: every change put back, and said on the page
    handle = sim.vehicle.handle

    def deaf_to_one(msg):
        if msg.get_type() == "PARAM_SET" and msg.param_id == "COMPASS_OFS_Y":
            return
        handle(msg)
    sim.act(lambda v: setattr(v, "handle", deaf_to_one))
    page.click("#upload")
    page.wait(lambda: "rolled back" in page.text("#live-error"), "the roll-back", 120)
    assert "COMPASS_OFS_Y" in page.text("#live-error")
    page.screenshot("rolled-back")
    for name, value in before.items():
        assert sim.vehicle.params[name] == pytest.approx(value), name


def test_the_page_says_when_the_vehicle_is_not_there_stops_answering_or_is_driven_elsewhere(
        page, sim, ui):
    from sim_operator import free_udp_port

    page.click("#tab-live")
    # nothing at that address
    page.type("#connection", f"udp:127.0.0.1:{free_udp_port()}")
    page.click("#connect")
    page.wait(lambda: "no autopilot HEARTBEAT" in page.text("#live-error"), "the refusal", 30)
    page.screenshot("no-vehicle")
    connect(page, sim.connection)
    # a second tab of the same browser: told, and may take over
    first = page.d.current_window_handle
    page.d.switch_to.new_window("tab")
    page.d.get(ui.base + "/#live")
    page.wait(lambda: page.visible("#start-session"), "the second tab on the vehicle")
    page.click("#start-session")
    page.wait(lambda: page.visible("#live-busy"), "the other tab's message")
    assert "another tab" in page.text("#live-busy")
    page.screenshot("second-tab")
    page.click("#takeover")
    page.wait(lambda: page.visible("#guide-card"), "the session in the tab that took over")
    page.click("#stop-guide")
    page.wait(lambda: "stopped by the operator" in page.text("#live-error"), "the stop")
    page.d.switch_to.window(first)       # the first tab no longer drives it
    page.wait(lambda: page.visible("#start-session"), "the first tab")
    page.click("#start-session")
    page.wait(lambda: page.visible("#live-busy"), "the first tab told")
    # the vehicle stops answering
    sim.close()
    page.wait(lambda: "has not answered" in page.text("#silent"), "the silence", 30)
    page.screenshot("silent")


def test_a_serial_port_that_disappears_is_said_on_the_page(page, tmp_path):
    import re
    import subprocess
    import sys

    vehicle = subprocess.Popen([sys.executable, "-m", "apmcal_sim", "pty", "--script", "operator",
                                "--param-file", str(tmp_path / "sim.json")],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        port = re.search(r"serial port: (\S+)", vehicle.stdout.readline()).group(1)
        connect(page, port)
        vehicle.kill()                   # unplugged
        vehicle.wait(10)
        page.wait(lambda: "the link failed" in page.text("#live-error"), "the lost port", 30)
        page.wait(lambda: page.visible("#connect-card"), "the connect card again")
        page.screenshot("port-gone")
    finally:
        vehicle.kill()
        vehicle.wait(10)


# -- ArduPilot's own firmware: the page on SERIAL1, the test posing it through SERIAL0 ----------
SITL_FACES = {"level": (0, 0), "left": (-90, 0), "right": (90, 0), "nosedown": (0, -90),
              "noseup": (0, 90), "back": (180, 0)}        # (roll, pitch) [deg]
SITL_BIAS = {"SIM_ACC1_BIAS_X": 0.3, "SIM_ACC1_BIAS_Y": -0.2, "SIM_ACC1_BIAS_Z": 0.25}   # m/s²


@pytest.mark.ardupilot_sitl
def test_guided_calibration_upload_and_undo_against_ardupilot_sitl(page, ardupilot_sitl):
    sitl = ardupilot_sitl(speedup=10, boot_params=SITL_BIAS)
    connect(page, sitl.gcs_connection)
    page.screenshot("sitl-connected")
    axes = iter([(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1)] * 5)

    def tumble():
        sitl.spin(1.0, next(axes))
        sitl.run_for(7)

    run_guided_session(page, lambda face: sitl.pose(*SITL_FACES[face], 0, settle_s=0), tumble)
    sitl.halt()
    proposed = page_proposal(page)
    # the bias injected into the firmware's accelerometer is what the page proposes to undo it
    for axis in "XYZ":
        assert proposed[f"INS_ACCOFFS_{axis}"] == pytest.approx(SITL_BIAS[f"SIM_ACC1_BIAS_{axis}"],
                                                               abs=0.03)
    sitl.catch_up()
    before = {n: sitl.get_param(n) for n in proposed}
    page.click("#upload")
    page.wait(lambda: page.all(".upload-done"), "the upload to SITL", 180)
    page.screenshot("sitl-uploaded")
    sitl.catch_up()
    for name, value in proposed.items():         # read back from the firmware by the driver
        assert sitl.get_param(name) == pytest.approx(value, rel=1e-5, abs=1e-6), name
    page.click("#undo")
    page.wait(lambda: "Undone" in page.text(".upload-done"), "the undo on SITL", 180)
    sitl.catch_up()
    for name, value in before.items():
        assert sitl.get_param(name) == pytest.approx(value, rel=1e-6, abs=1e-7), name


def test_a_newcomer_starts_the_simulated_vehicle_from_the_page_and_turns_it(page, ui):
    """No terminal: the page starts the bundled simulator, connects to it, and its buttons
    turn it as the session asks (the first two poses here; the whole session is the test
    above). Ctrl-C then stops the simulator and closes the link."""
    page.click("#tab-live")
    page.click("#sim-start")
    page.wait(lambda: page.visible("#vehicle-card") and page.visible("#sim-card"), "connected", 60)
    page.type("#hold", "3")
    page.click("#start-session")
    for face, button in (("level", "level"), ("left", "left")):
        page.wait(lambda face=face: page_face(page) == face, f"the page asking for {face}", 60)
        page.find(f"#sim-moves button[data-move='{button}']").click()
        page.wait(lambda face=face: page_face(page) != face, f"{face} recorded", 60)
    page.screenshot("simulated-vehicle")
    assert "pose 2 of 6 (on its LEFT side) recorded" in page.text("#messages")
    simulator, = [p for p in children(ui.process.pid) if "apmcal_sim" in p[1]]
    assert ui.interrupt() == 0
    assert "Traceback" not in ui.text()
    assert not Path(f"/proc/{simulator[0]}").exists(), "the simulated vehicle outlived apmcal ui"


def children(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of the processes ``pid`` started."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            out.append((int(stat.parent.name), cmdline))
    return out


# -- tcal, gap and the fleet -------------------------------------------------------------------
def report_frame_text(page: Page, entry_css: str) -> tuple[str, int]:
    """The text of an entry's report page (its iframe) and how many figures it shows."""
    frame = page.find(f"{entry_css} iframe.report")
    page.d.switch_to.frame(frame)
    try:
        page.wait(lambda: page.all("body h1") or page.all("body h2"), "the report page")
        return page.text("body"), len(page.all("img"))
    finally:
        page.d.switch_to.default_content()


def test_tcal_and_gap_give_their_verdicts_figures_and_files(page, tmp_path):
    page.find("input[name=kind][value=tcal]").click()
    page.find("#files").send_keys(str(ROOT / "logs" / "warmup.bin"))
    page.wait(lambda: page.all(".entry ul.tcal"), "the temperature calibration")
    assert "proposed" in page.text(".entry ul.tcal")
    text, images = report_frame_text(page, ".entry")
    assert "temperature calibration" in text and images >= 1
    page.screenshot("tcal")
    page.find(".downloads a[href$='warmup-tcal.param']").click()
    cli = tmp_path / "cli-tcal.param"
    assert main(["tcal", str(ROOT / "logs" / "warmup.bin"), "--param-file", str(cli),
                 "--quiet"]) == 0
    assert read_param_file(downloaded(page, "warmup-tcal.param")) == read_param_file(cli)
    page.find("input[name=kind][value=gap]").click()
    page.find("#files").send_keys(str(ROOT / "logs" / "gap.bin"))
    page.wait(lambda: page.all(".entry p.verdict"), "the gap diagnosis", 300)
    verdict = page.text(".entry p.verdict")
    assert verdict.startswith(("Modelling", "No candidate effect")), verdict
    text, images = report_frame_text(page, ".entry")
    assert "gap report" in text and images >= 2
    page.find(".downloads a[href$='gap-twin.parm']").click()
    assert read_param_file(downloaded(page, "gap-twin.parm"))
    page.screenshot("gap")


def test_a_fleet_folder_chosen_on_the_page_gives_the_flags_of_apmcal_fleet(page, tmp_path):
    from apmcal.fleet.run import run_fleet
    from apmcal_sim.fleet import write_fleet

    folder = tmp_path / "fleet"
    write_fleet(3, 3, folder, seed=3)
    expected = run_fleet([str(folder)], tmp_path / "serial-out", serial=True).flags
    page.click("#tab-fleet")
    page.wait(lambda: page.find("#folder").get_attribute("value"), "the folder browser")
    page.type("#folder", str(tmp_path))
    page.click("#folder-go")
    page.wait(lambda: page.all("#folder-list li[data-name='fleet']"), "the sub-folders")
    page.click("#folder-list li[data-name='fleet']")
    page.wait(lambda: page.find("#folder").get_attribute("value") == str(folder), "the fleet folder")
    page.screenshot("folder")
    page.click("#fleet-start")
    page.wait(lambda: page.all(".fleet-result"), "the fleet's result", 300)
    shown = [[td.text for td in row.find_elements("tag name", "td")]
             for row in page.all("table.flags tr")[1:]]
    assert shown == [[f.level, f.vehicle_id, f.reason, f.next_step]
                     for f in expected.itertuples()]
    assert any(row[0] == "action" for row in shown)
    text, _ = report_frame_text(page, ".fleet-result")
    assert "apmcal fleet" in text
    page.screenshot("fleet")
    # a folder that is not there: said on the page
    page.type("#folder", str(tmp_path / "no-such-folder"))
    page.click("#folder-go")
    page.wait(lambda: "no such folder" in page.text("#fleet-error"), "the missing folder")


def test_values_graded_redo_are_shown_and_not_written(page):
    """A real static log whose gyro offset is 39 °/s (graded REDO): the page shows the values
    and why they are withheld, and offers no file, as `apmcal log` writes none."""
    from conftest import shared_data_path

    data = shared_data_path()
    if data is None:
        pytest.skip("../shared/data absent: real recordings not available")
    page.find("#files").send_keys(str(data / "ardupilot" / "pxf_copter_static_51.BIN"))
    page.wait(lambda: page.all("#logs-job .entry .verdict-block"), "the verdict")
    withheld = [r.find_elements("tag name", "td")[0].text for r in page.all("table.params tr.withheld")]
    assert {"INS_GYROFFS_X", "INS_GYROFFS_Y", "INS_GYROFFS_Z"} <= set(withheld)
    assert "the gyroscope is graded REDO" in page.text(".proposal")
    assert not page.all(".downloads a")
    page.screenshot("withheld")
