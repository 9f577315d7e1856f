"""Upload, then restore, of calibration parameters on ArduPilot's own firmware (SITL, its full
table of about 1,350 parameters) through a loopback proxy that drops a quarter of the MAVLink
packets each way from the first one: all or nothing every time, every value read back from the
vehicle itself over the driver's own, lossless link.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from lossy_udp import LossyUdpProxy, free_udp_port

from apmcal.ardupilot.paramfile import read_param_file
from apmcal.core.errors import ApmcalError
from apmcal.link.upload import UploadReport, restore_params, upload_params
from apmcal.sources.live import VehicleLink

pytestmark = pytest.mark.ardupilot_sitl

LOSS = 0.25
NEW = {"INS_ACCOFFS_X": 0.31, "INS_ACCOFFS_Y": -0.27, "INS_ACCOFFS_Z": 0.52,
       "INS_ACCSCAL_X": 1.021, "INS_ACCSCAL_Y": 0.987, "INS_ACCSCAL_Z": 1.004,
       "COMPASS_OFS_X": 41.5, "COMPASS_OFS_Y": -63.25, "COMPASS_OFS_Z": 120.0,
       "COMPASS_DIA_X": 1.02, "COMPASS_DIA_Y": 0.97, "COMPASS_DIA_Z": 1.01,
       "COMPASS_ODI_X": 0.01, "COMPASS_ODI_Y": -0.02, "COMPASS_ODI_Z": 0.005}
# parameters the firmware writes itself while it runs (seen on this build: run counters, the
# ground pressure, the mission count, the automatic declination, and the third MAVLink port's
# group, whose entries come and go as the port comes up)
OWN_COUNTERS = ("STAT_", "BARO1_GND_PRESS", "BARO2_GND_PRESS", "MIS_TOTAL", "COMPASS_DEC",
                "MAV3_")
SETTLE_S = 1.0       # for a PARAM_SET still on its way through the proxy


class ParamSetRecorder:
    """Names of the PARAM_SETs apmcal sends towards the vehicle (before the proxy drops any)."""

    def __init__(self, dropper):
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

        self.names: set[str] = set()
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        drop = dropper.drop

        def note_and_drop(packet: bytes) -> bool:
            for msg in self._parser.parse_buffer(packet) or []:
                if msg.get_type() == "PARAM_SET":
                    self.names.add(msg.param_id)
            return drop(packet)
        dropper.drop = note_and_drop


def stored(values: dict) -> dict:
    return {k: float(np.float32(v)) for k, v in values.items()}


def on_vehicle(sitl) -> dict:
    """The vehicle's whole table, read over the driver's lossless link (its own counters out)."""
    return {k: v for k, v in sitl.all_params().items() if not k.startswith(OWN_COUNTERS)}


@pytest.mark.parametrize("seed", [21, 22])
def test_upload_and_restore_on_the_full_firmware_table_through_a_lossy_link(
        ardupilot_sitl, tmp_path, seed):
    gcs_port = free_udp_port()
    with LossyUdpProxy(gcs_port, LOSS, seed) as proxy:
        sets = ParamSetRecorder(proxy.up)
        sitl = ardupilot_sitl(speedup=10,
                              serial1=f"udpclient:127.0.0.1:{proxy.vehicle_port}")
        before = on_vehicle(sitl)
        assert len(before) > 1300
        backup = tmp_path / "backup.param"
        with VehicleLink(f"udpin:127.0.0.1:{gcs_port}") as link:
            try:
                uploaded = upload_params(link, NEW, backup)
            except ApmcalError as err:
                uploaded = err
            time.sleep(SETTLE_S)
            after_upload = on_vehicle(sitl)
            changed = {k for k in before if after_upload.get(k) != before[k]}
            if isinstance(uploaded, UploadReport):
                assert changed == set(NEW) and after_upload == {**before, **stored(NEW)}
            else:                                     # rolled back: nothing half-written
                assert changed == set(), (str(uploaded), changed)
            assert isinstance(uploaded, UploadReport), f"upload did not complete: {uploaded}"
            backed_up = stored(read_param_file(backup))
            assert {k: v for k, v in backed_up.items() if not k.startswith(OWN_COUNTERS)} \
                == before
            restored = restore_params(link, backup)
        time.sleep(SETTLE_S)
        after = on_vehicle(sitl)
    assert set(restored.written) == set(NEW)
    assert after == before
    assert sets.names == set(NEW)       # apmcal wrote nothing but the calibration
    for direction in (proxy.up, proxy.down):
        assert 0.18 < direction.dropped / (direction.dropped + direction.passed) < 0.32
