"""Test helpers (not a test module): the simulated vehicle served from a thread, and a lossy
loopback UDP proxy between it and the ground station.

    SimVehicle --udpout--> [vehicle side | LossyUdpProxy | gcs side] --> VehicleLink (udpin)

Each datagram (one MAVLink packet) is dropped with probability ``loss``, each way. Whether a
packet is dropped is decided by a generator seeded with the seed, the direction, the packet's
message id and payload, and how often that same message went that way before: the drops do not
depend on thread timing or on how many heartbeats happened to be sent in between.
"""
from __future__ import annotations

import random
import socket
import threading
import time
from contextlib import contextmanager

from sitl_helpers import only

from apmcal_sim.mavlink_vehicle import MavlinkVehicle
from apmcal_sim.vehicle import SimVehicle

LOOPBACK = "127.0.0.1"


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def message_key(packet: bytes) -> bytes:
    """Message id and payload of a MAVLink 1 or 2 packet (not its sequence number or CRC)."""
    if packet[:1] == b"\xfd" and len(packet) >= 10:         # MAVLink 2: 10-byte header
        return packet[7:10] + packet[10:10 + packet[1]]
    if packet[:1] == b"\xfe" and len(packet) >= 6:          # MAVLink 1: 6-byte header
        return packet[5:6] + packet[6:6 + packet[1]]
    return packet


class Dropper:
    """Seeded, timing-independent drop decisions for one direction."""

    def __init__(self, loss: float, seed: int, direction: str):
        self.loss, self.prefix = loss, f"{seed}/{direction}/".encode()
        self.seen: dict[bytes, int] = {}
        self.passed = self.dropped = 0

    def drop(self, packet: bytes) -> bool:
        key = message_key(packet)
        n = self.seen.get(key, 0)
        self.seen[key] = n + 1
        lost = random.Random(self.prefix + str(n).encode() + b"/" + key).random() < self.loss
        if lost:
            self.dropped += 1
        else:
            self.passed += 1
        return lost


class LossyUdpProxy:
    """Forwards datagrams between a vehicle sending to :attr:`vehicle_port` and a ground station
    listening on ``gcs_port``, both on loopback, losing ``loss`` of them each way."""

    def __init__(self, gcs_port: int, loss: float, seed: int):
        self.gcs_address = (LOOPBACK, gcs_port)
        self.vehicle_address = None          # learnt from the vehicle's first datagram
        self.vehicle_side = self._socket()
        self.gcs_side = self._socket()
        self.vehicle_port = self.vehicle_side.getsockname()[1]
        self.up = Dropper(loss, seed, "gcs->vehicle")
        self.down = Dropper(loss, seed, "vehicle->gcs")
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._forward_down, daemon=True),
                         threading.Thread(target=self._forward_up, daemon=True)]

    @staticmethod
    def _socket() -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((LOOPBACK, 0))
        s.settimeout(0.05)
        return s

    def _forward_down(self) -> None:
        while not self._stop.is_set():
            try:
                packet, self.vehicle_address = self.vehicle_side.recvfrom(65536)
            except (socket.timeout, ConnectionError):
                continue
            if not self.down.drop(packet):
                self._send(self.gcs_side, packet, self.gcs_address)

    def _forward_up(self) -> None:
        while not self._stop.is_set():
            try:
                packet, _ = self.gcs_side.recvfrom(65536)
            except (socket.timeout, ConnectionError):   # ICMP unreachable: GCS not open yet
                continue
            if self.vehicle_address is not None and not self.up.drop(packet):
                self._send(self.vehicle_side, packet, self.vehicle_address)

    @staticmethod
    def _send(sock: socket.socket, packet: bytes, address) -> None:
        try:
            sock.sendto(packet, address)
        except OSError:     # nobody listening there (yet): a lost packet, as on a real link
            pass

    def __enter__(self):
        for t in self._threads:
            t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        for t in self._threads:
            t.join(5)
        self.vehicle_side.close()
        self.gcs_side.close()


class ServedVehicle:
    """A 3.3 :class:`SimVehicle` served on ``connection`` from a thread (boot gyro calibration
    off, so that only the ground station changes its calibration parameters). Every PARAM_SET
    it receives is kept in :attr:`sets` as (name, value); ``full_params``: a real vehicle's
    full-size parameter table."""

    def __init__(self, connection: str, param_file=None, fs: float = 200.0,
                 full_params: bool = False):
        self.vehicle = SimVehicle(only("acc_noise"), "onepos", "3.3", param_file=param_file,
                                  fs=fs, duration=3600.0, full_params=full_params)
        self.vehicle.params.set("INS_GYR_CAL", 0, save=False)
        self.vehicle._boot_gyro = None
        self.sets: list[tuple[str, float]] = []
        handle = self.vehicle.handle

        def handle_and_note(msg):
            if msg.get_type() == "PARAM_SET":
                self.sets.append((msg.param_id, msg.param_value))
            handle(msg)
        self.vehicle.handle = handle_and_note
        self.endpoint = MavlinkVehicle(self.vehicle, connection)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)

    @property
    def params(self):
        return self.vehicle.params

    def _serve(self) -> None:
        while not self._stop.is_set():
            self.endpoint.poll()
            time.sleep(0.002)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(5)
        self.endpoint.close()


@contextmanager
def vehicle_behind_lossy_link(loss: float, seed: int, param_file=None, full_params=False):
    """(connection string for the ground station, :class:`ServedVehicle`, :class:`LossyUdpProxy`)."""
    gcs_port = free_udp_port()
    with LossyUdpProxy(gcs_port, loss, seed) as proxy, \
            ServedVehicle(f"udpout:{LOOPBACK}:{proxy.vehicle_port}", param_file,
                          full_params=full_params) as served:
        yield f"udpin:{LOOPBACK}:{gcs_port}", served, proxy
