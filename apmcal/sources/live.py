"""A live vehicle over MAVLink: its IMU streamed and recorded.

The link records everything it receives to a telemetry log (.tlog), and the IMU samples are
then read back with the ordinary tlog reader: one conversion path for live and logged data, and
the user keeps the raw recording.
"""
from __future__ import annotations

import time

from apmcal.link.connection import Connection
from apmcal.link.params import ParamProtocol

# ardupilot-facts.md "What the telemetry really carries": stream 1 = RAW_SENSORS carries RAW_IMU,
# SCALED_IMU2/3 and SCALED_PRESSURE; newer firmware also honours SET_MESSAGE_INTERVAL (511),
# through which HIGHRES_IMU (SI floats, free of RAW_IMU's 1 mG / 1 mrad/s steps) is asked for.
IMU_MESSAGE_IDS = {"RAW_IMU": 27, "SCALED_IMU2": 116, "HIGHRES_IMU": 105}
STREAMED_MESSAGE_IDS = {**IMU_MESSAGE_IDS, "SCALED_PRESSURE": 29}


class VehicleLink(ParamProtocol, Connection):
    """One MAVLink connection to one vehicle: its parameters (:class:`ParamProtocol`) and its
    IMU stream (:class:`~apmcal.link.connection.Connection` gives the constructor's arguments).
    """

    def request_imu_stream(self, rate_hz: int) -> None:
        """Ask for RAW_SENSORS at ``rate_hz`` both ways (old firmware and MAVLink 2 intervals).

        Parameters
        ----------
        rate_hz : int
            Messages per second [Hz].
        """
        mav, mavlink = self.master.mav, self._mavutil.mavlink
        mav.request_data_stream_send(self.target_system, self.target_component,
                                     mavlink.MAV_DATA_STREAM_RAW_SENSORS, int(rate_hz), 1)
        for msg_id in STREAMED_MESSAGE_IDS.values():
            mav.command_long_send(self.target_system, self.target_component,
                                  mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                  msg_id, 1e6 / rate_hz, 0, 0, 0, 0, 0)

    def collect(self, duration_s: float, progress=None) -> int:
        """Receive (and record) for ``duration_s``; returns the number of IMU messages seen.

        Parameters
        ----------
        duration_s : float
            How long to receive [s].
        progress : callable, optional
            Called with the seconds [s] received so far.

        Returns
        -------
        int
        """
        n_imu = 0
        end = time.monotonic() + duration_s
        while (now := time.monotonic()) < end:
            msg = self.recv(None, min(1.0, end - now))
            if msg is not None and msg.get_type() in IMU_MESSAGE_IDS:
                n_imu += 1
            if progress is not None:
                progress(min(duration_s, duration_s - (end - time.monotonic())))
        return n_imu
