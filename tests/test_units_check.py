"""Issue 9: units checked against physics. ArduPilot firmware of about May 2024 - Feb 2026 sent
HIGHRES_IMU's magnetic field in mGauss×1000 instead of gauss; apmcal, which prefers HIGHRES_IMU,
proposed compass offsets of 1e8 mGauss. Now that compass is dropped with a warning, the compass
comes from RAW_IMU, and the accelerometer and gyro results do not change."""
import json

import numpy as np
import pandas as pd
import pytest

from apmcal.cli import main
from apmcal.core.errors import ApmcalError
from apmcal.core.recording import LogContents, Recording
from apmcal.sensor_model.truth import Truth
from apmcal_sim import motion
from apmcal_sim.makelog import START_UNIX, write_tlog
from apmcal_sim.vehicle import FAULTY_HIGHRES_MAG_PER_MGAUSS, SimVehicle


def short_ferraris_tlog(path, faulty_highres_mag: bool) -> None:
    """A short Ferraris session (six faces, three 360° turns: the compass turns through space)
    on firmware 3.3 with RAW_IMU and HIGHRES_IMU at 25 Hz."""
    truth = Truth.random(7).with_effects(disable=["motion_contamination", "temperature_drift"])
    v = SimVehicle(truth, "ferraris", "3.3", None, fs=100.0, seed=7, start_unix=START_UNIX)
    v.motion = motion.ferraris(hold=6.0, pause=4.0)
    v.params.set("INS_GYR_CAL", 0, save=False)
    v._boot_gyro = None                       # neutral parameters, as apmcal_sim.makelog makes them
    if faulty_highres_mag:
        v.highres_mag_per_mgauss = FAULTY_HIGHRES_MAG_PER_MGAUSS
    write_tlog(v, path, 25.0, v.motion.duration + 1.0, highres=True)


def calibrate(tlog, out_json, quiet=True) -> dict:
    assert main(["log", str(tlog), "--lat", "5.6037", "--lon", "-0.187", "--json",
                 str(out_json), *(["--quiet"] if quiet else [])]) in (0, 1)
    return json.loads(out_json.read_text())


def test_faulty_highres_compass_is_dropped_and_raw_imu_used(tmp_path, capsys):
    short_ferraris_tlog(tmp_path / "good.tlog", faulty_highres_mag=False)
    short_ferraris_tlog(tmp_path / "faulty.tlog", faulty_highres_mag=True)
    good = calibrate(tmp_path / "good.tlog", tmp_path / "good.json")
    faulty = calibrate(tmp_path / "faulty.tlog", tmp_path / "faulty.json", quiet=False)
    printed = capsys.readouterr().out
    assert "on HIGHRES_IMU (IMU instance 0); compass from RAW_IMU (instance 0)" in printed

    # the user is told which message, what magnitude and why
    warnings = [n for n in faulty["summary"]["notes"] if "HIGHRES_IMU[0] mag" in n]
    assert len(warnings) == 1, faulty["summary"]["notes"]
    assert "e+08 mGauss" in warnings[0] and "mGauss×1000" in warnings[0]
    assert not any("HIGHRES_IMU" in n for n in good["summary"]["notes"])

    # accelerometer and gyro: the same HIGHRES_IMU samples, the same results
    used = "HIGHRES_IMU (IMU instance 0)"
    assert good["report"]["recording"] == used
    # and the compass's source named, where the report says what was used
    assert faulty["report"]["recording"] == used + "; compass from RAW_IMU (instance 0)"
    for sensor in ("acc", "gyr"):
        assert faulty[sensor] == good[sensor]
    for name, value in good["params"].items():
        if not name.startswith("COMPASS_"):
            assert faulty["params"][name] == value

    # compass: RAW_IMU's (integer mGauss), close to the good HIGHRES_IMU's and proposed
    assert np.allclose(faulty["mag"]["offset"], good["mag"]["offset"], atol=3.0)
    assert abs(faulty["params"]["COMPASS_OFS_X"]) < 1000
    assert not any(n.startswith("COMPASS_") for n in faulty["rejected_params"])


def recording(message, acc_m_s2=None, gyr_rad_s=None, mag_mgauss=None, n=200):
    rng = np.random.default_rng(0)
    data = {"t": np.arange(n) * 0.02}
    for prefix, vector in (("acc", acc_m_s2), ("gyr", gyr_rad_s), ("mag", mag_mgauss)):
        if vector is not None:
            xyz = np.asarray(vector, float) + rng.normal(0, 1e-3 * np.linalg.norm(vector), (n, 3))
            data.update({f"{prefix}_{a}": xyz[:, i] for i, a in enumerate("xyz")})
    return Recording(pd.DataFrame(data), message=message, corrected=True, frame="body")


@pytest.mark.parametrize("sensor, vector, unit", [
    ("mag", [300e6, 0, 200e6], "mGauss"),          # the firmware fault: ×1e6
    ("mag", [0.3, 0.0, 0.2], "mGauss"),            # gauss read as mGauss
    ("acc", [0, 0, -1.0], "m/s²"),                 # g read as m/s²
    ("acc", [0, 0, -1000.0], "m/s²"),              # mG read as m/s²
    ("gyr", [20.0, -10.0, 5.0], "rad/s"),          # mrad/s read as rad/s
])
def test_implausible_units_are_named_and_dropped(sensor, vector, unit):
    from apmcal.sources.units import drop_implausible_sensors

    good = {"acc_m_s2": [0, 0, -9.8], "gyr_rad_s": [0.01, 0, 0], "mag_mgauss": [300, 0, 200]}
    good[{"acc": "acc_m_s2", "gyr": "gyr_rad_s", "mag": "mag_mgauss"}[sensor]] = vector
    out = LogContents(path="x.tlog", format="tlog",
                      recordings=[recording("HIGHRES_IMU", **good)])
    reasons = drop_implausible_sensors(out)
    assert len(reasons) == 1 and f"HIGHRES_IMU[0] {sensor}" in reasons[0] and unit in reasons[0]
    assert sensor not in out.recordings[0].sensors
    assert sorted(out.recordings[0].sensors) == sorted({"acc", "gyr", "mag"} - {sensor})
    assert any(m.startswith("warning: ") and reasons[0] in m for m in out.messages)


def test_plausible_units_pass_including_an_uncalibrated_compass():
    from apmcal.sources.units import drop_implausible_sensors

    # 1800 mGauss of hard iron (COMPASS_OFFS_MAX) on a 500 mGauss field: still a compass
    out = LogContents(path="x.tlog", format="tlog", recordings=[
        recording("RAW_IMU", [0.3, -0.2, -9.6], [0.3, -0.2, 0.1], [1800 + 500, 0, 0])])
    assert drop_implausible_sensors(out) == []
    assert out.recordings[0].sensors == ["acc", "gyr", "mag"]


def test_a_log_with_nothing_plausible_is_refused_with_the_reason():
    from apmcal.core.errors import ApmcalError
    from apmcal.sources.units import require_plausible_units

    out = LogContents(path="x.tlog", format="tlog",
                      recordings=[recording("HIGHRES_IMU", acc_m_s2=[0, 0, -1000.0])])
    with pytest.raises(ApmcalError) as err:
        require_plausible_units(out)
    assert "x.tlog" in str(err.value) and "HIGHRES_IMU[0] acc" in str(err.value)


def test_csv_units_are_the_users_to_declare():
    """Raw counts declared (the reader's note) are allowed; undeclared, they are refused."""
    from apmcal.sources.units import require_plausible_units

    counts = recording("csv", acc_m_s2=[0, 0, -16384.0])
    out = LogContents(path="x.csv", format="csv", recordings=[counts],
                      messages=["acc: raw sensor counts, not SI units (no scale known)"])
    require_plausible_units(out)
    assert out.recordings[0].sensors == ["acc"]
    undeclared = LogContents(path="x.csv", format="csv", recordings=[counts])
    with pytest.raises(ApmcalError, match=r"acc_x\[counts\]"):
        require_plausible_units(undeclared)


def test_gap_drops_the_faulty_compass_too(tmp_path, capsys):
    """``apmcal gap`` reads logs by its own path: the same check, the compass from RAW_IMU."""
    short_ferraris_tlog(tmp_path / "good.tlog", faulty_highres_mag=False)
    short_ferraris_tlog(tmp_path / "faulty.tlog", faulty_highres_mag=True)
    out = {}
    for name in ("good", "faulty"):
        assert main(["gap", str(tmp_path / f"{name}.tlog"), "--effects", "bias_drift",
                     "--json", str(tmp_path / f"{name}.json")]) == 0
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
    printed = capsys.readouterr().out
    assert printed.count("HIGHRES_IMU[0] mag") == 1 and "mGauss×1000" in printed
    assert "mag" in out["faulty"]["session"]["sensors"]
    # the compass noise the twin was given is RAW_IMU's (1 mGauss steps), not 1e6 times more
    good = np.array(out["good"]["white_noise"]["mag"]["value"], dtype=float)
    faulty = np.array(out["faulty"]["white_noise"]["mag"]["value"], dtype=float)
    assert np.all(faulty < 10 * good + 1.0), (good, faulty)
