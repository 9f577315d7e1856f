"""The optional battery-current column ``current`` [A] of the readers' recordings.

Simulated logs (motors script: the simulator's current is 20 A × throttle) against the
simulator's own profile; real logs against the pymavlink reference; hand-built logs for the
units (CURR centi-amps, BAT amps, SYS_STATUS centi-amps with -1 = not measured), the first
battery, and the cases where no column may be attached (no records, all zero, an unstable or
rebooting tlog clock, no common time span, another component's SYS_STATUS).
"""
from __future__ import annotations

import struct

import numpy as np
import pymavlink_ref as ref
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from apmcal.report.text import summarize
from apmcal.sources import read_log
from apmcal.sources.dataflash import read_bin_messages
from apmcal.sources.tlog import read_tlog_messages
from apmcal_sim import makelog, motion
from apmcal_sim.logwriter import DataflashWriter, TlogWriter

UNIX0 = 1.7e9
MOTORS_S = 40.0        # motors script: idle 5 s, ramp 12.5 s, full 5 s, ramp 12.5 s, idle 5 s
AMPS_PER_THROTTLE = 20.0                     # sitl/vehicle.py SimVehicle.current_at
KINKS_S = (5.0, 17.5, 22.5, 35.0)            # where the throttle profile changes slope
SLOPE_A_PER_S = AMPS_PER_THROTTLE / 12.5     # ramp slope of the current [A/s]


# --- simulated logs: the simulator's own current ----------------------------------------------

@pytest.fixture(scope="module")
def motors_logs(tmp_path_factory):
    """(.bin, .tlog) of the motors script, 40 s, IMU at 50 Hz, made in process."""
    d = tmp_path_factory.mktemp("motors")
    paths = (d / "motors.bin", d / "motors.tlog")
    for p in paths:
        assert makelog.main(["--script", "motors", "--duration", str(MOTORS_S), "--out", str(p),
                             "--rate", "50"]) == 0
    return paths


def _sim_current(t: np.ndarray) -> np.ndarray:
    """The simulator's battery current [A] at times t [s since boot]."""
    return AMPS_PER_THROTTLE * motion.build("motors", duration=MOTORS_S).throttle(t)


def test_motors_script_really_drives_current():
    """Guard for the tests below: the profile the simulator uses has 0 A and 20 A stretches."""
    amps = _sim_current(np.array([2.0, 11.25, 20.0, 28.75, 38.0]))
    np.testing.assert_allclose(amps, [0.0, 10.0, 20.0, 10.0, 0.0], atol=1e-12)


def test_simulated_bin_current_matches_the_simulator(motors_logs):
    """BAT at 10 Hz (TimeUS on the IMU's clock, Curr float32 A). The profile is piecewise linear
    with its kinks (5, 17.5, 22.5, 35 s) on the 0.1 s BAT grid, so linear interpolation is exact
    there: the only error is float32 storage, ≤ 20 A × 2⁻²⁴ ≈ 1.2e-6 A. After the last BAT
    record (40.9 s) the IMU samples (to 40.98 s) get NaN."""
    c = read_log(motors_logs[0])
    assert {r.message for r in c.recordings} == {"IMU", "MAG"}
    for r in c.recordings:
        t, cur = r.t, r.data["current"].to_numpy()
        np.testing.assert_array_equal(np.isnan(cur), t > 40.9 + 1e-9)
        ok = ~np.isnan(cur)
        np.testing.assert_allclose(cur[ok], _sim_current(t[ok]), rtol=0, atol=2e-6)
        assert cur[ok].max() == pytest.approx(20.0, abs=2e-6)
        assert "current" not in r.sensors
    assert any("battery current [A] from BAT.Curr" in m for m in c.messages)


def test_simulated_tlog_current_matches_the_simulator(motors_logs):
    """SYS_STATUS at 1 Hz (t = 0..40 s), ``int(A × 100)`` cA, stamped by the ground station at
    start_unix + t. Where the profile is linear over a whole second the interpolation is
    exact and only the cA truncation remains (< 0.01 A); in the two seconds holding a kink off
    the 1 s grid (17.5, 22.5 s) linear interpolation errs by at most |Δslope|·h/4 =
    1.6 A/s × 1 s / 4 = 0.4 A. The boot clock offset is exact to float rounding (~1e-6 s)."""
    c = read_log(motors_logs[1])
    (r,) = c.recordings
    t, cur = r.t, r.data["current"].to_numpy()
    np.testing.assert_array_equal(np.isnan(cur), t > 40.0 + 1e-9)
    ok = ~np.isnan(cur)
    err = np.abs(cur[ok] - _sim_current(t[ok]))
    near_kink = np.zeros(ok.sum(), bool)
    for k in KINKS_S:
        near_kink |= np.floor(t[ok]) == np.floor(k)
    assert err[~near_kink].max() < 0.01 + 1e-6
    assert err.max() <= SLOPE_A_PER_S * 1.0 / 4 + 0.01 + 1e-6
    assert err.max() > 0.3          # the kink error is really there: the bound is tight
    assert any("battery current [A] from SYS_STATUS" in m for m in c.messages)


def test_simulated_logs_match_the_pymavlink_reference(motors_logs):
    b, tl = (read_log(p) for p in motors_logs)
    assert ref.compare(b, ref.df_expected(ref.pymavlink_messages(motors_logs[0], None))) > 0
    exp = ref.tlog_expected(ref.pymavlink_messages(motors_logs[1], ref.TLOG_READ))
    assert "current" in exp[("RAW_IMU", 0)]
    assert ref.compare(tl, exp) > 0


def test_summary_does_not_count_current_as_a_sensor(motors_logs):
    s = summarize(read_log(motors_logs[0]))
    assert sorted(tuple(r["sensors"]) for r in s["recordings"]) == [("acc", "gyr"), ("mag",)]


# --- real logs: the fast readers against pymavlink --------------------------------------------

# every log in shared/data/ardupilot with BAT/CURR/SYS_STATUS records → recordings that get a
# current column (empty: none may, a note must say why)
REAL = {
    "ardupilot/ardusub_small.BIN": {("IMU", 0), ("MAG", 0), ("MAG", 1)},       # BAT, Instance
    "ardupilot/ardusub_small.tlog": {("RAW_IMU", 0), ("SCALED_IMU2", 1)},      # SYS_STATUS
    "ardupilot/copter311_nan.log": {("IMU", 0), ("IMU2", 1), ("MAG", 0), ("MAG2", 1)},  # CURR
    "ardupilot/pixhawk1_copter368.bin": {("IMU", 0), ("IMU2", 1), ("MAG", 0)},  # BAT (+BAT2)
    "ardupilot/pixhawk_3imu_log171.bin": {("IMU", 0), ("IMU2", 1), ("IMU3", 2), ("MAG", 0),
                                          ("MAG2", 1), ("MAG3", 2)},            # CURR
    "ardupilot/pxf_copter_mag.BIN": {("IMU", 0), ("MAG", 0)},                  # CURR
    "ardupilot/pxf_copter_static_51.BIN": set(),             # CURR Curr zero in every record
    "ardupilot/sitl_vtol.tlog": set(),                       # SYS_STATUS current -1 throughout
}
CURRENT_MESSAGES = ("BAT", "CURR", "SYS_STATUS")


def _has_current_records(path) -> bool:
    if path.suffix == ".tlog":
        dec, _, _ = read_tlog_messages(path, ["SYS_STATUS"])
        return len(dec["SYS_STATUS"]) > 0
    if path.suffix.lower() == ".bin":
        msgs, _, _ = read_bin_messages(path, want=lambda n: n in CURRENT_MESSAGES)
        return bool(msgs)
    return any(line.split(",")[0] in ("BAT", "CURR") for line in path.read_text().splitlines())


def test_every_real_log_with_current_records_is_checked(shared_data):
    found = {f"ardupilot/{p.name}" for p in sorted((shared_data / "ardupilot").iterdir())
             if _has_current_records(p)}
    assert found == set(REAL)


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_logs_match_pymavlink(shared_data, name):
    path = shared_data / name
    c = read_log(path)
    kind = "tlog" if name.endswith(".tlog") else "df"
    if kind == "tlog":
        expected = ref.tlog_expected(ref.pymavlink_messages(path, ref.TLOG_READ))
    else:
        expected = ref.df_expected(ref.pymavlink_messages(path, None))
    assert ref.compare(c, expected) > 0
    with_current = {(r.message, r.instance) for r in c.recordings if "current" in r.data}
    assert with_current == REAL[name]
    assert {k for k, cols in expected.items() if "current" in cols} == REAL[name]
    for r in c.recordings:
        assert "current" not in r.sensors
        if "current" in r.data:
            assert np.isfinite(r.data["current"]).mean() > 0.95     # spans the recording
    if not REAL[name]:
        assert any(m.startswith("note: ") and "no current column" in m for m in c.messages)


def test_copter3_curr_is_centiamps_in_a_real_flight(shared_data):
    """pixhawk_3imu_log171.bin, Copter 3.3-dev CURR "IhhhHfh": Curr up to 2744 cA = 27.4 A in
    flight on a 15.5 V pack: a quadcopter's hover-to-climb current (2744 A would be absurd)."""
    c = read_log(shared_data / "ardupilot/pixhawk_3imu_log171.bin")
    cur = c.recordings[0].data["current"]
    assert 20.0 < cur.max() < 30.0 and 0.3 < cur.min() < 1.0


# --- hand-built dataflash logs: units, first battery, absent or zero current ------------------

def _fmt(t: int, name: str, fmt: str, cols: str, length: int) -> bytes:
    return struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, t, length, name.encode(),
                       fmt.encode(), cols.encode())


def _imu_fmt(tcol="TimeUS", tch="Q") -> bytes:
    return (_fmt(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89)
            + _fmt(130, "IMU", tch + "ffffff", f"{tcol},GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
                   3 + struct.calcsize("<" + tch + "ffffff")))


def _imu(t: int, tch="Q") -> bytes:
    return b"\xa3\x95\x82" + struct.pack("<" + tch + "ffffff", t, 0, 0, 0, 0, 0, -9.8)


def test_copter32_curr_int16_centiamps_bin(tmp_path):
    """Copter 3.2 CURR "IhIhhhf" (TimeMS): Curr 1464 cA at 1 s, 0 at 2 s → 14.64 A, 7.32 A
    half way, NaN after 2 s."""
    data = _imu_fmt("TimeMS", "I") + _fmt(131, "CURR", "IhIhhhf",
                                         "TimeMS,ThrOut,ThrInt,Volt,Curr,Vcc,CurrTot", 3 + 20)
    for k in range(1, 6):           # IMU at 0.5 s steps from 0.5 s; CURR at 1 and 2 s
        data += _imu(500 * k, "I")
        if k in (2, 4):
            data += b"\xa3\x95\x83" + struct.pack("<IhIhhhf", 500 * k, 0, 0, 1549,
                                                  1464 if k == 2 else 0, 5000, 1.0)
    p = tmp_path / "curr.bin"
    p.write_bytes(data)
    c = read_log(p)
    np.testing.assert_allclose(c.recordings[0].data["current"], [np.nan, 14.64, 7.32, 0.0,
                                                                 np.nan], rtol=1e-12)
    assert ref.compare(c, ref.df_expected(ref.pymavlink_messages(p, None))) > 0


def test_text_log_curr_centiamps(tmp_path):
    lines = ["FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
             "FMT, 130, 31, IMU, Iffffff, TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
             "FMT, 131, 23, CURR, IhIhhhf, TimeMS,ThrOut,ThrInt,Volt,Curr,Vcc,CurrTot"]
    for k in range(1, 5):
        lines.append(f"IMU, {1000 * k}, 0, 0, 0, 0, 0, -9.8")
        lines.append(f"CURR, {1000 * k}, 0, 0, 1500, {250 * k}, 5000, 1.0")
    p = tmp_path / "curr.log"
    p.write_text("\n".join(lines) + "\n")
    c = read_log(p)
    np.testing.assert_allclose(c.recordings[0].data["current"], [2.5, 5.0, 7.5, 10.0])
    assert ref.compare(c, ref.df_expected(ref.pymavlink_messages(p, None))) > 0


def test_bat_float_amps_first_battery_only(tmp_path):
    """Instance-numbered BAT ("QBff...", Curr float A): only instance 0 is used, though
    battery 1 is logged too (and first)."""
    data = _imu_fmt() + _fmt(131, "BAT", "QBff", "TimeUS,Instance,Volt,Curr", 3 + 17)
    for k in range(5):
        t_us = 100_000 * k
        data += _imu(t_us)
        data += b"\xa3\x95\x83" + struct.pack("<QBff", t_us, 1, 16.0, 99.0)
        data += b"\xa3\x95\x83" + struct.pack("<QBff", t_us, 0, 16.0, 1.5 * k)
    p = tmp_path / "bat.bin"
    p.write_bytes(data)
    c = read_log(p)
    np.testing.assert_allclose(c.recordings[0].data["current"], 1.5 * np.arange(5), rtol=1e-7)
    assert ref.compare(c, ref.df_expected(ref.pymavlink_messages(p, None))) > 0


def _sim_bin(path, curr_a=None):
    """A small .bin from the simulator's writer; BAT records only when ``curr_a`` is given."""
    with DataflashWriter(path) as w:
        for k in range(20):
            t_us = 20_000 * k
            w.imu(t_us, (0, 0, 0), (0, 0, -9.8), 30.0)
            w.mag(t_us, (200, 0, 400), (0, 0, 0))
            if curr_a is not None and k % 5 == 0:
                w.bat(t_us, 12.6, curr_a)
    return read_log(path)


def test_bin_without_battery_records_has_no_current(tmp_path):
    c = _sim_bin(tmp_path / "nobat.bin")
    assert all("current" not in r.data for r in c.recordings)
    assert not any("current" in m for m in c.messages)


def test_bin_with_zero_current_has_no_column_and_a_note(tmp_path):
    c = _sim_bin(tmp_path / "zero.bin", 0.0)
    assert all("current" not in r.data for r in c.recordings)
    assert "note: BAT.Curr is zero in every record (no current sensor?); no current column" \
        in c.messages
    assert _sim_bin(tmp_path / "some.bin", 3.0).recordings[0].data["current"].max() == 3.0


# --- hand-built tlogs: clock mapping and the cases without a column ---------------------------

def _v2(component=1):
    return mav2.MAVLink(None, srcSystem=1, srcComponent=component)


def _raw_imu(t_s: float):
    return mav2.MAVLink_raw_imu_message(int(round(t_s * 1e6)), 0, 0, -1000, 0, 0, 0, 1, 2, 3,
                                        0, 0)


def _sys_status(current_ca: int):
    return mav2.MAVLink_sys_status_message(0, 0, 0, 200, 12600, current_ca, 90, 0, 0, 0, 0, 0, 0)


def _tlog(path, imu_times, imu_stamps, status, heartbeat=True):
    """RAW_IMU at boot times ``imu_times`` stamped ``imu_stamps`` (s after UNIX0) and
    ``status`` = [(stamp s after UNIX0, cA, component)] SYS_STATUS frames, merged by stamp."""
    frames = [(s, 0, _raw_imu(t).pack(_v2())) for t, s in zip(imu_times, imu_stamps)]
    frames += [(s, 1, _sys_status(ca).pack(_v2(comp))) for s, ca, comp in status]
    if heartbeat:
        frames.append((-1.0, 0, mav2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(_v2())))
    with TlogWriter(path) as w:
        for s, _, packed in sorted(frames, key=lambda f: (f[0], f[1])):
            w.write(UNIX0 + s, packed)
    return read_log(path)


BOOT_TO_GCS_S = 100.0                 # the ground station's clock is 100 s ahead of boot time
IMU_T = np.arange(0.0, 20.0, 0.1)     # RAW_IMU at 10 Hz for 20 s
RAMP = [(BOOT_TO_GCS_S + k, 100 * k, 1) for k in range(0, 21)]   # 0..20 A, 1 A/s


def _check_reference(path, c):
    msgs = ref.pymavlink_messages(path, ref.TLOG_READ)
    assert ref.compare(c, ref.tlog_expected(msgs)) > 0


def test_tlog_clock_mapping(tmp_path):
    """Stamps 100 s ahead of boot time plus 0..30 ms of jitter: the median offset puts the
    1 A/s ramp on the boot clock to within the jitter (30 ms × 1 A/s = 0.03 A)."""
    rng = np.random.default_rng(1)
    stamps = IMU_T + BOOT_TO_GCS_S + rng.uniform(0, 0.03, len(IMU_T))
    p = tmp_path / "ok.tlog"
    c = _tlog(p, IMU_T, stamps, RAMP)
    cur = c.recordings[0].data["current"].to_numpy()
    np.testing.assert_allclose(cur, IMU_T, atol=0.03)
    _check_reference(p, c)


def test_tlog_unmeasured_current_is_left_out(tmp_path):
    """-1 cA = not measured: those records are skipped; -1 everywhere gives no column."""
    status = [(s, -1 if k % 2 else ca, comp) for k, (s, ca, comp) in enumerate(RAMP)]
    c = _tlog(tmp_path / "some.tlog", IMU_T, IMU_T + BOOT_TO_GCS_S, status)
    np.testing.assert_allclose(c.recordings[0].data["current"], IMU_T, atol=1e-5)
    c = _tlog(tmp_path / "none.tlog", IMU_T, IMU_T + BOOT_TO_GCS_S,
              [(s, -1, comp) for s, _, comp in RAMP])
    assert "current" not in c.recordings[0].data
    assert any("current_battery is -1 (not measured)" in m for m in c.messages)


def test_tlog_without_sys_status_has_no_current(tmp_path):
    c = _tlog(tmp_path / "nostatus.tlog", IMU_T, IMU_T + BOOT_TO_GCS_S, [])
    assert "current" not in c.recordings[0].data
    assert not any("current" in m for m in c.messages)


def test_tlog_buffered_clock_gives_a_note_and_no_column(tmp_path):
    """A ground station that buffers: frames stamped in bursts once a second, so tlog time
    minus boot time ranges over ~0.9 s (more than 0.5 s): no SYS_STATUS stamp can be placed
    on the boot clock. The same log stamped without buffering does get the column."""
    p = tmp_path / "buffered.tlog"
    c = _tlog(p, IMU_T, np.ceil(IMU_T) + BOOT_TO_GCS_S, RAMP)
    assert "current" not in c.recordings[0].data
    assert any("RAW_IMU[0]: tlog time minus boot time varies by" in m for m in c.messages)
    _check_reference(p, c)
    assert "current" in _tlog(tmp_path / "direct.tlog", IMU_T, IMU_T + BOOT_TO_GCS_S,
                              RAMP).recordings[0].data


def test_tlog_reboot_gives_a_note_and_no_column(tmp_path):
    """The vehicle reboots at 10 s (boot time restarts at 0) while the ground station's clock
    runs on: a SYS_STATUS time no longer says which boot it belongs to."""
    boot = np.concatenate([IMU_T[IMU_T < 10], IMU_T[IMU_T < 10]])
    p = tmp_path / "reboot.tlog"
    c = _tlog(p, boot, IMU_T + BOOT_TO_GCS_S, RAMP)
    assert "current" not in c.recordings[0].data
    assert any("RAW_IMU[0]: a clock jumps back (a reboot?)" in m for m in c.messages)
    _check_reference(p, c)


def test_tlog_without_common_span_gives_a_note(tmp_path):
    """SYS_STATUS only in the minute before the IMU stream starts."""
    status = [(BOOT_TO_GCS_S - 60 + k, 500, 1) for k in range(10)]
    p = tmp_path / "apart.tlog"
    c = _tlog(p, IMU_T, IMU_T + BOOT_TO_GCS_S, status)
    assert "current" not in c.recordings[0].data
    assert "note: RAW_IMU[0] and SYS_STATUS share no time span; no current attached" in c.messages
    _check_reference(p, c)


def test_tlog_other_components_sys_status_is_ignored(tmp_path):
    """A companion computer (component 191) sends its own SYS_STATUS with 50 A: only the
    autopilot's (the HEARTBEAT's component 1) counts."""
    other = [(s + 0.5, 5000, 191) for s, _, _ in RAMP]
    p = tmp_path / "components.tlog"
    c = _tlog(p, IMU_T, IMU_T + BOOT_TO_GCS_S, RAMP + other)
    np.testing.assert_allclose(c.recordings[0].data["current"], IMU_T, atol=1e-5)
    assert any("21 SYS_STATUS from components other than the autopilot" in m
               for m in c.messages)
    _check_reference(p, c)
