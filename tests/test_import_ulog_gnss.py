"""``bingham-fuser import`` of a PX4 ULog with GNSS: ``vehicle_gps_position`` (older firmware's layout) or
``sensor_gps`` (newer layout), written here by a small ULog writer with PX4's field names and types, with
values from the simulator's truth; pyulog (the independent parser) reads them in the importer.

The shared sample log (pyulog's sample.ulg) has no GNSS topic: the test that says so skips without it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from core.earth_field import decimal_year, field_ned_gauss
from drivers.samples import GnssSample, ImuSample
from drivers.sim import SimConfig, simulate
from fuser.importers import import_log, read_px4
from fuser.record import read_log

from ulog_writer import ULogWriter

pytest.importorskip("pyulog")

SAMPLE_ULG = Path(__file__).resolve().parents[2] / "shared" / "data" / "px4" / "sample.ulg"
UNIX_START_S = 1781870400.0  # 2026-06-19 12:00 UTC

SENSOR_COMBINED = [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
                   ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
                   ("uint32_t", "accelerometer_integral_dt"), ("float[3]", "magnetometer_ga")]
VEHICLE_ATTITUDE = [("uint64_t", "timestamp"), ("float", "rollspeed"), ("float", "pitchspeed"), ("float", "yawspeed"),
                    ("float[4]", "q")]
OLD_GPS = [("uint64_t", "timestamp"), ("uint64_t", "time_utc_usec"), ("int32_t", "lat"), ("int32_t", "lon"),
           ("int32_t", "alt"), ("int32_t", "alt_ellipsoid"), ("float", "s_variance_m_s"), ("float", "c_variance_rad"),
           ("float", "eph"), ("float", "epv"), ("float", "hdop"), ("float", "vdop"), ("int32_t", "noise_per_ms"),
           ("int32_t", "jamming_indicator"), ("float", "vel_m_s"), ("float", "vel_n_m_s"), ("float", "vel_e_m_s"),
           ("float", "vel_d_m_s"), ("float", "cog_rad"), ("int32_t", "timestamp_time_relative"), ("float", "heading"),
           ("float", "heading_offset"), ("uint8_t", "fix_type"), ("uint8_t", "jamming_state"), ("bool", "vel_ned_valid"),
           ("uint8_t", "satellites_used")]
NEW_GPS = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("uint32_t", "device_id"),
           ("double", "latitude_deg"), ("double", "longitude_deg"), ("double", "altitude_msl_m"),
           ("double", "altitude_ellipsoid_m"), ("float", "s_variance_m_s"), ("float", "c_variance_rad"),
           ("uint8_t", "fix_type"), ("float", "eph"), ("float", "epv"), ("float", "hdop"), ("float", "vdop"),
           ("int32_t", "noise_per_ms"), ("uint16_t", "automatic_gain_control"), ("uint8_t", "jamming_state"),
           ("int32_t", "jamming_indicator"), ("uint8_t", "spoofing_state"), ("float", "vel_m_s"), ("float", "vel_n_m_s"),
           ("float", "vel_e_m_s"), ("float", "vel_d_m_s"), ("float", "cog_rad"), ("bool", "vel_ned_valid"),
           ("int32_t", "timestamp_time_relative"), ("uint64_t", "time_utc_usec"), ("uint8_t", "satellites_used")]


def write_ulog(path: Path, layout: str):
    """A 10-s PX4-style log: sensor_combined at 250 Hz, vehicle_attitude at 50 Hz, GNSS at 10 Hz (no fix for 1 s)."""
    f = simulate(SimConfig(seed=3, duration_s=10.0, imu_rate_hz=250.0, attitude_rate_hz=50.0, mag_field_ned_gauss=None,
                           decimal_year=decimal_year(UNIX_START_S)))
    w = ULogWriter(start_us=int(f.t_ns[0] // 1000))
    topic = "vehicle_gps_position" if layout == "old" else "sensor_gps"
    w.topic("sensor_combined", SENSOR_COMBINED)
    w.topic("vehicle_attitude", VEHICLE_ATTITUDE)
    w.topic(topic, OLD_GPS if layout == "old" else NEW_GPS)
    events = [(int(t), 0, k) for k, t in enumerate(f.t_ns.tolist())]
    events += [(int(f.t_ns[k]), 1, j) for j, k in enumerate(f.attitude_index.tolist())]
    g = f.gnss
    events += [(int(f.t_ns[k]), 2, i) for i, k in enumerate(g.index.tolist())]  # published on arrival
    written = []
    for t, kind, i in sorted(events):
        if kind == 0:
            mag = f.mag_true_gauss[i] if np.isnan(f.mag_gauss[i, 0]) else f.mag_gauss[i]
            w.write("sensor_combined", timestamp=t // 1000, gyro_rad=f.gyro_rad_s[i], gyro_integral_dt=4000,
                    accelerometer_timestamp_relative=0, accelerometer_m_s2=f.accel_m_s2[i], accelerometer_integral_dt=4000,
                    magnetometer_ga=mag)
        elif kind == 1:
            w.write("vehicle_attitude", timestamp=t // 1000, rollspeed=0.0, pitchspeed=0.0, yawspeed=0.0, q=f.q_attitude[i])
        else:
            fix = 1 if t < f.t_ns[0] + 1e9 else 3
            vn, ve, vd = g.vel_ned_m_s[i]
            sample_us = int(g.t_ns[i] // 1000)
            utc = int(UNIX_START_S * 1e6) + (sample_us - int(f.t_ns[0] // 1000))
            common = dict(s_variance_m_s=0.25, c_variance_rad=0.02, fix_type=fix, eph=1.2, epv=2.5, hdop=0.7, vdop=1.1,
                          noise_per_ms=90, jamming_indicator=20, vel_m_s=math.hypot(vn, ve), vel_n_m_s=vn, vel_e_m_s=ve,
                          vel_d_m_s=vd, cog_rad=math.atan2(ve, vn), timestamp_time_relative=0, jamming_state=1,
                          vel_ned_valid=fix >= 2, satellites_used=14 if fix == 3 else 2, time_utc_usec=utc if fix == 3 else 0)
            lat, lon, alt = (g.lat_deg[i], g.lon_deg[i], g.alt_m[i]) if fix == 3 else (0.0, 0.0, 0.0)
            if layout == "old":
                w.write(topic, timestamp=t // 1000, lat=round(lat * 1e7), lon=round(lon * 1e7), alt=round(alt * 1e3),
                        alt_ellipsoid=round((alt + 47.0) * 1e3), heading=float("nan"), heading_offset=0.0, **common)
                stamp_ns = (t // 1000) * 1000
            else:
                w.write(topic, timestamp=t // 1000, timestamp_sample=sample_us, device_id=11010310, latitude_deg=lat,
                        longitude_deg=lon, altitude_msl_m=alt, altitude_ellipsoid_m=alt + 47.0, automatic_gain_control=800,
                        spoofing_state=1, **common)
                stamp_ns = sample_us * 1000
            written.append((stamp_ns, fix, lat, lon, alt, vn, ve, vd, utc))
    path.write_bytes(bytes(w.data))
    return written


@pytest.fixture(scope="module", params=["old", "new"])
def logged(request, tmp_path_factory):
    path = tmp_path_factory.mktemp(request.param) / f"{request.param}.ulg"
    written = write_ulog(path, request.param)
    summary = import_log(path, path.with_suffix(".mcap"), config_path=path.with_suffix(".toml"))
    return path, written, summary


def test_gnss_fixes_are_read_in_either_layout(logged):
    path, written, _ = logged
    data = read_px4(path)
    assert len(written) == 99
    assert [g.t_ns for g in data.gnss] == [w[0] for w in written]  # timestamp_sample where the layout has it
    assert [g.fix_type for g in data.gnss] == [w[1] for w in written]
    for g, (_, fix, lat, lon, alt, vn, ve, vd, _) in zip(data.gnss, written):
        if fix < 2:
            assert g.vel_ned_m_s is None and g.lat_deg is None
            continue
        np.testing.assert_allclose(g.vel_ned_m_s, (vn, ve, vd), atol=1e-5)  # float32 in the log
        assert g.vertical_velocity and g.speed_accuracy_m_s == pytest.approx(0.25)
        assert (g.lat_deg, g.lon_deg) == pytest.approx((lat, lon), abs=1.1e-7) and g.alt_m == pytest.approx(alt, abs=1.1e-3)


def test_gnss_goes_through_mavlink_into_the_mcap(logged):
    _, written, summary = logged
    inputs = [s for s, _ in read_log(summary.path).inputs()]
    gnss = [s for s in inputs if isinstance(s, GnssSample)]
    assert summary.gnss == len(gnss) == len(written)
    for s, (t, fix, lat, lon, alt, vn, ve, _, _) in zip(gnss, written):
        assert s.t_ns == t and s.fix_type == fix
        if fix == 3:
            assert math.hypot(*s.vel_ned_m_s[:2]) == pytest.approx(math.hypot(vn, ve), abs=0.006)  # GPS_RAW_INT, cm/s
            assert (s.lat_deg, s.lon_deg) == pytest.approx((lat, lon), abs=1.1e-7)
    assert sum(isinstance(s, ImuSample) for s in inputs) == 2500


def test_reference_field_is_the_world_magnetic_models_at_the_first_fix(logged):
    _, written, summary = logged
    first = next(w for w in written if w[1] == 3)
    expected = field_ned_gauss(first[2], first[3], first[4], decimal_year(first[8] * 1e-6))
    assert summary.mag_field_ned_gauss == pytest.approx(expected, abs=1e-6)
    assert "World Magnetic Model" in read_log(summary.path).metadata["bingham_fuser"]["mag_field_source"]


@pytest.mark.skipif(not SAMPLE_ULG.exists(), reason="../shared/data/px4/sample.ulg not available")
def test_the_shared_sample_log_has_no_gnss():
    assert read_px4(SAMPLE_ULG, duration_s=5.0).gnss == []
