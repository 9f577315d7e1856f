"""Parameter upload: backed up first, verified by read-back, rolled back on any failure.

A fake link stands in for the vehicle so that every failure mode can be forced; the end-to-end
run against the simulated vehicle is in test_live_sitl.py.
"""
import math
import time

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from apmcal.ardupilot.paramfile import read_param_file, write_param_file
from apmcal.cli import main
from apmcal.core.errors import ApmcalError
from apmcal.link.upload import restore_params, upload_params
from apmcal.sources.live import VehicleLink


class FakeLink:
    """Stores float32 values like ArduPilot; can drop chosen names, or distort their first write.

    ``calls`` scripts the n-th set_param (1-based): "interrupt" (Ctrl-C before it is sent),
    "store_then_interrupt" (Ctrl-C while awaiting the answer to a stored write), "silent" (no
    answer, nothing stored).
    """

    connection = "fake:vehicle"

    def __init__(self, params, drop=(), distort=(), calls=None):
        self.params = {k: float(np.float32(v)) for k, v in params.items()}
        self.drop, self.distort = set(drop), set(distort)
        self.calls = dict(calls or {})
        self.sent = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def fetch_params(self):
        return dict(self.params)

    def read_param(self, name):
        return self.params.get(name)

    def attempts(self, minimum=3):
        return minimum

    def set_param(self, name, value, attempts=3):
        """As VehicleLink.set_param: the value once confirmed, else the last value reported;
        one call is one scripted event whatever ``attempts``."""
        if not math.isfinite(value):    # as VehicleLink.set_param
            raise ApmcalError(f"refusing to send non-finite value {value!r}")
        action = self.calls.get(len(self.sent) + 1)
        if action == "interrupt":
            self.sent.append((name, "interrupted"))
            raise KeyboardInterrupt
        self.sent.append((name, value))
        if action == "silent" or name in self.drop or name not in self.params:
            # ArduPilot drops unknown names silently: only a timeout, then the read-back
            return self.read_param(name)
        error = 0.5 if name in self.distort else 0.0    # a one-off corrupted write
        self.distort.discard(name)
        stored = float(np.float32(value + error))
        self.params[name] = stored
        if action == "store_then_interrupt":
            raise KeyboardInterrupt
        return stored


BEFORE = {"INS_ACCOFFS_X": 0.0, "INS_ACCOFFS_Y": 0.0, "INS_ACCSCAL_X": 1.0, "SYSID_THISMAV": 1}


def test_upload_writes_verifies_and_backs_up(tmp_path):
    link = FakeLink(BEFORE)
    backup = tmp_path / "backup.param"
    report = upload_params(link, {"INS_ACCOFFS_X": 0.123456789, "INS_ACCSCAL_X": 1.01}, backup)
    assert link.params["INS_ACCOFFS_X"] == float(np.float32(0.123456789))
    assert report.written == {"INS_ACCOFFS_X": float(np.float32(0.123456789)),
                              "INS_ACCSCAL_X": float(np.float32(1.01))}
    assert read_param_file(backup) == pytest.approx(BEFORE)


def test_unknown_name_refused_before_anything_is_written(tmp_path):
    link = FakeLink(BEFORE)
    with pytest.raises(ApmcalError, match="COMPASS_DIA_X"):
        upload_params(link, {"INS_ACCOFFS_X": 0.2, "COMPASS_DIA_X": 1.0}, tmp_path / "b.param")
    assert link.sent == []


def test_non_finite_value_refused_before_anything_is_written(tmp_path):
    link = FakeLink(BEFORE)
    with pytest.raises(ApmcalError, match="not finite"):
        upload_params(link, {"INS_ACCOFFS_X": 0.2, "INS_ACCOFFS_Y": float("nan")},
                      tmp_path / "b.param")
    assert link.sent == []


@pytest.mark.parametrize("failure", ["drop", "distort"])
def test_failed_write_rolls_back_everything(tmp_path, failure):
    link = FakeLink(BEFORE, **{failure: ["INS_ACCSCAL_X"]})
    values = {"INS_ACCOFFS_X": 0.3, "INS_ACCOFFS_Y": -0.2, "INS_ACCSCAL_X": 1.05}
    with pytest.raises(ApmcalError, match="rolled back"):
        upload_params(link, values, tmp_path / "b.param")
    assert link.params == {k: float(np.float32(v)) for k, v in BEFORE.items()}


def test_restore_puts_back_the_backup(tmp_path):
    link = FakeLink(BEFORE)
    backup = tmp_path / "b.param"
    upload_params(link, {"INS_ACCOFFS_X": 0.3, "INS_ACCOFFS_Y": -0.2}, backup)
    report = restore_params(link, backup)
    assert set(report.written) == {"INS_ACCOFFS_X", "INS_ACCOFFS_Y"}
    assert link.params == {k: float(np.float32(v)) for k, v in BEFORE.items()}


def test_rollback_that_cannot_be_confirmed_says_how_to_restore(tmp_path):
    link = FakeLink(BEFORE, drop=["INS_ACCSCAL_X"])
    link.read_param = lambda name: None          # the vehicle stops answering altogether
    with pytest.raises(ApmcalError, match="apmcal restore"):
        upload_params(link, {"INS_ACCOFFS_X": 0.3, "INS_ACCSCAL_X": 1.05}, tmp_path / "b.param")


def as_stored(params):
    return {k: float(np.float32(v)) for k, v in params.items()}


# ----------------------------------------------------------------------------- firmware limits
# a 3.3+ parameter table (second IMU, COMPASS_DIA, COMPASS_OFFS_MAX) and a 3.2 one (APM 2.x)
VEHICLE_33 = {**{f"INS_ACC{s}{k}_{a}": v for s in ("", "2") for k, v in (("OFFS", 0.0),
                                                                          ("SCAL", 1.0))
                 for a in "XYZ"},
              **{f"COMPASS_{k}_{a}": v for k, v in (("OFS", 0.0), ("DIA", 1.0), ("ODI", 0.0))
                 for a in "XYZ"},
              "COMPASS_OFFS_MAX": 1800.0}
VEHICLE_32 = {**{f"INS_ACC{k}_{a}": v for k, v in (("OFFS", 0.0), ("SCAL", 1.0)) for a in "XYZ"},
              **{f"COMPASS_OFS_{a}": 0.0 for a in "XYZ"}}


@pytest.mark.parametrize("vehicle, values, name, why", [
    (VEHICLE_33, {"INS_ACCOFFS_X": 0.1, "INS_ACCSCAL_X": 1.25}, "INS_ACCSCAL_X",
     "scale 1.2500 outside 0.8..1.2"),
    (VEHICLE_33, {"INS_ACC2OFFS_Y": -3.6}, "INS_ACC2OFFS_Y", r"\|offset\| 3.600 > 3.5 m/s²"),
    (VEHICLE_33, {"COMPASS_OFS_X": 1900.0}, "COMPASS_OFS_X",
     r"offset vector length 1900.0 > COMPASS_OFFS_MAX 1800 mGauss"),
    # each axis within 1800, the vector not: the pre-arm check compares the length
    (VEHICLE_33, {f"COMPASS_OFS_{a}": 1100.0 for a in "XYZ"}, "COMPASS_OFS_X",
     r"offset vector length 1905.3 > COMPASS_OFFS_MAX"),
    # only Y written, but the vehicle already holds a large X: judged as it will be after
    ({**VEHICLE_33, "COMPASS_OFS_X": 1500.0}, {"COMPASS_OFS_Y": 1200.0}, "COMPASS_OFS_X",
     r"offset vector length 1920.9"),
    (VEHICLE_33, {"COMPASS_DIA_Y": 0.1}, "COMPASS_DIA_Y", "diagonal 0.1000 outside 0.2..5.0"),
    # one DIA written to a vehicle whose other two are 0: a singular matrix after the upload
    ({**VEHICLE_33, "COMPASS_DIA_Y": 0.0, "COMPASS_DIA_Z": 0.0}, {"COMPASS_DIA_X": 1.0},
     "COMPASS_DIA_Y", "diagonal 0.0000 outside 0.2..5.0"),
    (VEHICLE_33, {"COMPASS_ODI_Z": -1.0}, "COMPASS_ODI_Z", "off-diagonal"),
    (VEHICLE_32, {"COMPASS_OFS_Z": 450.0}, "COMPASS_OFS_Z", r"> 400 mGauss"),
    # every axis within 3.2's ±400, the vector beyond config.h's COMPASS_OFFSETS_MAX (600)
    (VEHICLE_32, {f"COMPASS_OFS_{a}": 390.0 for a in "XYZ"}, "COMPASS_OFS_X",
     r"offset vector length 675.5 > the pre-arm limit of this firmware 600 mGauss"),
    (VEHICLE_32, {"INS_ACCSCAL_Y": 1.15}, "INS_ACCSCAL_Y", r"3.2 limit"),
])
def test_out_of_range_value_refused_before_anything_is_written(tmp_path, vehicle, values, name,
                                                               why):
    link = FakeLink(vehicle)
    backup = tmp_path / "b.param"
    with pytest.raises(ApmcalError, match=why) as err:
        upload_params(link, values, backup)
    assert f"param {name}: " in str(err.value) and "nothing was written" in str(err.value)
    assert "\n" not in str(err.value)
    assert link.sent == [] and not backup.exists()


@pytest.mark.parametrize("vehicle, values", [
    (VEHICLE_33, {"INS_ACCSCAL_Y": 1.15, "INS_ACC2OFFS_Z": -3.4}),       # 3.2's limit only
    ({**VEHICLE_33, "COMPASS_OFFS_MAX": 2500.0}, {"COMPASS_OFS_X": 1900.0}),
    (VEHICLE_33, {f"COMPASS_DIA_{a}": 0.0 for a in "XYZ"}),    # all zero: firmware's "unset"
])
def test_in_range_values_are_written(tmp_path, vehicle, values):
    link = FakeLink(vehicle)
    report = upload_params(link, values, tmp_path / "b.param")
    assert report.written == as_stored(values)


def test_cli_upload_refuses_out_of_range_param_file_in_one_line(tmp_path, capsys, monkeypatch):
    import apmcal.sources.live

    link = FakeLink(VEHICLE_33)
    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", lambda connection, **kw: link)
    param = tmp_path / "new.param"
    param.write_text("INS_ACCOFFS_X 0.1\nINS_ACCSCAL_Z 0.7\n")
    backup = tmp_path / "b.param"
    assert main(["upload", "fake:vehicle", str(param), "--backup", str(backup)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "param INS_ACCSCAL_Z: scale 0.7000 outside 0.8..1.2" in err[0]
    assert link.sent == [] and not backup.exists()


# ----------------------------------------------------------------------------- restore
def test_restore_reports_names_the_vehicle_does_not_have(tmp_path):
    link = FakeLink(BEFORE)
    backup = tmp_path / "b.param"
    write_param_file(backup, {**BEFORE, "INS_ACCOFFS_X": 0.4, "INS_ACC3OFFS_X": 3.0,
                              "COMPASS_OFS2_Y": 1.0})
    report = restore_params(link, backup)
    assert report.skipped == ["COMPASS_OFS2_Y", "INS_ACC3OFFS_X"]
    assert report.written == {"INS_ACCOFFS_X": float(np.float32(0.4))}
    assert [n for n, _ in link.sent] == ["INS_ACCOFFS_X"]


def test_restore_tries_every_name_then_lists_all_failures(tmp_path):
    link = FakeLink(BEFORE, drop=["INS_ACCOFFS_X", "INS_ACCSCAL_X"])
    backup = tmp_path / "b.param"
    wanted = {**BEFORE, "INS_ACCOFFS_X": 0.4, "INS_ACCOFFS_Y": -0.3, "INS_ACCSCAL_X": 1.02}
    write_param_file(backup, wanted)
    with pytest.raises(ApmcalError, match="restore not confirmed for 2 of 3") as err:
        restore_params(link, backup)
    assert "INS_ACCOFFS_X" in str(err.value) and "INS_ACCSCAL_X" in str(err.value)
    assert link.params["INS_ACCOFFS_Y"] == float(np.float32(-0.3))   # tried after a failure


def test_restore_of_names_not_in_the_backup_refused_before_writing(tmp_path):
    link = FakeLink(BEFORE)
    backup = tmp_path / "b.param"
    write_param_file(backup, {**BEFORE, "INS_ACCOFFS_X": 0.4})
    with pytest.raises(ApmcalError, match="not in the backup: NOPE"):
        restore_params(link, backup, names=["INS_ACCOFFS_X", "NOPE"])
    assert link.sent == []


# ----------------------------------------------------------------------------- NaN on the vehicle
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_non_finite_vehicle_value_backed_up_as_comment_and_not_restored(tmp_path, bad):
    from pymavlink.mavparm import MAVParmDict

    link = FakeLink({**BEFORE, "BARO_ODD": bad})
    backup = tmp_path / "b.param"
    upload_params(link, {"INS_ACCOFFS_X": 0.3}, backup)
    text = backup.read_text().splitlines()
    assert f"# BARO_ODD {bad!r} (not finite on the vehicle; not restorable)" in text
    assert read_param_file(backup) == pytest.approx(BEFORE)       # still loads, without it
    mavproxy = MAVParmDict()
    mavproxy.load(str(backup))
    assert "BARO_ODD" not in mavproxy and len(mavproxy) == len(BEFORE)
    link.sent.clear()
    report = restore_params(link, backup)
    assert report.unrestorable == ["BARO_ODD"] and report.skipped == []
    assert [n for n, _ in link.sent] == ["INS_ACCOFFS_X"]
    assert link.params["INS_ACCOFFS_X"] == 0.0


def test_rollback_does_not_send_a_non_finite_previous_value(tmp_path):
    link = FakeLink({**BEFORE, "INS_ACCOFFS_Y": float("nan")}, drop=["INS_ACCSCAL_X"])
    with pytest.raises(ApmcalError, match=r"INS_ACCOFFS_Y \(held a non-finite value") as err:
        upload_params(link, {"INS_ACCOFFS_Y": 0.2, "INS_ACCSCAL_X": 1.05}, tmp_path / "b.param")
    assert "apmcal restore" in str(err.value)
    assert link.params["INS_ACCSCAL_X"] == 1.0


# ----------------------------------------------------------------------------- Ctrl-C
VALUES = {"INS_ACCOFFS_X": 0.3, "INS_ACCOFFS_Y": -0.2, "INS_ACCSCAL_X": 1.05}


def interrupted_upload(link, backup) -> ApmcalError:
    """The ApmcalError upload_params raises; a KeyboardInterrupt escaping it fails the test
    (instead of stopping pytest)."""
    try:
        upload_params(link, VALUES, backup)
    except ApmcalError as err:
        return err
    except KeyboardInterrupt:
        pytest.fail("KeyboardInterrupt escaped upload_params")
    pytest.fail("upload_params did not raise")


@pytest.mark.parametrize("call, action", [(2, "interrupt"), (2, "store_then_interrupt"),
                                          (3, "store_then_interrupt"), (1, "store_then_interrupt")])
def test_interrupted_upload_is_rolled_back(tmp_path, call, action):
    link = FakeLink(BEFORE, calls={call: action})
    backup = tmp_path / "b.param"
    err = interrupted_upload(link, backup)
    assert str(err) == f"fake:vehicle: interrupted; all changes rolled back from {backup}"
    assert link.params == as_stored(BEFORE)


@pytest.mark.parametrize("rollback", ["interrupt", "silent"])
def test_interrupted_upload_whose_rollback_fails_names_the_restore_command(tmp_path, rollback):
    # Ctrl-C on the second write; the first put-back is interrupted again, or goes unanswered
    link = FakeLink(BEFORE, calls={2: "store_then_interrupt", 3: rollback})
    link.read_param = lambda name: None          # unanswered put-backs stay unconfirmed
    backup = tmp_path / "b.param"
    err = str(interrupted_upload(link, backup))
    assert err.startswith("fake:vehicle: interrupted; rollback")
    assert err.endswith(f"restore with 'apmcal restore fake:vehicle {backup}'")


# ----------------------------------------------------------------------------- fetch_params
class FakeMaster:
    """pymavlink's side of a vehicle with ``n`` parameters: PARAM_REQUEST_LIST answers all but
    ``lost`` indices; PARAM_REQUEST_READ by index answers all but ``never``."""

    def __init__(self, n, lost=(), never=(), lists_ignored=0):
        self.n, self.lost, self.never = n, set(lost), set(never)
        self.queue, self.reads = [], []
        self.lists_ignored, self.lists = lists_ignored, 0     # the first requests go unanswered
        self.mav = self

    def _value(self, index, reported_index=None, component=1, count=None):
        msg = mavlink.MAVLink_param_value_message(
            f"P{index}".encode(), float(index), mavlink.MAV_PARAM_TYPE_REAL32,
            self.n if count is None else count,
            index if reported_index is None else reported_index)
        msg._header = mavlink.MAVLink_header(msg.id, srcSystem=1, srcComponent=component)
        return msg

    def param_request_list_send(self, target_system, target_component):
        self.lists += 1
        if self.lists <= self.lists_ignored:
            return
        self.queue += [self._value(i) for i in range(self.n) if i not in self.lost]
        self.queue.append(self._value(0, reported_index=65535))   # another GCS's read answered

    def param_request_read_send(self, target_system, target_component, param_id, param_index):
        assert param_id == b"" and param_index >= 0        # by index, not by name
        self.reads.append(param_index)
        if param_index not in self.never:
            self.queue.append(self._value(param_index))

    def recv_match(self, blocking=True, timeout=None):
        if self.queue:
            return self.queue.pop(0)
        time.sleep(min(timeout or 0.01, 0.01))
        return None


def link_to(master):
    link = VehicleLink.__new__(VehicleLink)      # no socket, no HEARTBEAT
    link.master, link.connection, link._tlog = master, "fake:vehicle", None
    link._mavutil = mavutil
    link.target_system, link.target_component = 1, 1
    return link


def test_fetch_params_asks_for_lost_indices_one_by_one():
    master = FakeMaster(50, lost=[3, 17, 49])
    params = link_to(master).fetch_params(idle_s=0.05)
    assert params == {f"P{i}": float(i) for i in range(50)}
    assert master.reads == [3, 17, 49]


class LatentMaster(FakeMaster):
    """A FakeMaster whose answers to reads arrive ``latency_s`` after the request, the first
    request of each index in ``first_read_lost`` going unanswered; notes when each read was
    sent and how many reads were out before the first answer arrived."""

    def __init__(self, n, lost, first_read_lost, latency_s):
        super().__init__(n, lost)
        self.first_read_lost, self.latency_s = set(first_read_lost), latency_s
        self.pending, self.sent_at = [], {}
        self.reads_before_first_answer = None

    def param_request_read_send(self, target_system, target_component, param_id, param_index):
        self.reads.append(param_index)
        self.sent_at.setdefault(param_index, []).append(time.monotonic())
        if param_index in self.first_read_lost and self.reads.count(param_index) == 1:
            return
        self.pending.append((time.monotonic() + self.latency_s, self._value(param_index)))

    def recv_match(self, blocking=True, timeout=None):
        due = [p for p in self.pending if p[0] <= time.monotonic()]
        if due and not self.queue:
            self.pending.remove(due[0])
            if self.reads_before_first_answer is None:
                self.reads_before_first_answer = len(self.reads)
            return due[0][1]
        return super().recv_match(blocking, timeout)


def test_fetch_params_pipelines_reads_and_asks_again_after_the_measured_round_trip():
    """Many indices lost from the list: the reads go out READS_IN_FLIGHT at a time (ArduPilot
    queues at most 20), and a read whose answer is lost is asked again after a wait set by the
    measured round trip (20 ms here), not after answer_timeout_s (2 s)."""
    from apmcal.link.params import READS_IN_FLIGHT

    lost = range(0, 300, 2)
    master = LatentMaster(300, lost, first_read_lost=lost[::5], latency_s=0.02)
    link = link_to(master)
    link.answer_timeout_s = 2.0
    params = link.fetch_params(idle_s=0.05)
    assert params == {f"P{i}": float(i) for i in range(300)}
    assert master.reads_before_first_answer == READS_IN_FLIGHT
    waits = [sent[1] - sent[0] for i, sent in master.sent_at.items() if len(sent) > 1]
    assert sorted(master.sent_at) == list(lost) and len(waits) == len(lost[::5])
    assert max(waits) < 0.5, waits


def test_fetch_params_refuses_a_partial_set():
    master = FakeMaster(50, lost=[3, 17, 49], never=[17, 49])
    with pytest.raises(ApmcalError, match=r"2 of 50 parameters never arrived \(param_index 17, "
                                          r"49\)"):
        link_to(master).fetch_params(idle_s=0.05, retries=2, reads_per_index=2)
    assert master.reads == [3, 17, 49, 17, 49]            # each asked for twice


def test_fetch_params_sends_an_unanswered_list_request_again():
    master = FakeMaster(5, lists_ignored=2)
    assert len(link_to(master).fetch_params(idle_s=0.05, retries=2)) == 5
    assert master.lists == 3


def test_list_requests_are_sent_as_often_as_the_downlink_loss_calls_for():
    """A quarter of the vehicle's packets missing (pymavlink's sequence-number count): the
    way up is taken to lose as many, so the list request is tried 10 times (0.25^10 < 1e-6),
    and five lost ones are survived; on a clean link three tries are all."""
    master = FakeMaster(5, lists_ignored=5)
    master.mav_loss, master.mav_count = 25, 75
    assert len(link_to(master).fetch_params(idle_s=0.02)) == 5
    assert master.lists == 6
    clean = FakeMaster(5, lists_ignored=99)
    clean.mav_loss, clean.mav_count = 0, 1000
    with pytest.raises(ApmcalError, match="vehicle sent no parameters"):
        link_to(clean).fetch_params(idle_s=0.02)
    assert clean.lists == 3


def test_fetch_params_from_a_silent_vehicle_is_one_clear_error():
    master = FakeMaster(5, lists_ignored=99)
    with pytest.raises(ApmcalError, match="vehicle sent no parameters"):
        link_to(master).fetch_params(idle_s=0.05, retries=2)
    assert master.lists == 3


def test_fetch_params_ignores_another_components_parameter_list():
    """A gimbal (component 154) answers the same request with its own, shorter list: neither its
    values nor its param_count may enter the autopilot's set."""
    master = FakeMaster(5, lost=[4])
    send_list = master.param_request_list_send

    def with_gimbal(*args):
        send_list(*args)
        master.queue[:0] = [master._value(i + 100, component=154, count=2, reported_index=i)
                            for i in range(2)]
    master.param_request_list_send = with_gimbal
    params = link_to(master).fetch_params(idle_s=0.05)
    assert params == {f"P{i}": float(i) for i in range(5)}
    assert master.reads == [4]


def _heartbeat(component, autopilot):
    msg = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GIMBAL if autopilot == 8 else
                                            mavlink.MAV_TYPE_QUADROTOR, autopilot, 0, 0, 4, 3)
    msg._header = mavlink.MAVLink_header(msg.id, srcSystem=1, srcComponent=component)
    return msg


def test_the_target_is_the_autopilot_not_the_first_heartbeat():
    master = FakeMaster(0)
    master.queue = [_heartbeat(154, mavlink.MAV_AUTOPILOT_INVALID),
                    _heartbeat(1, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)]
    link = link_to(master)
    link.target_system = link.target_component = None
    link.wait_heartbeat(1.0)
    assert (link.target_system, link.target_component) == (1, 1)


def test_only_non_autopilot_heartbeats_is_one_clear_error():
    master = FakeMaster(0)
    master.queue = [_heartbeat(154, mavlink.MAV_AUTOPILOT_INVALID)]
    with pytest.raises(ApmcalError, match="no autopilot HEARTBEAT within 0.3 s"):
        link_to(master).wait_heartbeat(0.3)


# ----------------------------------------------------------------------------- set_param
class VectorVehicle:
    """pymavlink's side of an ArduPilot holding one Vector3f, FOO_X/Y/Z: a set of FOO_X is
    answered with _X, _Y and _Z (ArduPilot's AP_Param::send_parameter, issue 9). ``lose``
    lists the PARAM_SETs (1-based) that never arrive."""

    def __init__(self, lose=()):
        self.values = {f"FOO_{a}": 0.0 for a in "XYZ"}
        self.queue, self.sets, self.reads, self.lose = [], 0, [], set(lose)
        self.mav = self

    def _value(self, name):
        msg = mavlink.MAVLink_param_value_message(name.encode(), self.values[name],
                                                  mavlink.MAV_PARAM_TYPE_REAL32, 3, 65535)
        msg._header = mavlink.MAVLink_header(msg.id, srcSystem=1, srcComponent=1)
        return msg

    def param_set_send(self, target_system, target_component, name, value, kind):
        self.sets += 1
        if self.sets in self.lose:
            return
        name = name.decode()
        self.values[name] = float(np.float32(value))
        echoed = [f"FOO_{a}" for a in "XYZ"] if name.endswith("_X") else [name]
        self.queue += [self._value(n) for n in echoed]

    def param_request_read_send(self, target_system, target_component, name, index):
        self.reads.append(name.decode())
        self.queue.append(self._value(name.decode()))

    def recv_match(self, blocking=True, timeout=None):
        return self.queue.pop(0) if self.queue else time.sleep(min(timeout or 0.01, 0.01))


def test_set_param_is_not_answered_by_the_stale_echo_of_another_element():
    vehicle = VectorVehicle()
    link = link_to(vehicle)
    link.answer_timeout_s = 0.2
    assert link.set_param("FOO_X", 0.5) == float(np.float32(0.5))
    # FOO_Y (0.0) from the FOO_X write is still queued, before the answer to this write
    assert link.set_param("FOO_Y", -0.25) == -0.25
    assert vehicle.sets == 2 and vehicle.reads == []


def test_set_param_reads_back_and_writes_again_when_the_set_is_lost():
    vehicle = VectorVehicle(lose=[2])
    link = link_to(vehicle)
    link.answer_timeout_s = 0.2
    link.set_param("FOO_X", 0.5)
    # the FOO_Y set is lost: only the stale FOO_Y = 0 arrives; the read-back says 0 too
    assert link.set_param("FOO_Y", -0.25) == -0.25
    assert vehicle.sets == 3 and vehicle.reads == ["FOO_Y"]
    assert vehicle.values["FOO_Y"] == -0.25


def test_set_param_reports_what_the_vehicle_holds_when_never_confirmed():
    vehicle = VectorVehicle(lose=[1, 2, 3])
    link = link_to(vehicle)
    link.answer_timeout_s = 0.05
    assert link.set_param("FOO_Z", 2.0, attempts=3) == 0.0   # last read-back: the old value
    assert vehicle.sets == 3 and vehicle.reads == ["FOO_Z"] * 3


def test_set_param_tries_as_often_as_the_loss_seen_calls_for():
    """By default the tries are sized by the link's loss: 44 % of round trips lost (25 % each
    way) calls for 17 tries (0.44^17 < 1e-6), so 16 lost sets are survived; a clean link's
    record calls for few."""
    vehicle = VectorVehicle(lose=range(1, 17))
    link = link_to(vehicle)
    link.answer_timeout_s = 0.02
    link.round_trips.answered, link.round_trips.lost = 560, 440
    assert link.attempts() == 17
    assert link.set_param("FOO_Z", 2.0) == 2.0
    assert vehicle.sets == 17
    clean = link_to(VectorVehicle())
    clean.round_trips.answered = 1000
    assert clean.attempts() == 3


# ----------------------------------------------------------------------------- scope
def test_restore_writes_calibration_only_and_never_counters(tmp_path):
    vehicle = {**BEFORE, "SERIAL1_BAUD": 57.0, "STAT_RUNTIME": 600.0, "STAT_BOOTCNT": 7.0}
    backup = tmp_path / "b.param"
    write_param_file(backup, {**vehicle, "INS_ACCOFFS_X": 0.4, "SERIAL1_BAUD": 115.0,
                              "STAT_RUNTIME": 30.0, "STAT_BOOTCNT": 3.0})
    link = FakeLink(vehicle)
    report = restore_params(link, backup)
    assert [n for n, _ in link.sent] == ["INS_ACCOFFS_X"]
    assert report.left_out == ["SERIAL1_BAUD", "STAT_BOOTCNT", "STAT_RUNTIME"]
    link = FakeLink(vehicle)
    report = restore_params(link, backup, all_params=True)
    assert sorted(n for n, _ in link.sent) == ["INS_ACCOFFS_X", "SERIAL1_BAUD"]
    assert report.left_out == ["STAT_BOOTCNT", "STAT_RUNTIME"]
    with pytest.raises(ApmcalError, match="param STAT_RUNTIME: a counter"):
        restore_params(FakeLink(vehicle), backup, names=["STAT_RUNTIME"], all_params=True)


@pytest.mark.parametrize("name, all_params, why", [
    ("SYSID_THISMAV", False, "not a calibration parameter"),
    ("STAT_BOOTCNT", True, "a counter or identity the vehicle keeps itself")])
def test_upload_out_of_scope_refused_before_anything_is_written(tmp_path, name, all_params, why):
    link = FakeLink({**BEFORE, "STAT_BOOTCNT": 1.0})
    backup = tmp_path / "b.param"
    with pytest.raises(ApmcalError, match=f"param {name}: {why}"):
        upload_params(link, {"INS_ACCOFFS_X": 0.2, name: 2.0}, backup, all_params=all_params)
    assert link.sent == [] and not backup.exists()
