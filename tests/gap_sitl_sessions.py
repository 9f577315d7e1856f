"""Sessions recorded from ArduPilot's own firmware (SITL) for the gap diagnosis's tests and
benchmarks (not a test module): ``apmcal gap`` on logs of real firmware with known SIM_*
injections, and the twin's round trip through SITL (``docs/sitl-twin.md``).

A session is a script of steps run on a fresh vehicle from its boot — ("hold", roll, pitch,
yaw, seconds): the ``calibration`` model posed and held (deg, s); ("spin", rate, (x, y, z),
seconds): turned at ``rate`` rad/s about a body axis; ("until", seconds): held as it is until
that many simulated seconds after boot. Both logs are kept: the .tlog of everything the
firmware sent (its parameter table first, then RAW_IMU, int16 telemetry truncated toward zero,
at ``telemetry_hz``) and the dataflash .BIN (float IMU at the firmware's 25 Hz, or at its loop
rate with LOG_BITMASK's IMU_FAST bit, from boot: LOG_DISARMED 1). With ``motors`` the vehicle
is armed on the ground first (ARMING_CHECK 0) and both logs start then: its motors turn at
MOT_SPIN_ARM, which is what makes SITL add its SIM_GYRn_RND noise (only while the throttle is
above SIM_INS_THR_MIN: ``docs/ardupilot-facts.md``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from ardupilot_sitl import ArduPilotSitl, SitlError

RAW_IMU = 27                    # MAVLink message id
BOOT = {"LOG_DISARMED": 1}      # the dataflash log from boot, not from arming
# armed on the ground, motors at MOT_SPIN_ARM (throttle 0.1, above SIM_INS_THR_MIN 0.05), never
# disarming by itself; the dataflash log from arming on
MOTORS = {"ARMING_CHECK": 0, "DISARM_DELAY": 0, "SIM_INS_THR_MIN": 0.05, "LOG_DISARMED": 0}


@dataclass(frozen=True)
class Recorded:
    """One recorded session.

    Attributes
    ----------
    tlog : Path
        The telemetry log (parameters, then RAW_IMU at the rate asked for).
    bin : Path
        The dataflash log (IMU, MAG at the firmware's own rates).
    seconds : float
        Simulated seconds since boot at the end.
    wall_s : float
        Wall-clock seconds the recording took.
    """

    tlog: Path
    bin: Path
    seconds: float
    wall_s: float


def run_script(sitl: ArduPilotSitl, script) -> None:
    """The steps of ``script`` (module docstring) on a started vehicle."""
    for step in script:
        kind = step[0]
        if kind == "hold":
            _, roll, pitch, yaw, seconds = step
            sitl.pose(roll, pitch, yaw, settle_s=0.0)
            _run(sitl, seconds)
        elif kind == "spin":
            _, rate, axis, seconds = step
            sitl.spin(rate, axis)
            _run(sitl, seconds)
        elif kind == "until":
            _run(sitl, step[1] - sitl.time_boot_s)
        else:
            raise ValueError(f"unknown step {step!r}")


def _run(sitl: ArduPilotSitl, seconds: float, chunk_s: float = 20.0) -> None:
    """``seconds`` of simulated time in chunks: the driver's stall check allows each call
    30 wall seconds beyond its share at the speedup asked for, which a busy machine (the
    firmware runs far slower than asked) can exceed over minutes but not over one chunk."""
    end = sitl.time_boot_s + seconds
    while sitl.time_boot_s < end:
        sitl.run_for(min(chunk_s, end - sitl.time_boot_s))


def record(workdir, script, boot_params: dict | None = None, *, model: str = "calibration",
           telemetry_hz: float = 50.0, motors: bool = False, speedup: float = 400.0
           ) -> Recorded:
    """Run ``script`` on a fresh vehicle started with ``boot_params`` (SIM_* injections, as
    defaults from the first sample on) and return its logs.

    Parameters
    ----------
    workdir : path
        A fresh scratch folder.
    script : list of tuple
        Steps (module docstring).
    boot_params : dict, optional
        Parameters loaded at boot besides LOG_DISARMED 1 (and, with ``motors``, the arming
        ones).
    model : str
        The physics model: "calibration" to pose and spin, "quad" for a copter on the ground.
    telemetry_hz : float
        RAW_IMU rate asked for [Hz].
    motors : bool
        Arm first, so that the motors turn at MOT_SPIN_ARM on the ground.
    speedup : float
        Simulated seconds per wall second asked for.
    """
    start = time.monotonic()
    params = dict(BOOT, **(MOTORS if motors else {}), **(boot_params or {}))
    with ArduPilotSitl(Path(workdir), model=model, speedup=speedup, boot_params=params) as sitl:
        sitl.all_params()       # the whole table sent, so that the .tlog carries it
        if motors:      # both logs from the motors' start on: one noise level throughout
            sitl.arm(force=True)
        sitl.request_message(RAW_IMU, telemetry_hz)
        run_script(sitl, script)
        seconds = sitl.time_boot_s
        sitl.flush_logs()
        logs = sitl.dataflash_logs()
    if not logs:
        raise SitlError(f"no dataflash log in {workdir}")
    return Recorded(Path(workdir) / "sitl.tlog", logs[-1], seconds, time.monotonic() - start)
