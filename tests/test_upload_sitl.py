"""Upload and restore against the simulated vehicle (in-process, loopback UDP), also through a
proxy losing a quarter of the packets each way (issue 9).

The simulated vehicle answers a set of a vector's _X with _X, _Y and _Z, as ArduPilot does
(apmcal_sim.params_store.ParamStore.answered_set_with): the echo of the _X write carries _Y's old value
and arrives before the answer to the _Y write.
"""
from __future__ import annotations

import re
import time

import numpy as np
import pytest
from lossy_udp import ServedVehicle, free_udp_port, vehicle_behind_lossy_link
from sitl_helpers import only

from apmcal.ardupilot.paramfile import read_param_file, write_param_file
from apmcal.cli import main
from apmcal.core.errors import ApmcalError
from apmcal.link.upload import UploadReport, restore_params, upload_params
from apmcal.sources.live import VehicleLink
from apmcal_sim.vehicle import SimVehicle

NEW = {"INS_ACCOFFS_X": 0.31, "INS_ACCOFFS_Y": -0.27, "INS_ACCOFFS_Z": 0.52,
       "COMPASS_OFS_X": 41.5, "COMPASS_OFS_Y": -63.25, "COMPASS_OFS_Z": 120.0}
LOSS = 0.25
# loopback answers come within milliseconds: a generous wait, yet short enough that the many
# lost answers of a lossy link do not make the tests slow
ANSWER_TIMEOUT_S = 0.3
SETTLE_S = 0.5      # time for a PARAM_SET still on its way to reach the vehicle before checking


def as_stored(values: dict) -> dict:
    return {k: float(np.float32(v)) for k, v in values.items()}


def upload_through(connection: str, values: dict, backup) -> UploadReport | ApmcalError:
    """The report of an upload, or the error it ended with."""
    try:
        with VehicleLink(connection) as link:
            link.answer_timeout_s = ANSWER_TIMEOUT_S
            return upload_params(link, values, backup)
    except ApmcalError as err:
        return err


def lossy_upload(values: dict, seed: int, tmp_path):
    """(outcome, parameters before, parameters after, PARAM_SETs received, proxy)."""
    with vehicle_behind_lossy_link(LOSS, seed) as (connection, served, proxy):
        before = served.params.as_dict()
        outcome = upload_through(connection, values, tmp_path / "backup.param")
        time.sleep(SETTLE_S)
        after = served.params.as_dict()
    return outcome, before, after, served.sets, proxy


def rollback_claims(message: str) -> dict[str, str]:
    """Name -> what the message says of it, from 'rollback not confirmed for A (vehicle
    reports 0.3), B (no answer): ...' (or any 'rollback ... for A, B: ...')."""
    listed = re.search(r"rollback [a-z ]+ for (.*?): restore with", message)
    assert listed, message
    return {m.group(1): m.group(2) or "failed"
            for m in re.finditer(r"([A-Z0-9_]+)(?: \(([^)]*)\))?", listed.group(1))}


def check_all_or_nothing(outcome, before: dict, after: dict, values: dict) -> None:
    """Every value verified, or every name back at its value before; and the message says
    which, truthfully."""
    new = as_stored(values)
    if isinstance(outcome, UploadReport):
        assert outcome.written == new
        assert {n: after[n] for n in new} == new, "reported verified, but the vehicle differs"
        return
    message = str(outcome)
    assert "\n" not in message
    if "all changes rolled back" in message:
        assert {n: after[n] for n in new} == {n: before[n] for n in new}, message
        return
    claims = rollback_claims(message)
    for name in new:
        said = claims.get(name)
        if said is None:        # not listed: put back
            assert after[name] == before[name], (name, message)
        elif said.startswith("vehicle reports "):
            assert after[name] == float(said.split()[-1]), (name, message)
        elif said == "no answer":       # unknown, but never a third value
            assert after[name] in (before[name], new[name]), (name, message)
        else:                   # said to have failed
            assert after[name] != before[name], (name, message)


def test_upload_of_whole_vectors_is_verified(tmp_path):
    """Issue 9: the stale _Y echo of the _X write is not taken for the answer to the _Y write."""
    with vehicle_behind_lossy_link(0.0, 0) as (connection, served, _):
        outcome = upload_through(connection, NEW, tmp_path / "backup.param")
        time.sleep(SETTLE_S)
        after = served.params.as_dict()
    assert isinstance(outcome, UploadReport), str(outcome)
    assert outcome.written == as_stored(NEW)
    assert {n: after[n] for n in NEW} == as_stored(NEW)


@pytest.mark.parametrize("seed", [1, 2])
def test_upload_through_lossy_link_is_all_or_nothing(tmp_path, seed):
    outcome, before, after, sets, proxy = lossy_upload(NEW, seed, tmp_path)
    assert sets, f"no PARAM_SET reached the vehicle: {outcome}"   # got past the backup
    assert proxy.up.dropped and proxy.down.dropped                # loss both ways
    assert 0.1 < proxy.down.dropped / (proxy.down.dropped + proxy.down.passed) < 0.4
    check_all_or_nothing(outcome, before, after, NEW)


def test_refused_write_through_lossy_link_rolls_back_everything(tmp_path):
    """The last value is refused (a rotation the simulator does not model: the set is dropped
    and the old value read back), so the six written before must all be put back, through the
    same lossy link."""
    values = {**NEW, "AHRS_ORIENTATION": 37}
    outcome, before, after, sets, proxy = lossy_upload(values, 3, tmp_path)
    assert isinstance(outcome, ApmcalError), "the refused value was reported verified"
    assert "param AHRS_ORIENTATION: write of 37 not confirmed" in str(outcome)
    assert {n for n, _ in sets} >= set(values)
    check_all_or_nothing(outcome, before, after, values)
    assert after["AHRS_ORIENTATION"] == before["AHRS_ORIENTATION"]


@pytest.mark.parametrize("seed", [11, 12])
def test_upload_and_restore_of_a_full_size_vehicle_through_a_lossy_link(tmp_path, seed):
    """A real vehicle's 1,349 parameters, a quarter of the packets lost each way: the download
    (twice: upload's backup, restore's comparison) no longer runs out of time, so upload and
    restore both complete, each value verified on the vehicle itself; were either to fail, no
    value may be left half-written."""
    with vehicle_behind_lossy_link(LOSS, seed, full_params=True) as (connection, served, proxy):
        before = served.params.as_dict()
        assert len(before) == 1349
        backup = tmp_path / "backup.param"
        with VehicleLink(connection) as link:     # its default waits: the measured RTT's
            try:
                uploaded = upload_params(link, NEW, backup)
            except ApmcalError as err:
                uploaded = err
            time.sleep(SETTLE_S)
            after_upload = served.params.as_dict()
            check_all_or_nothing(uploaded, before, after_upload, NEW)
            assert isinstance(uploaded, UploadReport), f"upload did not complete: {uploaded}"
            assert as_stored(read_param_file(backup)) == before     # complete, and right
            restored = restore_params(link, backup)
        time.sleep(SETTLE_S)
        after = served.params.as_dict()
    assert restored.written == {n: before[n] for n in NEW}
    assert after == {**before, "STAT_RUNTIME": after["STAT_RUNTIME"]}
    for direction in (proxy.up, proxy.down):
        assert 0.18 < direction.dropped / (direction.dropped + direction.passed) < 0.32


WRITTEN = {**NEW, "INS_GYROFFS_X": 0.01, "INS_GYROFFS_Y": -0.02, "INS_GYROFFS_Z": 0.015,
           "INS_ACCSCAL_X": 1.01, "INS_ACCSCAL_Y": 0.99, "INS_ACCSCAL_Z": 1.002}


def test_a_link_that_turns_lossy_after_the_download_is_believed_at_once(tmp_path):
    """A clean download, then a quarter of the packets lost each way while writing (a radio
    at the edge of its range): the tries per write follow the loss of the recent round
    trips, not the clean record, so all of 4 uploads of 12 values complete, each verified on
    the vehicle (with 3 tries per write, as before, 2 of the 4 were rolled back)."""
    completed = []
    for seed in range(4):
        with vehicle_behind_lossy_link(0.0, seed) as (connection, served, proxy):
            before = served.params.as_dict()
            with VehicleLink(connection) as link:
                params = link.fetch_params()
                proxy.up.loss = proxy.down.loss = LOSS
                try:
                    outcome = upload_params(link, WRITTEN, tmp_path / f"b{seed}.param",
                                            vehicle_params=params)
                except ApmcalError as err:
                    outcome = err
            time.sleep(SETTLE_S)
            after = served.params.as_dict()
        check_all_or_nothing(outcome, before, after, WRITTEN)
        completed.append(isinstance(outcome, UploadReport) or str(outcome))
    assert completed == [True] * 4, completed


# ----------------------------------------------------------------------------- restore
def serve_on(port: int, param_file):
    return ServedVehicle(f"udpout:127.0.0.1:{port}", param_file)


def test_restore_writes_no_counters_and_reports_no_false_failures(tmp_path, capsys):
    """A backup (as upload writes it), a calibration, a reboot (STAT_BOOTCNT counts up), then
    restore: the calibration comes back, verified, exit status 0; the counters are left as the
    vehicle keeps them."""
    port, eeprom, backup = free_udp_port(), tmp_path / "eeprom.json", tmp_path / "backup.param"
    connection = f"udpin:127.0.0.1:{port}"
    vehicle = SimVehicle(only(), "onepos", "3.3", param_file=eeprom)
    backed_up = vehicle.params.as_dict()
    write_param_file(backup, backed_up, comment_non_finite=True)
    for name, value in NEW.items():          # the calibration (saved to the vehicle's EEPROM)
        vehicle.params.set(name, value)
    with serve_on(port, eeprom) as served:           # the next boot
        booted = served.params.as_dict()
        assert booted["STAT_BOOTCNT"] == backed_up["STAT_BOOTCNT"] + 1
        assert {n: booted[n] for n in NEW} == as_stored(NEW)
        status = main(["restore", connection, str(backup)])
        time.sleep(SETTLE_S)
        after = served.params.as_dict()
    out, err = capsys.readouterr()
    assert status == 0, err
    assert f"restored {len(NEW)} parameters" in out
    assert {n: after[n] for n in NEW} == {n: backed_up[n] for n in NEW}
    assert not [n for n, _ in served.sets if n.startswith("STAT_")]
    assert after["STAT_BOOTCNT"] == booted["STAT_BOOTCNT"]
    assert "STAT_BOOTCNT" in out                       # named as left as it is


def test_restore_all_params_still_writes_no_counters(tmp_path):
    port, eeprom, backup = free_udp_port(), tmp_path / "eeprom.json", tmp_path / "backup.param"
    connection = f"udpin:127.0.0.1:{port}"
    with serve_on(port, eeprom) as served:
        before = served.params.as_dict()
    write_param_file(backup, {**before, "COMPASS_LEARN": 1.0, "STAT_RUNTIME": 99.0})
    with serve_on(port, eeprom) as served:
        assert main(["restore", connection, str(backup), "--all-params"]) == 0
        time.sleep(SETTLE_S)
        after = served.params.as_dict()
    assert after["COMPASS_LEARN"] == 1.0
    assert [n for n, _ in served.sets] == ["COMPASS_LEARN"]       # not STAT_BOOTCNT/RUNTIME


def test_restore_of_a_missing_file_fails_at_once_naming_it(tmp_path, capsys, monkeypatch):
    import apmcal.sources.live

    def no_connection(*args, **kwargs):
        raise AssertionError("connected before checking the file")
    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", no_connection)
    missing = tmp_path / "nope.param"
    assert main(["restore", "udpin:127.0.0.1:1", str(missing)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and str(missing) in err[0] and "no such parameter file" in err[0]


def test_upload_of_a_counter_refused_before_connecting(tmp_path, capsys, monkeypatch):
    import apmcal.sources.live

    def no_connection(*args, **kwargs):
        raise AssertionError("connected before checking the file")
    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", no_connection)
    param = tmp_path / "new.param"
    param.write_text("INS_ACCOFFS_X 0.1\nSTAT_RUNTIME 5\n")
    assert main(["upload", "udpin:127.0.0.1:1", str(param), "--all-params"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and f"{param}: param STAT_RUNTIME: " in err[0]
    param.write_text("INS_ACCOFFS_X 0.1\nSERIAL1_BAUD 57\n")
    assert main(["upload", "udpin:127.0.0.1:1", str(param)]) == 2
    err = capsys.readouterr().err
    assert "param SERIAL1_BAUD: not a calibration parameter" in err and "--all-params" in err


@pytest.mark.parametrize("command, words", [
    ("upload", ["backup", "verified", "put back", "--all-params", "param_file"]),
    ("restore", ["backup", "read-back", "STAT_", "--all-params", "backup_file"])])
def test_upload_and_restore_have_help(capsys, command, words):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for word in words:
        assert word in text
