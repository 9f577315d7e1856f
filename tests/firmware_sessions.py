"""Sessions recorded from ArduPilot's own firmware (SITL) for the real-firmware tests and
benchmarks (not a test module).

- :func:`injected_errors` draws, per seed, the sensor errors set through SIM_* and
  :func:`calibration_in_force` a calibration (different from the exact one) already on the
  vehicle; :func:`exact_calibration` is the calibration that undoes the errors, per the
  firmware README's table (``../shared/ardupilot-sitl/README.md``, "Injected errors and the exact
  calibration they call for").
- :func:`guided_six_faces` runs ``apmcal live CONNECTION --guide ardupilot6 --auto`` against the
  firmware's second serial port and poses the ``calibration`` model as each prompt asks;
  :func:`compass_turns` records ``apmcal live`` while the model turns about a sequence of axes.
"""
from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from ardupilot_sitl import ACCELCAL_ATTITUDES

from apmcal.calibration.guided import FACES

ROOT = Path(__file__).resolve().parents[1]

# the words of apmcal's prompt for each of ArduPilot's six poses (in ArduPilot's order, the
# firmware's ACCELCAL_VEHICLE_POS 1-6) → the calibration model's attitude [deg]
FACE_ATTITUDES = {face.words: ACCELCAL_ATTITUDES[i + 1] for i, face in enumerate(FACES)}


def injected_errors(seed: int) -> dict[str, float]:
    """SIM_* errors of the first IMU and compass for ``seed``: accelerometer bias [m/s²] and
    scale, gyro bias [rad/s], compass hard iron [mGauss] and soft iron."""
    rng = np.random.default_rng(seed)
    errors = {}
    for axis in "XYZ":
        errors[f"SIM_ACC1_BIAS_{axis}"] = rng.uniform(-0.4, 0.4)
        errors[f"SIM_ACC1_SCAL_{axis}"] = 1 + rng.uniform(-0.04, 0.04)
        errors[f"SIM_GYR1_BIAS_{axis}"] = rng.uniform(-0.03, 0.03)
        errors[f"SIM_MAG1_OFS_{axis}"] = rng.uniform(-150, 150)
        errors[f"SIM_MAG1_DIA_{axis}"] = 1 + rng.uniform(-0.06, 0.06)
        errors[f"SIM_MAG1_ODI_{axis}"] = rng.uniform(-0.04, 0.04)
    return {k: round(float(v), 4) for k, v in errors.items()}


def calibration_in_force(seed: int) -> dict[str, float]:
    """A wrong calibration already on the vehicle (apmcal must undo it): accelerometer offsets
    and scales, compass offsets, soft iron and a COMPASS_SCALE ≠ 1."""
    rng = np.random.default_rng(10_000 + seed)
    params = {"COMPASS_SCALE": round(float(rng.uniform(1.05, 1.2)), 3)}
    for axis in "XYZ":
        params[f"INS_ACCOFFS_{axis}"] = round(float(rng.uniform(-0.2, 0.2)), 3)
        params[f"INS_ACCSCAL_{axis}"] = round(float(1 + rng.uniform(-0.02, 0.02)), 3)
        params[f"COMPASS_OFS_{axis}"] = round(float(rng.uniform(-60, 60)), 1)
        params[f"COMPASS_DIA_{axis}"] = round(float(1 + rng.uniform(-0.03, 0.03)), 3)
        params[f"COMPASS_ODI_{axis}"] = round(float(rng.uniform(-0.02, 0.02)), 3)
    return params


def at_rest_reading_range(seed: int, gravity_ms2: float = 9.80665) -> tuple[float, float]:
    """The smallest and largest |specific force| [m/s²] the accelerometer reads at rest with
    :func:`calibration_in_force` over :func:`injected_errors` (``seed``), over every attitude:
    the firmware's sensor is f ⊘ SIM_ACC1_SCAL + SIM_ACC1_BIAS, the calibration in force
    (sensor − INS_ACCOFFS) ⊙ INS_ACCSCAL (docs/ardupilot-facts.md); |f| the firmware's gravity."""
    errors, in_force = injected_errors(seed), calibration_in_force(seed)

    def per_axis(prefix: str) -> np.ndarray:
        table = errors if prefix.startswith("SIM") else in_force
        return np.array([table[f"{prefix}_{axis}"] for axis in "XYZ"])

    # directions spread evenly over the sphere (a Fibonacci lattice)
    k = np.arange(20_000) + 0.5
    z = 1 - 2 * k / len(k)
    phi = np.pi * (1 + 5 ** 0.5) * k
    f = gravity_ms2 * np.column_stack([np.sqrt(1 - z * z) * np.cos(phi),
                                       np.sqrt(1 - z * z) * np.sin(phi), z])
    sensor = f / per_axis("SIM_ACC1_SCAL") + per_axis("SIM_ACC1_BIAS")
    reading = np.linalg.norm((sensor - per_axis("INS_ACCOFFS")) * per_axis("INS_ACCSCAL"), axis=1)
    return float(reading.min()), float(reading.max())


# the Earth field's magnitude the firmware simulates at its default home, from its own tables
# (AP_Declination; the firmware README's "Facts measured on this build") [mGauss]
SITL_FIELD_MGAUSS = 579.3


def exact_calibration(errors: dict[str, float], field_mgauss: float | None = None
                      ) -> dict[str, float]:
    """The parameters that undo ``errors`` exactly (the firmware README's table):
    INS_ACCOFFS = SIM_ACC1_BIAS, INS_ACCSCAL = SIM_ACC1_SCAL, INS_GYROFFS = SIM_GYR1_BIAS (no
    drift), COMPASS_OFS = SIM_MAG1_OFS, COMPASS_DIA/ODI = SIM_MAG1_DIA/ODI with COMPASS_SCALE 1.

    ``field_mgauss``: the field magnitude a calibration was told (or assumed) the vehicle sees.
    A compass calibration scales its soft-iron matrix so that the corrected field has that
    magnitude; the exact DIA/ODI for it are the README's times field_mgauss / 579.3 (the
    field the firmware really simulates). None: the README's own (the true field).
    """
    rename = {"SIM_ACC1_BIAS": "INS_ACCOFFS", "SIM_ACC1_SCAL": "INS_ACCSCAL",
              "SIM_GYR1_BIAS": "INS_GYROFFS", "SIM_MAG1_OFS": "COMPASS_OFS",
              "SIM_MAG1_DIA": "COMPASS_DIA", "SIM_MAG1_ODI": "COMPASS_ODI"}
    gain = 1.0 if field_mgauss is None else field_mgauss / SITL_FIELD_MGAUSS
    exact = {}
    for name, value in errors.items():
        if name[:-2] in rename:
            scaled = name[:-2] in ("SIM_MAG1_DIA", "SIM_MAG1_ODI")
            exact[rename[name[:-2]] + name[-2:]] = value * gain if scaled else value
    return exact


def parameter_sigmas(result: dict) -> dict[str, float]:
    """1σ of each proposed calibration parameter, from the calibration's own σ in a
    ``--json`` file: INS_ACCOFFS ← acc offset, INS_ACCSCAL ← acc matrix diagonal, INS_GYROFFS ←
    gyro offset, COMPASS_OFS ← mag offset (the firmware adds it: same σ), COMPASS_DIA/ODI ← the
    mag matrix's diagonal / (xy, xz, yz) entries."""
    sig = {}
    for sensor, prefix in (("acc", "INS_ACC"), ("gyr", "INS_GYR"), ("mag", "COMPASS_")):
        block = result.get(sensor) or {}
        s = block.get("sigma") or {}
        for i, axis in enumerate("XYZ"):
            if s.get("offset") is not None:
                sig[{"acc": "INS_ACCOFFS", "gyr": "INS_GYROFFS", "mag": "COMPASS_OFS"}[sensor]
                    + f"_{axis}"] = s["offset"][i]
            if s.get("matrix") is not None and sensor != "gyr":
                name = "INS_ACCSCAL" if sensor == "acc" else "COMPASS_DIA"
                sig[f"{name}_{axis}"] = s["matrix"][i][i]
        if sensor == "mag" and s.get("matrix") is not None:
            for axis, (i, j) in zip("XYZ", ((0, 1), (0, 2), (1, 2))):
                sig[f"COMPASS_ODI_{axis}"] = s["matrix"][i][j]
        del prefix
    return sig


def known_failure(rate: str, why: str):
    """An open defect, with how often the claim holds over fresh SITL recordings (for the gap,
    ``python benchmarks/gap_firmware_rates.py --runs 10``; docs/gap-trust.md, "One recording
    per test run"): the claim is still checked, and reported as XPASS where it holds."""
    return pytest.mark.xfail(strict=False, reason=f"holds on {rate} recordings: {why}")


def within_3_sigma_bound(n: int) -> float:
    """The bound the largest of ``n`` errors in σ is held to, so that a test of ``n`` estimates
    with honest σ fails as rarely as one estimate falls beyond 3σ (0.27 %): each alone is then
    held to 0.27 %/n (Bonferroni). With 18 estimates that is 3.79σ; the plain 3σ on each of 18
    honest estimates fails one run in 28 (1 − 0.9973¹⁸), and did, at 3.08σ on one of them."""
    from scipy.stats import norm

    return float(norm.isf(0.0027 / (2 * max(n, 1))))


def errors_in_sigma(result: dict, exact: dict[str, float], names) -> dict[str, float]:
    """|proposed − exact| / σ for each of ``names`` (a proposal missing counts as infinite)."""
    sig = parameter_sigmas(result)
    out = {}
    for name in names:
        proposed = result["params"].get(name)
        if proposed is None or name not in sig:
            out[name] = float("inf")
        else:
            out[name] = abs(proposed - exact[name]) / sig[name]
    return out


# -- the live path against the firmware ----------------------------------------------------------
# apmcal live's IMU stream rate [Hz] in these sessions: at the driver's speedup the stream
# arrives that many times faster, and a busy machine must keep up with it
LIVE_RATE_HZ = 25


def apmcal_live(sitl, tmp_path: Path, *args: str, stdin=subprocess.DEVNULL) -> subprocess.Popen:
    """``python -m apmcal live`` on the firmware's SERIAL1, its stdout a pipe of text lines."""
    cmd = [sys.executable, "-m", "apmcal", "live", sitl.gcs_connection, "--save-log",
           str(tmp_path / "live.tlog"), "--json", str(tmp_path / "live.json"),
           "--rate", str(LIVE_RATE_HZ), *args]
    return subprocess.Popen(cmd, cwd=tmp_path, stdin=stdin, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


class _Pump:
    """Reads the driver's own link (SERIAL0) in a thread while the test waits on apmcal, so
    that the firmware's clock and messages keep flowing to the driver's .tlog; the poses are
    sent from the same thread (the driver is not thread-safe)."""

    def __init__(self, sitl):
        self.sitl = sitl
        self.todo: list = []
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def call(self, fn) -> None:
        with self.lock:
            self.todo.append(fn)

    def _run(self) -> None:
        try:
            while not self.stop.is_set():
                with self.lock:
                    todo, self.todo = self.todo, []
                for fn in todo:
                    fn(self.sitl)
                self.sitl.recv(timeout_s=0.05)
        except BaseException as exc:        # seen by the test in close()
            self.error = exc

    def close(self) -> None:
        self.stop.set()
        self.thread.join(30)
        if self.error is not None:
            raise self.error


@contextlib.contextmanager
def _live_with_pump(sitl, tmp_path: Path, *args: str):
    """(apmcal live process, the driver's pump) for the block; after it apmcal is killed if
    still running and the pump stopped (its error, if any, raised)."""
    proc = apmcal_live(sitl, tmp_path, *args)
    pump = _Pump(sitl)
    try:
        yield proc, pump
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        pump.close()


def _json_result(tmp_path: Path) -> dict | None:
    out = tmp_path / "live.json"
    return json.loads(out.read_text()) if out.exists() else None


def guided_six_faces(sitl, tmp_path: Path, hold_s: float = 5.0, timeout_s: float = 240.0,
                     turn_rate_deg_s: float = 90.0, extra=()) -> tuple[int, str, dict | None]:
    """``apmcal live --guide ardupilot6 --auto`` with the model posed as each prompt asks,
    turned there at ``turn_rate_deg_s`` as a person would.

    Returns (exit status (None: still running at ``timeout_s`` [s wall], then killed),
    everything apmcal printed, its --json result or None).
    """
    lines = []
    asked = None
    deadline = time.monotonic() + timeout_s
    with _live_with_pump(sitl, tmp_path, "--guide", "ardupilot6", "--auto", "--hold",
                         f"{hold_s:g}", "--face-timeout", "120", *extra) as (proc, pump):
        for line in proc.stdout:
            lines.append(line)
            if pump.error is not None:          # the model can no longer be posed: stop now
                break
            if line.startswith("pose ") and "place the vehicle" in line:
                words = line.split("place the vehicle ", 1)[1]
                face = next(f for f in FACE_ATTITUDES if words.startswith(f + ","))
                if face != asked:               # a prompt repeated: the model is on its way
                    asked = face
                    pump.call(lambda s, att=FACE_ATTITUDES[face]: s.pose(
                        *att, settle_s=0, rate_deg_s=turn_rate_deg_s))
            if time.monotonic() > deadline:
                lines.append(f"[no end within {timeout_s:g} s]\n")
                break
        try:
            status = proc.wait(timeout=max(deadline - time.monotonic(), 1.0))
        except subprocess.TimeoutExpired:
            status = None
            lines.append(f"[no exit within {timeout_s:g} s]\n")
    return status, "".join(lines), _json_result(tmp_path)


# axes to turn about, body frame, each from the attitude the last one left: together they carry
# the compass through every direction
TURN_AXES = [(0, 0, 1), (1, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, -1, 1),
             (-1, 1, 1), (1, 1, -1)]


def compass_turns(sitl, tmp_path: Path, seconds_per_axis: float = 8.0,
                  rate_rad_s: float = 1.2, extra=()) -> tuple[int, str, dict | None]:
    """``apmcal live --duration`` while the model turns about :data:`TURN_AXES` in turn.

    The turns are timed in simulated seconds (from the driver's thread) and go round the axes
    again until apmcal is done; apmcal's --duration is wall time, set for one round at the
    driver's speedup plus a margin.
    """
    total_sim_s = seconds_per_axis * len(TURN_AXES)
    wall_s = total_sim_s / sitl.speedup + 2.0
    with _live_with_pump(sitl, tmp_path, "--duration", f"{wall_s:.1f}", "--min-still", "1",
                         *extra) as (proc, pump):
        def turn_round_the_axes(s):
            for axis in TURN_AXES:
                if pump.stop.is_set():
                    return
                s.spin(rate_rad_s, axis)
                s.run_for(seconds_per_axis)
            pump.call(turn_round_the_axes)

        pump.call(turn_round_the_axes)
        out_text = proc.communicate(timeout=wall_s + 180)[0]
    return proc.returncode, out_text, _json_result(tmp_path)
