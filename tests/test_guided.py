"""`apmcal live --guide ardupilot6`: each of ArduPilot's six poses prompted, waited for (Enter,
or with --auto the vehicle still in the pose), checked from gravity; a wrong or repeated pose
rejected and asked for again; no MAV_CMD_ACCELCAL_VEHICLE_POS sent.

The simulated vehicle runs in a thread of this process and a simulated operator turns it when
apmcal prompts, so the outcome does not depend on how fast the machine is.
"""
from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sim_operator import TILTED_45, SimOperator, ThreadedSim, arrival_times, pose_error_deg

from apmcal.calibration.guided import (
    FACES,
    GuideOptions,
    TerminalOperator,
    detect_face,
    record_six_faces,
)
from apmcal.cli import main
from apmcal.sources.live import VehicleLink
from apmcal_sim.motion import pose_matrix

ROOT = Path(__file__).resolve().parents[1]
G0 = 9.80665
ORDER = ["level", "left", "right", "nosedown", "noseup", "back"]


@pytest.fixture
def sim(tmp_path):
    s = ThreadedSim(tmp_path)
    s.wait_for_boot()
    yield s
    s.close()


def run_live(sim, tmp_path, operator, *extra):
    out = tmp_path / "guided.json"
    status = main(["live", sim.connection, "--guide", "ardupilot6", "--hold", "2",
                   "--rate", "50", "--quiet", "--face-timeout", "60",
                   "--save-log", str(tmp_path / "guided.tlog"), "--json", str(out), *extra],
                  operator=operator)
    return status, (json.loads(out.read_text()) if out.exists() else None)


def assert_accelerometer_as_injected(result, sim):
    assert result["method"] == "ferraris"
    offset = np.asarray(sim.truth.to_dict()["acc"]["offset"])
    err = np.abs(np.subtract(result["acc"]["offset"], offset))
    assert np.all(err < 4 * np.asarray(result["acc"]["sigma"]["offset"])), err


def accelcal_commands(sim) -> list:
    return [m for _, m in sim.vehicle.commands
            if m.command == mavlink.MAV_CMD_ACCELCAL_VEHICLE_POS]


# -- pose from gravity ----------------------------------------------------------------------
@pytest.mark.parametrize("face", ORDER)
def test_each_face_is_read_from_gravity(face):
    f = -pose_matrix(face).T @ np.array([0.0, 0.0, G0])       # specific force, body frame
    seen, tilt, _ = detect_face(f)
    assert seen is not None and seen.name == face and tilt < 1e-6


def test_a_pose_tilted_beyond_25_degrees_is_no_face():
    level = np.array([0.0, 0.0, -G0])
    tilt = lambda deg: np.array([np.sin(np.radians(deg)), 0, -np.cos(np.radians(deg))]) * G0
    assert detect_face(tilt(20))[0].name == "level"
    seen, angle, nearest = detect_face(tilt(35))
    assert seen is None and nearest.name == "level" and angle == pytest.approx(35)
    assert detect_face(level)[0] is FACES[0]


# -- against the simulated vehicle ------------------------------------------------------------
def test_six_good_poses_give_the_six_face_calibration_and_no_accelcal_command(sim, tmp_path):
    operator = SimOperator(sim)
    status, result = run_live(sim, tmp_path, operator)
    assert status == 0
    assert operator.asked() == list(enumerate(ORDER, 1))       # each pose asked for once
    assert operator.said("all six poses recorded")
    held = operator.said("s held")
    assert held and len(held) == len(set(held)), "a hold's progress line shown twice"
    assert_accelerometer_as_injected(result, sim)
    # the vehicle recorded what it received: the stream requests, and no accel-cal command
    received = {m.command for _, m in sim.vehicle.commands}
    assert mavlink.MAV_CMD_SET_MESSAGE_INTERVAL in received
    assert accelcal_commands(sim) == []


def test_six_poses_alone_do_not_measure_the_compass(tmp_path):
    """Six still poses, turned between at once (as a SITL attitude is set), the compass's
    readings whole mGauss and noise-free (as real SITL sends them), at a site whose field the
    six poses spread in all three axes (Canberra): six compass vectors cannot determine the
    compass's 9 unknowns. Nothing of it is proposed, the compass line says why and what to do,
    and the accelerometer's grade is not dragged down by it (before: an internal error)."""
    site = {"lat": -35.363, "lon": 149.165, "alt": 584.0, "year": 2026.0}
    sim = ThreadedSim(tmp_path, seed=1, site=site, effects_off=["mag_noise"])
    try:
        sim.wait_for_boot()
        # holds of 3 s: a 2 s hold (= --min-still) can come out just too short for the
        # calibration's own hold finder when the turns are instant
        status, result = run_live(sim, tmp_path, SimOperator(sim, move_s=0.05),
                                  "--lat", str(site["lat"]), "--lon", str(site["lon"]),
                                  "--hold", "3")
    finally:
        sim.close()
    assert status == 0
    assert_accelerometer_as_injected(result, sim)
    assert not [n for n in result["params"] if n.startswith("COMPASS_")]
    assert "mag" not in result
    verdict = result["verdict"]
    assert verdict["mag"]["grade"] == "not measured"
    assert "not measured by this session" not in verdict["mag"]["reason"]   # said once
    assert "turn the vehicle" in verdict["mag"]["reason"]
    assert verdict["acc"]["grade"] == "good"
    assert verdict["overall"]["grade"] != "redo"


def test_whole_mgauss_readings_are_quantization_not_outliers(tmp_path):
    """The same noise-free whole-mGauss compass, but the vehicle turned between the poses in
    3 s (the turns pass through many directions): the compass is determined, no reading is
    called an outlier (before: 13-16 % were, the MAD of exact readings being ~0), and the
    offsets are within their σ, which is not below the rounding's (1/√12 mGauss)."""
    site = {"lat": -35.363, "lon": 149.165, "alt": 584.0, "year": 2026.0}
    sim = ThreadedSim(tmp_path, seed=3, site=site, effects_off=["mag_noise"])
    sim.vehicle.whole_mgauss_compass = True
    try:
        sim.wait_for_boot()
        status, result = run_live(sim, tmp_path, SimOperator(sim),
                                  "--lat", str(site["lat"]), "--lon", str(site["lon"]))
    finally:
        sim.close()
    assert status == 0
    fit = result["report"]["ellipsoids"]["mag"]
    assert fit["outlier_fraction"] == 0.0, fit["notes"]
    sigma = np.asarray(result["mag"]["sigma"]["offset"])
    assert np.all(sigma >= 1 / np.sqrt(12) - 1e-9)
    err = np.subtract(result["mag"]["offset"], sim.truth.to_dict()["mag"]["offset"])
    assert np.all(np.abs(err) < 4 * sigma), (err, sigma)
    assert "COMPASS_OFS_X" in result["params"]


def test_a_wrong_pose_is_rejected_and_asked_for_again(sim, tmp_path):
    operator = SimOperator(sim, first={"left": ["right"]})
    status, result = run_live(sim, tmp_path, operator)
    assert status == 0
    assert operator.asked() == [(1, "level"), (2, "left"), (2, "left"), (3, "right"),
                                (4, "nosedown"), (5, "noseup"), (6, "back")]
    rejected = operator.said("rejected")
    assert rejected == ["rejected: the vehicle is on its RIGHT side, not on its LEFT side: "
                        "ArduPilot's order is level, LEFT, RIGHT, nose DOWN, nose UP, BACK; "
                        "place it on its LEFT side"]
    assert_accelerometer_as_injected(result, sim)


def test_a_repeated_pose_is_rejected(sim, tmp_path):
    operator = SimOperator(sim, first={"right": ["left"]})      # left again instead of right
    status, result = run_live(sim, tmp_path, operator)
    assert status == 0
    assert operator.asked().count((3, "right")) == 2
    assert operator.said("rejected") == [
        "rejected: the vehicle is on its LEFT side, pose 2 of 6, already recorded (a repeated "
        "pose): place it on its RIGHT side"]
    assert result["method"] == "ferraris"


def test_auto_waits_until_the_vehicle_is_still_in_the_pose(sim):
    """No key press: the hold starts only once the vehicle rests in the pose asked for (not
    on the way, not while it rocks), and a wrong pose is rejected and asked for again."""
    operator = SimOperator(sim, press_enter=False, first={
        "left": ["right"],                             # wrong: rejected after 3 s still
        "nosedown": [("via", TILTED_45, 2.0)],         # rests 2 s on the way: no face
        "noseup": [("wobble", 1.0)]})                  # rocks 1 s after arriving
    with VehicleLink(sim.connection) as link:
        link.request_imu_stream(50)
        result = record_six_faces(link, GuideOptions(hold_s=2.0, auto=True,
                                                     face_timeout_s=60.0), operator)
    v = sim.vehicle
    assert list(result.holds) == ORDER
    assert operator.asked().count((2, "left")) == 2
    assert len(operator.said("rejected")) == 1 and "RIGHT" in operator.said("rejected")[0]
    # the last half second of a turn moves less than 3°: it passes for still
    slack = 0.6
    assert result.holds["nosedown"].start >= arrival_times(v, "nosedown")[-1] - slack
    assert result.holds["nosedown"].start > arrival_times(v, "via")[-1] + 2.0
    assert result.holds["noseup"].start >= arrival_times(v, "noseup")[-1] - slack
    assert operator.said("moved") or result.holds["noseup"].start > arrival_times(v, "wobble")[0]
    for name, hold in result.holds.items():
        assert hold.seconds >= 2.0
        assert pose_error_deg(v, hold.acc_mean, name) < 5.0
    assert accelcal_commands(sim) == []


class ScriptedKeys(SimOperator):
    """Turns the vehicle as asked, but types ``line`` at pose ``at``."""

    def __init__(self, sim, at: int, line: str | None):
        super().__init__(sim)
        self.at, self.line = at, line

    def answer(self, timeout_s):
        if self.requests and self.requests[-1].index == self.at:
            if self.line is None:                    # never presses anything
                time.sleep(0.01)
                return None
            return self.line
        return super().answer(timeout_s)


def test_the_operator_can_stop_and_nothing_is_calibrated(sim, tmp_path, capsys):
    status, result = run_live(sim, tmp_path, ScriptedKeys(sim, at=3, line="q"))
    assert status == 2 and result is None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert ("stopped at pose 3 of 6 (on its RIGHT side): stopped by the operator; poses "
            "recorded: level, left; nothing calibrated") in err[0]


def test_a_pose_never_confirmed_times_out_with_the_reason(sim, tmp_path, capsys):
    status, _ = run_live(sim, tmp_path, ScriptedKeys(sim, at=1, line=None),
                         "--face-timeout", "1")
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pose 1 of 6 (level): no key press within 1 s" in err[0]


def test_closed_keyboard_input_stops_in_one_line(sim, tmp_path, capsys):
    out = io.StringIO()
    status, _ = run_live(sim, tmp_path, TerminalOperator(io.StringIO(""), out))
    assert status == 2
    assert "pose 1 of 6: place the vehicle level" in out.getvalue()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "keyboard input closed" in err[0]


class ClosedKeyboard(SimOperator):
    """Turns the vehicle as asked, but its keyboard input is closed (a script, ``</dev/null``)."""

    def answer(self, timeout_s):
        raise EOFError


def test_auto_runs_with_keyboard_input_closed(sim, tmp_path):
    status, result = run_live(sim, tmp_path, ClosedKeyboard(sim, press_enter=False), "--auto",
                              "--hold", "3")     # --auto's holds end as soon as they are long enough
    assert status == 0
    assert_accelerometer_as_injected(result, sim)


def test_auto_needs_guide(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["live", "udp:127.0.0.1:1", "--auto"])
    assert exc.value.code == 2 and "--auto needs --guide" in capsys.readouterr().err


def test_command_line_prompts_on_stdout_and_reads_enter_from_stdin(sim, tmp_path):
    """The real terminal path: `python -m apmcal live --guide` in a subprocess; Enter is written
    to its stdin when its prompt has been read and the vehicle rests in the pose."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = tmp_path / "guided.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "apmcal", "live", sim.connection, "--guide", "ardupilot6",
         "--hold", "2", "--face-timeout", "60", "--save-log", str(tmp_path / "g.tlog"),
         "--json", str(out)],
        cwd=tmp_path, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    prompts = []
    try:
        for line in proc.stdout:
            if line.startswith("pose ") and "place the vehicle" in line:
                face = next(f for f in FACES if f"place the vehicle {f.words}," in line)
                prompts.append(face.name)
                sim.turn_and_wait(face.name)
                proc.stdin.write("\n")
                proc.stdin.flush()
        status = proc.wait(timeout=120)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    assert status == 0, proc.stderr.read()
    assert prompts == ORDER
    assert json.loads(out.read_text())["method"] == "ferraris"
    assert accelcal_commands(sim) == []


def test_command_line_auto_with_stdin_from_dev_null_completes(sim, tmp_path):
    """`python -m apmcal live --guide ardupilot6 --auto </dev/null`: no keyboard at all (a
    script); the vehicle is turned when each prompt is read, and the run completes (before:
    "keyboard input closed" at pose 1, exit 2)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = tmp_path / "guided.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "apmcal", "live", sim.connection, "--guide", "ardupilot6",
         "--auto", "--hold", "3", "--rate", "50", "--face-timeout", "60",
         "--save-log", str(tmp_path / "g.tlog"),
         "--json", str(out)],
        cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    prompts = []
    try:
        for line in proc.stdout:
            if line.startswith("pose ") and "place the vehicle" in line:
                face = next(f for f in FACES if f"place the vehicle {f.words}," in line)
                if face.name not in prompts:
                    prompts.append(face.name)
                    sim.act(lambda v, name=face.name: v.goto_pose(name))
        status = proc.wait(timeout=120)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    assert status == 0, proc.stderr.read()
    assert prompts == ORDER
    assert json.loads(out.read_text())["method"] == "ferraris"
