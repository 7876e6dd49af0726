"""The simulated vehicle: physically consistent truth, the sensor errors asked for, decodable output."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core import quaternion as cq
from drivers import AttitudeSample, DroneCanDecoder, ImuSample, MagSample, MavlinkDecoder
from drivers.sim import GRAVITY_M_S2, SimConfig, dronecan_stream, mavlink_stream, simulate

QUIET = SimConfig(
    gyro_noise_rad_s=0.0, accel_noise_m_s2=0.0, mag_noise_gauss=0.0, gyro_bias_rad_s=0.0, accel_bias_m_s2=0.0,
    gyro_bias_walk_rad_s_rt_s=0.0, accel_bias_walk_m_s2_rt_s=0.0, scale_error=0.0, vibration_m_s2=0.0,
    dropout_probability=0.0, attitude_error_rad=0.0,
)


@pytest.fixture(scope="module")
def flight():
    return simulate(SimConfig(duration_s=60.0, imu_rate_hz=1000.0))


def test_level_at_rest_reads_minus_g_and_the_earth_field():
    f = simulate(dataclasses.replace(QUIET, duration_s=0.01))
    assert cq.angular_distance(f.q_true[0], cq.IDENTITY) < 0.25  # wobble and yaw start near level
    assert f.accel_true_m_s2[0] == pytest.approx((0, 0, -GRAVITY_M_S2), abs=0.05)
    field = cq.rotate(f.q_true[0], f.mag_true_gauss[0])  # back to NED
    assert field == pytest.approx((0.21, 0.0, 0.43), abs=1e-12)


def test_gyro_truth_is_the_derivative_of_the_true_attitude(flight):
    # Independent: body rate from successive true quaternions, omega = rotvec(q_k* q_k+1) / dt.
    q = flight.q_true
    dt = 1e-3
    omega = cq.to_rotvec(cq.multiply(cq.conjugate(q[:-1]), q[1:])) / dt
    mid = 0.5 * (flight.gyro_true_rad_s[:-1] + flight.gyro_true_rad_s[1:])
    assert np.max(np.abs(omega - mid)) < 1e-3  # a world-frame rate would be off by ~15 rad/s


def test_programme_contains_hover_turns_aggressive_and_a_flip(flight):
    t = (flight.t_ns - flight.t_ns[0]) / 1e9
    rate = np.linalg.norm(flight.gyro_true_rad_s, axis=1)
    assert rate[t < 9].max() < 0.5  # hover
    assert rate[(t > 30) & (t < 38)].max() > 4.0  # aggressive
    flip = (t > 41.9) & (t < 42.7)
    assert np.sum(flight.gyro_true_rad_s[flip, 0]) * 1e-3 == pytest.approx(2 * np.pi, abs=0.05)
    assert flight.accel_true_m_s2[flip, 2].max() > -0.5 * GRAVITY_M_S2  # thrust cut while inverted
    # Hover and turns hold altitude: specific force rotated to NED cancels gravity vertically.
    upright = ~flip
    vertical = cq.rotate(flight.q_true[upright], flight.accel_true_m_s2[upright])[:, 2] + GRAVITY_M_S2
    assert np.max(np.abs(vertical)) < 1e-9


def test_noise_bias_and_scale_follow_the_config():
    cfg = dataclasses.replace(QUIET, duration_s=20.0, gyro_noise_rad_s=0.01, gyro_bias_rad_s=0.05, seed=3)
    f = simulate(cfg)
    residual = f.gyro_rad_s - f.gyro_true_rad_s - f.gyro_bias_rad_s
    assert np.std(residual, axis=0) == pytest.approx([0.01] * 3, rel=0.05)
    assert np.ptp(f.gyro_bias_rad_s, axis=0) == pytest.approx([0, 0, 0])  # no walk configured
    walk = simulate(dataclasses.replace(cfg, gyro_bias_walk_rad_s_rt_s=1e-3))
    drift = walk.gyro_bias_rad_s[-1] - walk.gyro_bias_rad_s[0]
    assert np.all(np.abs(drift) < 6 * 1e-3 * np.sqrt(20.0)) and np.any(np.abs(drift) > 1e-5)
    scaled = simulate(dataclasses.replace(QUIET, duration_s=60.0, scale_error=0.02))
    big = np.abs(scaled.gyro_true_rad_s) > 1.0
    ratio = scaled.gyro_rad_s[big] / scaled.gyro_true_rad_s[big]
    assert np.all(np.abs(ratio - 1) < 0.1) and np.std(ratio) > 0


def test_saturation_dropouts_and_rates():
    f = simulate(dataclasses.replace(QUIET, duration_s=60.0, gyro_range_rad_s=5.0, dropout_probability=0.1, imu_rate_hz=200.0, attitude_rate_hz=10.0, mag_rate_hz=50.0))
    assert np.max(np.abs(f.gyro_rad_s)) == 5.0
    assert np.max(np.abs(f.gyro_true_rad_s)) > 5.0
    assert np.mean(~f.imu_valid) == pytest.approx(0.1, abs=0.01)
    assert len(f.t_ns) == 12000 and len(f.attitude_index) == 600
    assert np.mean(~np.isnan(f.mag_gauss[:, 0])) == pytest.approx(0.25)
    assert np.all(np.diff(f.t_ns) == 5_000_000)


def test_same_seed_same_flight_other_seed_other_noise():
    a, b, c = (simulate(SimConfig(duration_s=2.0, seed=s)) for s in (1, 1, 2))
    assert np.array_equal(a.gyro_rad_s, b.gyro_rad_s) and np.array_equal(a.q_attitude, b.q_attitude)
    assert not np.array_equal(a.gyro_rad_s, c.gyro_rad_s)
    assert np.array_equal(a.q_true, c.q_true)


def test_mavlink_output_decodes_to_the_measurements():
    f = simulate(SimConfig(duration_s=5.0, dropout_probability=0.05))
    decoder = MavlinkDecoder()
    out = [s for _, _, data in mavlink_stream(f) for s in decoder.feed(data)]
    imu = [s for s in out if isinstance(s, ImuSample)]
    att = [s for s in out if isinstance(s, AttitudeSample)]
    assert [s.t_ns for s in imu] == f.t_ns[f.imu_valid].tolist()
    assert np.allclose([s.gyro_rad_s for s in imu], f.gyro_rad_s[f.imu_valid], rtol=1e-6, atol=1e-7)
    assert sum(s.mag_gauss is not None for s in imu) == np.sum(~np.isnan(f.mag_gauss[f.imu_valid, 0]))
    assert len(att) == len(f.attitude_index)
    assert np.all(cq.angular_distance(np.array([s.q_wxyz for s in att]), f.q_true[f.attitude_index]) < 0.06)
    # the simulated autopilot announces itself once a second, as a real one does: 5 HEARTBEATs in 5 s
    assert dict(decoder.stats) == {"accepted": len(out), "ignored": 5} and decoder.received["HEARTBEAT"] == 5


def test_ardupilot_style_output_decodes():
    f = simulate(dataclasses.replace(QUIET, duration_s=1.0))
    decoder = MavlinkDecoder()
    out = [s for _, _, d in mavlink_stream(f, imu_message="RAW_IMU", attitude_message="ATTITUDE") for s in decoder.feed(d)]
    att = [s for s in out if isinstance(s, AttitudeSample)]
    assert np.all(cq.angular_distance(np.array([s.q_wxyz for s in att]), f.q_true[f.attitude_index]) < 1e-5)


def test_dronecan_output_decodes_to_the_measurements():
    f = simulate(SimConfig(duration_s=1.0))
    decoder = DroneCanDecoder()
    out = [s for _, _, frames in dronecan_stream(f) for fr in frames for s in decoder.feed(fr)]
    imu = [s for s in out if isinstance(s, ImuSample)]
    mags = [s for s in out if isinstance(s, MagSample)]
    assert [s.t_ns for s in imu] == f.t_ns[f.imu_valid].tolist()
    assert np.allclose([s.accel_m_s2 for s in imu], f.accel_m_s2[f.imu_valid], rtol=2**-10, atol=1e-3)
    assert len(mags) == np.sum(~np.isnan(f.mag_gauss[f.imu_valid, 0]))
    assert len([s for s in out if isinstance(s, AttitudeSample)]) == len(f.attitude_index)
