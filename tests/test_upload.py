"""Parameter upload: backed up first, verified by read-back, rolled back on any failure.

A fake link stands in for the vehicle so that every failure mode can be forced; the end-to-end
run against the simulated vehicle is in test_live_sitl.py.
"""
import numpy as np
import pytest

from apmcal.errors import ApmcalError
from apmcal.vehicle.paramfile import read_param_file
from apmcal.vehicle.upload import restore_params, upload_params


class FakeLink:
    """Stores float32 values like ArduPilot; can drop chosen names, or distort their first write."""

    connection = "fake:vehicle"

    def __init__(self, params, drop=(), distort=()):
        self.params = {k: float(np.float32(v)) for k, v in params.items()}
        self.drop, self.distort = set(drop), set(distort)
        self.sent = []

    def fetch_params(self):
        return dict(self.params)

    def read_param(self, name):
        return self.params.get(name)

    def set_param(self, name, value):
        self.sent.append((name, value))
        if name in self.drop or name not in self.params:
            return None            # ArduPilot drops unknown names silently: only a timeout
        error = 0.5 if name in self.distort else 0.0    # a one-off corrupted write
        self.distort.discard(name)
        stored = float(np.float32(value + error))
        self.params[name] = stored
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
