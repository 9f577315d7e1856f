"""World Magnetic Model for any recording date: the model of the date's own span, a note and the
nearest covered year outside them, and a calibration that does not stop on an old log."""
from __future__ import annotations

import datetime
import struct
from pathlib import Path

import numpy as np
import pytest
from pygeomag import GeoMag

from apmcal.calibration.log import Options, calibrate_log
from apmcal.core.geomag import decimal_year, earth_field_ned
from apmcal.report.lines import calibration_lines
from apmcal.sources import read_log

LOGS = Path(__file__).resolve().parents[1] / "logs"
ACCRA = (5.6037, -0.187)


@pytest.mark.parametrize("year, model", [(2012.5, "WMM_2010.COF"), (2018.5, "WMM_2015v2.COF"),
                                         (2022.5, "WMM_2020.COF"), (2026.5, "WMM_2025.COF")])
def test_each_date_is_evaluated_with_the_model_of_its_span(year, model):
    want = GeoMag(coefficients_file=f"wmm/{model}").calculate(
        glat=ACCRA[0], glon=ACCRA[1], alt=0.06, time=year)
    field, note = earth_field_ned(*ACCRA, 60.0, year)
    np.testing.assert_allclose(field, np.array([want.x, want.y, want.z]) / 100.0, rtol=1e-12)
    assert note is None


@pytest.mark.parametrize("year, used", [(2003.0, 2010.0), (2034.2, 2030.0)])
def test_dates_outside_the_models_use_the_nearest_covered_year_with_a_note(year, used):
    field, note = earth_field_ned(*ACCRA, 0.0, year)
    np.testing.assert_allclose(field, earth_field_ned(*ACCRA, 0.0, used)[0])
    assert note == (f"{year:.3f} lies outside the World Magnetic Model years 2010-2030: field "
                    f"of {used:.0f} used")


@pytest.mark.parametrize("year", [2010.0, 2030.0])
def test_the_ends_of_the_covered_years_are_inside(year):
    assert earth_field_ned(*ACCRA, 0.0, year)[1] is None


def test_decimal_year():
    assert decimal_year(datetime.date(2026, 1, 1)) == 2026.0
    assert decimal_year(datetime.datetime(2024, 7, 2, 0, 0)) == pytest.approx(2024 + 183 / 366)
    new_york = datetime.timezone(datetime.timedelta(hours=-5))
    assert decimal_year(datetime.datetime(2025, 12, 31, 22, 0, tzinfo=new_york)) == \
        pytest.approx(2026 + 3 / 24 / 365)          # 03:00 UTC on 1 January 2026


def test_an_old_recording_is_calibrated_with_the_field_of_its_date(tmp_path):
    """The sample session with its ground-station clock moved to 2018 (an APM 2.x era log)."""
    data = bytearray((LOGS / "ferraris.tlog").read_bytes())
    unix_2018 = datetime.datetime(2018, 6, 1, tzinfo=datetime.timezone.utc).timestamp()
    data[:8] = struct.pack(">Q", int(unix_2018 * 1e6))
    log = tmp_path / "old.tlog"
    log.write_bytes(bytes(data))
    cal, _ = calibrate_log(read_log(log), Options(lat_deg=ACCRA[0], lon_deg=ACCRA[1]))
    assert "mag" in cal.sensors
    text = " ".join(calibration_lines(cal.report, cal.sensors))
    assert "mag: field magnitude" in text and "WMM at recording date 2018-06-01" in text
    assert cal.report.magnetic_field.source == "WMM at recording date 2018-06-01"
    field_2018 = np.linalg.norm(earth_field_ned(*ACCRA, 0.0, decimal_year(
        datetime.date(2018, 6, 1)))[0])
    assert cal.report.magnetic_field.mgauss == pytest.approx(field_2018)


def test_the_fields_uncertainty_is_the_wmms_own_for_its_magnitude():
    """WMM2025's error model gives 138 nT (1σ) for the total intensity F: 1.38 mGauss."""
    from apmcal.core.geomag import field_uncertainty

    sigma_f, _, _ = field_uncertainty(-35.363262, 149.165237, 0.0,
                                      decimal_year(datetime.date(2026, 11, 29)))
    assert sigma_f == pytest.approx(1.38)


def _sphere_samples(n: int, radius: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    return np.round(radius * v / np.linalg.norm(v, axis=1, keepdims=True)) + [40.0, -25.0, 10.0]


def test_a_site_puts_the_fields_uncertainty_into_the_soft_iron_matrix_sigma():
    """The ellipsoid gives the matrix's shape; its gain comes from the field it is scaled to,
    known to the WMM's 0.24 %: every matrix entry's σ carries |M_ij| × that, the offsets none."""
    from apmcal.solvers.magnetometer import calibrate_magnetometer

    mag = _sphere_samples(4000, 580.0)
    when = datetime.date(2026, 11, 29)
    site = calibrate_magnetometer(mag, -35.363262, 149.165237, when, resolution_mgauss=1.0)
    none = calibrate_magnetometer(mag, None, None, when, resolution_mgauss=1.0)
    relative = site.magnetic_field.sigma_mgauss / site.magnetic_field.mgauss
    diag_sigma = np.diag(site.sensor.sigma["matrix"])
    assert np.all(diag_sigma >= relative * np.abs(np.diag(site.sensor.matrix)) * 0.999)
    assert np.all(np.diag(none.sensor.sigma["matrix"]) < 0.2 * diag_sigma)
    np.testing.assert_allclose(site.sensor.sigma["offset"], none.sensor.sigma["offset"], rtol=0.2)


def test_a_reading_held_unchanged_counts_once_and_noisy_repeats_keep_their_weight():
    """A quantized compass held still without noise repeats one reading, with one rounding
    error: the run is taken once (σ would shrink with the hold time otherwise). A noisy one
    repeats a reading a few times in a row by chance, each with its own noise: kept."""
    from apmcal.solvers.magnetometer import distinct_readings

    mag = _sphere_samples(300, 500.0)
    held = np.concatenate([mag[:100], np.repeat(mag[100:101], 5000, axis=0), mag[101:]])
    kept = distinct_readings(held)
    np.testing.assert_array_equal(kept, mag)                       # time order kept
    rng = np.random.default_rng(1)
    noisy = np.round(np.array([300.0, -100.0, 200.0]) + rng.normal(0, 1.0, (5000, 3)))
    assert len(distinct_readings(noisy)) == len(noisy)
    twice = np.repeat(mag[:50], 2, axis=0)                          # short runs: all kept
    assert len(distinct_readings(twice)) == 100
