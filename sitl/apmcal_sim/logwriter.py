"""Log writers read back by pymavlink: telemetry .tlog and dataflash .bin.

.tlog: each record is an 8-byte big-endian microsecond Unix timestamp followed by one packed
MAVLink message (the format mavutil.mavlogfile reads). Messages are packed by the vehicle's own
pymavlink MAVLink 2 encoder, so only the timestamp framing is written here.

.bin: hand-written with struct because pymavlink has no dataflash writer. Every record is
0xA3 0x95, message type, payload; FMT (type 128) records describe each type with DFReader's
format characters (Q uint64, f float32, h int16, I uint32, B uint8, N char[16], Z char[64]).
"""
from __future__ import annotations

import struct
from pathlib import Path

HEAD = b"\xa3\x95"
FMT_TYPE = 128

# name → (type id, DFReader format, columns); units: Gyr rad/s, Acc m/s², T degC, Mag mGauss,
# BAT Volt V and Curr A as float32 (the newer firmware's BAT layout, e.g. "Qfffffcf" on Copter
# 3.6: libraries/AP_BattMonitor/LogStructure.h, units V and A, no multiplier), cut to these three
DF_MESSAGES = {
    "FMT": (FMT_TYPE, "BBnNZ", "Type,Length,Name,Format,Columns"),
    "PARM": (129, "QNf", "TimeUS,Name,Value"),
    "MSG": (130, "QZ", "TimeUS,Message"),
    "IMU": (131, "QffffffIIf", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,T"),
    "MAG": (132, "QhhhhhhhhhB", "TimeUS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health"),
    "GPS": (133, "QBIHBLLf", "TimeUS,Status,GMS,GWk,NSats,Lat,Lng,Alt"),
    "BAT": (134, "Qff", "TimeUS,Volt,Curr"),
}
_STRUCT = {"Q": "Q", "f": "f", "h": "h", "H": "H", "I": "I", "B": "B", "L": "i", "n": "4s",
           "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i"}   # c, C, e: ints ×100
GPS_EPOCH_UNIX_S = 315964800       # 1980-01-06 UTC
GPS_MINUS_UTC_S = 18               # leap seconds since 1980 (2017 on), as ArduPilot logs them


def _struct(fmt: str) -> struct.Struct:
    return struct.Struct("<" + "".join(_STRUCT[c] for c in fmt))


class TlogWriter:
    """Write (unix time [s], packed MAVLink bytes) records to a .tlog file."""

    def __init__(self, path):
        self.f = open(Path(path), "wb")

    def write(self, unix_s: float, packed: bytes) -> None:
        """One record: ``packed`` MAVLink bytes stamped with Unix time ``unix_s`` [s] (µs resolution)."""
        self.f.write(struct.pack(">Q", int(round(unix_s * 1e6))) + packed)

    def close(self) -> None:
        """Close the file."""
        self.f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ArduPilot 4.x's IMU record carries the instance in an "I" column (e.g. IMU "QBffffffIIfBBHH"
# on 4.1); only the columns sitl writes are kept
IMU_WITH_INSTANCE = (131, "QBffffffIIf", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,T")


class DataflashWriter:
    """Write a binary dataflash log with FMT, PARM, MSG, IMU, MAG, GPS and BAT records.

    ``imu_instance``: IMU records in the 4.x layout with an instance column ``I`` (always 0),
    as tools written for 4.x logs (ArduPilot's tempcal_imu.py) expect. ``messages``: further or
    replacing definitions, name → (type id, format, columns) as in ``DF_MESSAGES`` (the flight
    writer's ATT, RCOU, 4.x GPS and MAG).
    """

    def __init__(self, path, imu_instance: bool = False, messages: dict | None = None):
        self.f = open(Path(path), "wb")
        self.imu_instance = imu_instance
        self._messages = dict(DF_MESSAGES, **({"IMU": IMU_WITH_INSTANCE} if imu_instance else {}),
                              **(messages or {}))
        self._structs = {name: _struct(fmt) for name, (_, fmt, _) in self._messages.items()}
        for name, (mid, fmt, cols) in self._messages.items():
            length = 3 + self._structs[name].size
            self._record("FMT", mid, length, name.encode(), fmt.encode(), cols.encode())

    def _record(self, name: str, *values) -> None:
        self.f.write(HEAD + bytes([self._messages[name][0]]) + self._structs[name].pack(*values))

    def parm(self, time_us: int, name: str, value: float) -> None:
        """One PARM record: parameter ``name`` = ``value`` at ``time_us`` [µs since boot]."""
        self._record("PARM", time_us, name.encode(), float(value))

    def msg(self, time_us: int, text: str) -> None:
        """One MSG record (text cut to 64 bytes) at ``time_us`` [µs since boot]."""
        self._record("MSG", time_us, text.encode()[:64])

    def imu(self, time_us: int, gyr, acc, temp_c: float) -> None:
        """One IMU record: gyro [rad/s] and accel [m/s²] body frame, temperature [degC]."""
        instance = (0,) if self.imu_instance else ()
        self._record("IMU", time_us, *instance, *map(float, gyr), *map(float, acc), 0, 0,
                     float(temp_c))

    def mag(self, time_us: int, field_mgauss, ofs, motor=(0, 0, 0)) -> None:
        """One MAG record: corrected field, COMPASS_OFS and motor compensation [mGauss]."""
        ints = [int(max(-32768, min(32767, round(v)))) for v in (*field_mgauss, *ofs, *motor)]
        self._record("MAG", time_us, *ints, 1)

    def gps(self, time_us: int, unix_s: float, lat_deg: float, lon_deg: float,
            alt_m: float) -> None:
        """One GPS record with a 3D fix at Unix time ``unix_s``: GPS week and ms of the week
        (GWk, GMS) as ArduPilot logs them; Lat/Lng in 1e-7 degrees."""
        gps_ms = int(round((unix_s - GPS_EPOCH_UNIX_S + GPS_MINUS_UTC_S) * 1000))
        week, ms = divmod(gps_ms, 604_800_000)
        self._record("GPS", time_us, 3, ms, week, 10, int(round(lat_deg * 1e7)),
                     int(round(lon_deg * 1e7)), float(alt_m))

    def bat(self, time_us: int, volt: float, curr_a: float) -> None:
        """One BAT record: battery voltage [V] and current [A] (float32)."""
        self._record("BAT", time_us, float(volt), float(curr_a))

    def close(self) -> None:
        """Close the file."""
        self.f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
