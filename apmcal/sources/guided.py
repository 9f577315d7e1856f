"""Guided recording: the ground station asks for ArduPilot's six accelerometer-calibration
poses one after another and records each hold.

ardupilot-facts.md "ArduPilot's own calibrators": the onboard accel cal takes the faces in the
order level, LEFT, RIGHT, nose DOWN, nose UP, BACK. The prompt is printed for the operator and
also sent as MAV_CMD_ACCELCAL_VEHICLE_POS (the command a GCS sends when the vehicle is in a pose),
which the simulated vehicle in operator mode obeys by turning to that pose.
"""
from __future__ import annotations

from typing import Callable

# MAV_CMD_ACCELCAL_VEHICLE_POS param1 values, ArduPilot's ACCELCAL_VEHICLE_POS enum
ARDUPILOT_FACES = ((1, "level"), (2, "on its LEFT side"), (3, "on its RIGHT side"),
                   (4, "nose DOWN"), (5, "nose UP"), (6, "on its BACK"))


def record_six_faces(link, hold_s: float, move_s: float, say: Callable[[str], None]) -> int:
    """Prompt each face, give ``move_s`` to get there, record ``hold_s`` still.

    Returns the number of IMU messages received during the holds.
    """
    from pymavlink import mavutil

    n_imu = 0
    for code, words in ARDUPILOT_FACES:
        say(f"Place vehicle {words} and hold it still for {hold_s:g} s")
        link.master.mav.command_long_send(link.target_system, link.target_component,
                                          mavutil.mavlink.MAV_CMD_ACCELCAL_VEHICLE_POS, 0,
                                          code, 0, 0, 0, 0, 0, 0)
        link.collect(move_s)
        n_imu += link.collect(hold_s)
    return n_imu
