"""``bingham-fuser import`` of a ULog from current PX4 (1.10 on): the magnetometer is no longer in
``sensor_combined`` but in its own topic, ``vehicle_magnetometer``; and the logger's dropouts.

The import read only ``sensor_combined.magnetometer_ga``: a current log came in without any magnetometer, in
silence, and its heading rested on the gyro alone. The log here is written by the project's ULog writer with
PX4 1.14's field names and types (msg/SensorCombined.msg, msg/VehicleMagnetometer.msg), values from the
simulator; pyulog (the independent parser) reads it in the importer.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from drivers.sim import SimConfig, simulate
from fuser.importers import read_px4

from ulog_writer import ULogWriter

pytest.importorskip("pyulog")

SENSOR_COMBINED_1_14 = [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
                        ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
                        ("uint32_t", "accelerometer_integral_dt"), ("uint8_t", "accelerometer_clipping"),
                        ("uint8_t", "gyro_clipping"), ("uint8_t", "accel_calibration_count"),
                        ("uint8_t", "gyro_calibration_count")]
VEHICLE_MAGNETOMETER = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("uint32_t", "device_id"),
                        ("float[3]", "magnetometer_ga"), ("uint8_t", "calibration_count")]
VEHICLE_ATTITUDE = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("float[4]", "q")]
IMU_HZ, MAG_EVERY = 250.0, 5  # the magnetometer at 50 Hz
MAG_LAG_US = 2_000  # published 2 ms after its sample, between two IMU samples


def _write(path: Path) -> list[tuple[int, np.ndarray]]:
    """A 6-s log; returns each magnetometer reading an IMU sample follows as (sample time in us, gauss)."""
    f = simulate(SimConfig(seed=5, duration_s=6.0, imu_rate_hz=IMU_HZ, attitude_rate_hz=50.0, mag_field_ned_gauss=(0.2, 0.01, 0.43)))
    w = ULogWriter(start_us=int(f.t_ns[0] // 1000))
    for name, fields in (("sensor_combined", SENSOR_COMBINED_1_14), ("vehicle_magnetometer", VEHICLE_MAGNETOMETER),
                         ("vehicle_attitude", VEHICLE_ATTITUDE)):
        w.topic(name, fields)
    mags, attitude = [], dict(zip(f.attitude_index.tolist(), range(len(f.attitude_index))))
    for k, t_us in enumerate((f.t_ns // 1000).tolist()):
        w.write("sensor_combined", timestamp=t_us, gyro_rad=f.gyro_rad_s[k], gyro_integral_dt=4000, accelerometer_timestamp_relative=0,
                accelerometer_m_s2=f.accel_m_s2[k], accelerometer_integral_dt=4000, accelerometer_clipping=0, gyro_clipping=0,
                accel_calibration_count=1, gyro_calibration_count=1)
        if k % MAG_EVERY == 0:
            mag = f.mag_true_gauss[k] if np.isnan(f.mag_gauss[k, 0]) else f.mag_gauss[k]
            w.write("vehicle_magnetometer", timestamp=t_us + MAG_LAG_US, timestamp_sample=t_us + 1, device_id=396825,
                    magnetometer_ga=mag, calibration_count=1)
            mags.append((t_us + 1, mag))
        if k in attitude:
            w.write("vehicle_attitude", timestamp=t_us, timestamp_sample=t_us, q=f.q_attitude[attitude[k]])
    last_us = int(f.t_ns[-1] // 1000) + 1  # a reading after the last IMU sample: no IMU message carries it
    w.write("vehicle_magnetometer", timestamp=last_us + MAG_LAG_US, timestamp_sample=last_us, device_id=396825,
            magnetometer_ga=f.mag_true_gauss[-1], calibration_count=1)
    path.write_bytes(bytes(w.data))
    return mags


def test_the_magnetometer_of_current_px4_rides_with_the_next_imu_sample(tmp_path: Path) -> None:
    path = tmp_path / "px4_1_14.ulg"
    mags = _write(path)
    data = read_px4(path)
    assert data.mag is not None
    carried = np.flatnonzero(~np.isnan(data.mag[:, 0]))
    assert len(carried) == len(mags) == 300
    assert data.skipped.get("mag_after_last_imu") == 1
    for k, (t_us, mag) in zip(carried.tolist(), mags):
        assert data.t_ns[k] == data.t_ns[np.searchsorted(data.t_ns, t_us * 1000)]  # the first IMU sample at or after it
        np.testing.assert_allclose(data.mag[k], mag, rtol=1e-6)  # float32 in the log
    assert data.field_source.startswith("mean of the first")  # no GNSS, no EKF2 field state: measured at rest
    assert data.mag_field_ned_gauss is not None
    assert np.linalg.norm(data.mag_field_ned_gauss) == pytest.approx(np.linalg.norm((0.2, 0.01, 0.43)), rel=0.02)


def test_the_loggers_dropouts_are_counted(tmp_path: Path) -> None:
    """PX4's logger writes a dropout message ('O', its duration in ms) where its buffer overflowed and data was lost:
    the import cannot bring that data back, but it says how much the log lacks."""
    path = tmp_path / "dropouts.ulg"
    _write(path)
    w_data = bytearray(path.read_bytes())
    for duration_ms in (35, 120):
        w_data += struct.pack("<HBH", 2, ord("O"), duration_ms)  # a dropout message: uint16 duration in ms
    path.write_bytes(bytes(w_data))
    data = read_px4(path)
    assert data.skipped["logger_dropouts"] == 2 and data.skipped["logger_dropout_ms"] == 155
