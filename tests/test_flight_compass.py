"""The compass from an ordinary flight: simulated multicopter flights with injected hard and soft
iron, motor-current interference, a wrong compass orientation and a biased logged yaw
(apmcal_sim.flight), and the real logs in ../shared/data."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from apmcal.calibration.flight import calibrate_flight, calibrate_flight_log
from apmcal.core.errors import ApmcalError
from apmcal.solvers import compass_heading
from apmcal.sources.flight import read_flight
from apmcal_sim import flight as sim

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "ardupilot"
FIT_PARAMS = ("OFS_X", "OFS_Y", "OFS_Z", "DIA_X", "DIA_Y", "DIA_Z", "ODI_X", "ODI_Y", "ODI_Z",
              "MOT_X", "MOT_Y", "MOT_Z")


@pytest.fixture(scope="module")
def wrong_orientation(tmp_path_factory):
    """Seed 1: compass 0 mounted YAW_90 while COMPASS_ORIENT says NONE; logged yaw biased 8°."""
    d = tmp_path_factory.mktemp("flight")
    truth = sim.write_flight(d / "f.bin", d / "f.json", seed=1, orient_error=2)
    return d / "f.bin", truth


@pytest.fixture(scope="module")
def yaw_pair(tmp_path_factory):
    """Seed 2 flown twice, identical but for the logged yaw: unbiased, and biased 25° with a
    heading-dependent ±12.5° and a drift."""
    d = tmp_path_factory.mktemp("yaw")
    truth = sim.write_flight(d / "y0.bin", seed=2, yaw_bias_deg=0.0)
    sim.write_flight(d / "y25.bin", seed=2, yaw_bias_deg=25.0)
    return d / "y0.bin", d / "y25.bin", truth


def _check_against_truth(proposed, sigma, truth, instance):
    ideal = truth["compasses"][instance]["ideal"]
    for p in FIT_PARAMS:
        name = sim.param_name(p, instance)
        err = proposed[name] - ideal[p]
        assert abs(err) <= 3 * sigma[name], (name, proposed[name], ideal[p], sigma[name])
    mot = np.array([proposed[sim.param_name(f"MOT_{a}", instance)] for a in "XYZ"])
    mot_true = np.array([ideal[f"MOT_{a}"] for a in "XYZ"])
    assert np.linalg.norm(mot - mot_true) <= 0.10 * np.linalg.norm(mot_true)


def test_log_command_recovers_every_parameter_and_names_the_orientation(wrong_orientation,
                                                                         tmp_path):
    """`apmcal log FLIGHT --json --param-file`: every injected parameter of both compasses
    within 3σ, COMPASS_MOT within 10 %, compass 0's YAW_90 mount named and proposed."""
    from apmcal.cli import main
    path, truth = wrong_orientation
    out_json, out_param = tmp_path / "r.json", tmp_path / "r.param"
    assert main(["log", str(path), "--json", str(out_json), "--param-file", str(out_param),
                 "--report", str(tmp_path / "report")]) == 0
    page = (tmp_path / "report" / "index.html").read_text()
    # the heading error along the flight, one figure per compass, nothing from the network
    assert page.count("data:image/png;base64,") == 2 and "http" not in page
    assert "compass 0: calibration in force <span class='redo'>" in page
    res = json.loads(out_json.read_text())
    assert res["method"] == "flight"
    c0, c1 = res["compasses"]
    assert c0["orientation"]["wrong"] and c0["orientation"]["best"] == 2
    assert "YAW_90" in c0["orientation"]["evidence"]
    assert not c1["orientation"]["wrong"]
    for c in (c0, c1):
        _check_against_truth(c["proposed"], c["sigma"], truth, c["instance"])
        assert c["proposed_health"]["verdict"] == "good"
    assert c0["in_force_health"]["verdict"] == "redo"          # mounted 90° off
    params = dict(line.split() for line in out_param.read_text().splitlines()
                  if line and not line.startswith("#"))
    assert float(params["COMPASS_ORIENT"]) == 2 and float(params["COMPASS_MOTCT"]) == 2


def test_biased_logged_yaw_does_not_bias_the_fit(yaw_pair):
    """The same flight with its logged yaw unbiased and 25° off (heading-dependent, drifting)
    gives the same parameters, and both recover the truth within 3σ."""
    y0, y25, truth = yaw_pair
    assert not np.allclose(read_flight(y0).yaw, read_flight(y25).yaw, atol=0.1)
    r0 = calibrate_flight(y0, check_orientation=False)
    r25 = calibrate_flight(y25, check_orientation=False)
    for a, b in zip(r0.compasses, r25.compasses):
        for name, v in a.proposed.items():
            assert b.proposed[name] == pytest.approx(v, rel=1e-9, abs=1e-9)
        _check_against_truth(b.proposed, b.sigma, truth, b.instance)
        assert b.health_in_force.p95_deg == pytest.approx(a.health_in_force.p95_deg, abs=1e-9)


def test_heading_error_of_calibration_in_force_matches_the_true_one(yaw_pair):
    """The reported 95 % heading error of the calibration in force is the true one (from the
    simulator's true attitude) within 1°, though the true heading is never given to apmcal."""
    y0, y25, truth = yaw_pair
    res = calibrate_flight(y25, check_orientation=False)
    fd = read_flight(y25)
    tr = sim.fly(truth["rate_hz"], 1.0, truth["seed"])
    decl = np.arctan2(truth["earth_field_ned_mgauss"][1], truth["earth_field_ned_mgauss"][0])
    for c, mag in zip(res.compasses, fd.mags):
        k = np.searchsorted(tr.t, mag.t - 1e-3)           # log time = sim time + 1 ms
        head = compass_heading.compass_heading(mag.field, tr.roll[k], tr.pitch[k], decl)
        true_err = np.abs(compass_heading.wrap_deg(np.degrees(head - tr.yaw[k])))
        true_p95 = float(np.percentile(true_err, 95))
        assert true_p95 > 5.0                               # the stale calibration is poor
        assert c.health_in_force.p95_deg == pytest.approx(true_p95, abs=1.0)


def test_constant_current_names_the_climb_manoeuvre(yaw_pair):
    """Where the current does not vary COMPASS_MOT is not fitted, and the report says which
    manoeuvre would identify it."""
    y0, _, _ = yaw_pair
    fd = read_flight(y0)
    fd.current = np.full_like(fd.current, 15.0)
    res = calibrate_flight(fd, check_orientation=False)
    for c in res.compasses:
        assert not any(k.startswith("COMPASS_MOT") for k in c.proposed)
        assert any("COMPASS_MOT" in what and "climb at full throttle" in how
                   for what, how in c.unidentified)
    assert any("climb at full throttle" in line for line in res.lines())


def test_reader_units(yaw_pair):
    """Flight series in their stated units: rad, deg, A, 0..1, mGauss."""
    y0, _, truth = yaw_pair
    fd = read_flight(y0)
    assert np.max(np.abs(fd.roll)) < 0.5 and np.max(np.abs(fd.yaw)) <= 2 * np.pi
    assert fd.lat[0] == pytest.approx(sim.SITE["lat"], abs=1e-6)
    assert np.max(fd.current) == pytest.approx(truth["current_range_a"][1], rel=1e-3)
    assert 0.0 <= fd.throttle.min() and fd.throttle.max() <= 1.0
    assert [m.instance for m in fd.mags] == [0, 1]
    assert fd.boot_unix_s == pytest.approx(sim.START_UNIX - 1e-3, abs=1e-3)


def test_not_a_flight_goes_the_old_way():
    """A bench session (no ATT, no GPS) is not taken for a flight; asked directly, the reason
    is named."""
    path = ROOT / "logs" / "gap.bin"
    assert calibrate_flight_log(path) == (None, None)
    with pytest.raises(ApmcalError, match="not a flight.*ATT"):
        calibrate_flight(path)


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/ardupilot (real logs) is absent")
def test_real_flight_gets_a_heading_verdict():
    """pixhawk_3imu_log171.bin (Copter 3.3-dev, three compasses, GPS): each compass gets a
    heading error in degrees and a verdict, and what the flight could not identify is named
    with its manoeuvre."""
    res = calibrate_flight(REAL / "pixhawk_3imu_log171.bin")
    assert [c.instance for c in res.compasses] == [0, 1, 2]
    for c in res.compasses:
        assert np.isfinite(c.health_in_force.p95_deg) and c.health_in_force.verdict in (
            "good", "usable", "redo")
        assert c.orientation is not None and not c.orientation.wrong
    text = "\n".join(res.lines())
    assert "heading error 95 %" in text and "what determines it: " in text


def test_a_flown_log_says_what_the_compass_check_lacked():
    """A log that flew but cannot be checked names what it lacked and the remedy; a bench
    session or a log without attitude says nothing (it is no flight)."""
    from apmcal.calibration.flight import MANOEUVRE, lacking

    assert "--lat/--lon" in lacking("no GPS fix (and no --lat/--lon) for the expected field")
    turn = lacking("the heading changed only 12° (need 90°)")
    assert turn.startswith("the heading changed only 12°") and MANOEUVRE["iron"] in turn
    for no_flight in ("no ATT attitude records", "no MAG compass records",
                      "the vehicle never moved (GPS speed ≤ 1 m/s, throttle ≤ 0.2)"):
        assert lacking(no_flight) is None


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/ardupilot (real logs) is absent")
def test_a_real_flight_without_gps_fix_names_the_site_it_needs(capsys):
    from apmcal.cli import main

    assert main(["log", str(REAL / "pxf_copter_mag.BIN")]) in (0, 1)
    out = capsys.readouterr().out
    assert "compass in flight: not checked" in out and "--lat/--lon" in out


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/ardupilot (real logs) is absent")
def test_a_telemetry_log_is_read_for_the_flight_check_and_a_slow_gyro_refused():
    """sitl_vtol.tlog (ArduPlane SITL, 2018-08-08): attitude, position from
    GLOBAL_POSITION_INT, the boot clock dated by SYSTEM_TIME, compass 0 from RAW_IMU — and
    its RAW_IMU at about 4 Hz is refused as a heading reference, with the remedy."""
    import datetime

    from apmcal.calibration.flight import calibrate_flight_log, flight_evidence

    path = REAL / "sitl_vtol.tlog"
    fd = read_flight(path)
    assert fd.firmware.startswith("ArduPlane V3.10") and len(fd.att_t) > 800
    assert np.all(np.abs(fd.roll) < np.pi) and -35.37 < np.median(fd.lat) < -35.35
    when = datetime.datetime.fromtimestamp(fd.boot_unix_s + fd.gps_t[0], datetime.timezone.utc)
    assert when.date() == datetime.date(2018, 8, 8)
    assert [m.instance for m in fd.mags] == [0] and 200 < np.median(
        np.linalg.norm(fd.mags[0].field, axis=1)) < 1000          # mGauss, the Earth's field
    flew, why = flight_evidence(fd)
    assert not flew and "gyro is logged at" in why
    result, lacking = calibrate_flight_log(path)
    assert result is None and "dataflash log" in lacking


def _correlated_noise_fit(seed: int, rho: float = 0.97):
    """A yaw-free fit of a simulated flight's path (apmcal_sim.flight.fly, 10 Hz, the true
    roll and pitch) whose compass noise is AR(1) with lag-one correlation ``rho`` (2 mGauss
    rms): errors [/σ] of OFS, DIA, ODI against the injected truth."""
    from apmcal.solvers.compass_flight import AttitudeUncertainty, FieldPrior, fit_flight

    rng = np.random.default_rng(seed)
    tr = sim.fly(10.0, 1.0, seed)
    b_ned = np.array([232.0, 53.0, -529.0])
    body = np.einsum("nji,j->ni", sim.dcm(tr.roll, tr.pitch, tr.yaw), b_ned)
    m = np.eye(3) + np.diag(rng.normal(0, 0.04, 3))
    m[0, 1], m[0, 2], m[1, 2] = rng.normal(0, 0.02, 3)
    m = np.triu(m) + np.triu(m, 1).T
    ofs = rng.normal(0, 80, 3)
    noise = np.zeros((len(tr.t), 3))
    step = rng.normal(0, 2.0 * np.sqrt(1 - rho ** 2), noise.shape)
    for k in range(1, len(noise)):
        noise[k] = rho * noise[k - 1] + step[k]
    raw = body @ np.linalg.inv(m).T - ofs + noise
    fit = fit_flight(raw, tr.roll, tr.pitch, np.zeros(len(raw)),
                     FieldPrior.from_ned(b_ned, 1.0, np.radians(0.1)),
                     fixed={9: 0.0, 10: 0.0, 11: 0.0}, t=tr.t,
                     attitude=AttitudeUncertainty(0.0, 0.0, 10.0))
    truth = np.concatenate([ofs, np.diag(m), [m[0, 1], m[0, 2], m[1, 2]]])
    return (fit.x[:9] - truth) / fit.sigma[:9]


def test_sigma_covers_residuals_correlated_in_time():
    """Compass noise correlated over seconds (lag-one 0.97 at 10 Hz): |error| < 3σ for at
    least 95 % of 180 estimates over 20 flights, median |z| near an honest 0.67 (σ from the
    samples as if independent: 59 %, median |z| 2.4 — checked once by hand)."""
    z = np.abs(np.concatenate([_correlated_noise_fit(seed) for seed in range(1, 21)]))
    assert np.mean(z < 3.0) >= 0.95
    assert 0.4 <= np.median(z) <= 1.0


def test_the_logs_int16_truncation_is_undone():
    """ArduPilot logs MAG as ``(int16_t)field``, truncating toward zero: read back, the mean
    of what a logged value stands for is the value + ½·sign (0 for 0), so a field of either
    sign comes back unbiased where the logged integers are half a mGauss short."""
    from apmcal.calibration.flight import untruncated

    true = np.random.default_rng(3).uniform(-600.0, 600.0, 200_000)
    logged = np.trunc(true)                      # C's float → int16 conversion
    assert np.mean((logged - true)[true > 1]) == pytest.approx(-0.5, abs=0.01)
    assert np.mean((logged - true)[true < -1]) == pytest.approx(0.5, abs=0.01)
    back = untruncated(logged)
    for side in (true > 1, true < -1):
        assert abs(np.mean((back - true)[side])) < 0.01
