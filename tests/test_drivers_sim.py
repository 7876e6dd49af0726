"""The simulated vehicle: physically consistent truth, the sensor errors asked for, decodable output."""

from __future__ import annotations

import dataclasses
import re
import sys

import numpy as np
import pytest

from core import quaternion as cq
from core.earth_field import field_ned_gauss
from drivers import AttitudeSample, DroneCanDecoder, GnssSample, ImuSample, MagSample, MavlinkDecoder
from drivers.scenarios import scenario
from drivers.sim import GRAVITY_M_S2, SimConfig, dronecan_stream, mavlink_stream, samples, simulate

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
    field = cq.rotate(f.q_true[0], f.mag_true_gauss[0])  # back to NED: the WMM's at the start (Zurich, mid-2026)
    assert field == pytest.approx(field_ned_gauss(47.3977, 8.5456, 488.0, 2026.5), abs=1e-12)


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
    # Hover, turns and manoeuvres hold altitude: specific force rotated to NED cancels gravity vertically.
    before = t < 41.9
    vertical = cq.rotate(flight.q_true[before], flight.accel_true_m_s2[before])[:, 2] + GRAVITY_M_S2
    assert np.max(np.abs(vertical)) < 1e-9
    assert np.max(np.abs(flight.alt_true_m[before] - 488.0)) < 1e-6
    # the flip drops it a few metres; the altitude hold then stops the fall within seconds
    assert 1.0 < 488.0 - flight.alt_true_m[-1] < 10.0
    assert np.max(np.abs(flight.vel_ned_true_m_s[t > 50.0, 2])) < 0.01


def test_translation_follows_thrust_drag_and_gravity(flight):
    """Independent of the integrator: the velocity's central difference equals R f + g, and the
    accelerometer sees the rotor drag, -k times the body-horizontal velocity."""
    t = (flight.t_ns - flight.t_ns[0]) / 1e9
    dt = 1e-3
    v = flight.vel_ned_true_m_s
    accel_ned = cq.rotate(flight.q_true, flight.accel_true_m_s2) + np.array([0.0, 0.0, GRAVITY_M_S2])
    smooth = (np.abs(t - 42.3) > 0.5)[1:-1]  # the thrust cut at 60 degrees of tilt is a step
    central = (v[2:] - v[:-2]) / (2 * dt)
    # (Euler steps: the central difference is the mean of two steps' accelerations, which differ by
    # up to 0.05 m/s^2 at the manoeuvres' jerk; a missing or mis-rotated force would be metres per s^2)
    assert np.max(np.abs(central - accel_ned[1:-1])[smooth]) < 0.1
    v_body = cq.rotate(cq.conjugate(flight.q_true), v)
    np.testing.assert_allclose(flight.accel_true_m_s2[:, :2], -0.35 * v_body[:, :2], atol=1e-12)
    # it moves in the turns and manoeuvres (metres per second, sideways specific force well above the noise)
    assert np.max(np.linalg.norm(v[:, :2], axis=1)) > 3.0
    assert np.max(np.abs(flight.accel_true_m_s2[(t > 10) & (t < 40), :2])) > 1.0
    # at rest it stays put: hover drifts by centimetres per second at most
    assert np.max(np.linalg.norm(v[t < 9, :2], axis=1)) < 0.3


def test_without_drag_and_damping_the_specific_force_is_thrust_along_body_z():
    """The earlier model: f = (0, 0, -g / cos tilt) while within 60 degrees of upright."""
    f = simulate(dataclasses.replace(QUIET, duration_s=41.0, imu_rate_hz=200.0, rotor_drag_1_s=0.0, vertical_damping_1_s=0.0))
    tilt_cos = 1.0 - 2.0 * (f.q_true[:, 1] ** 2 + f.q_true[:, 2] ** 2)
    np.testing.assert_allclose(f.accel_true_m_s2[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(f.accel_true_m_s2[:, 2], -GRAVITY_M_S2 / tilt_cos, rtol=1e-12)


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
    assert set(decoder.stats) <= {"accepted", "ignored"}


def test_dronecan_sends_the_receivers_fixes_as_fix2():
    """Fix2: NED velocity as float32 (the DSDL's), the speed accuracy as three equal velocity variances (float16),
    WGS84 position in 1e-8 deg and mm, stamped with the fix time (us) on the node's time base."""
    f = simulate(SimConfig(duration_s=3.0, seed=4))
    decoder = DroneCanDecoder()
    gnss = [s for _, _, frames in dronecan_stream(f) for fr in frames for s in decoder.feed(fr) if isinstance(s, GnssSample)]
    g = f.gnss
    assert [s.t_ns for s in gnss] == g.t_ns.tolist()
    np.testing.assert_allclose([s.vel_ned_m_s for s in gnss], g.vel_ned_m_s, rtol=1e-6, atol=1e-6)
    assert all(s.vertical_velocity and not s.filtered and s.fix_type == 3 for s in gnss)
    assert [s.speed_accuracy_m_s for s in gnss] == pytest.approx([0.1] * len(gnss), rel=2**-10)
    np.testing.assert_allclose([s.lat_deg for s in gnss], g.lat_deg, atol=1e-8)
    np.testing.assert_allclose([s.alt_m for s in gnss], g.alt_m, atol=1e-3)


# -- GNSS ------------------------------------------------------------------------------------------
def _metres_per_degree(lat_deg: float) -> tuple[float, float]:
    """Length of a degree of latitude and of longitude (the usual series for the WGS84 ellipsoid)."""
    phi = np.radians(lat_deg)
    return (111132.92 - 559.82 * np.cos(2 * phi) + 1.175 * np.cos(4 * phi), 111412.84 * np.cos(phi) - 93.5 * np.cos(3 * phi))


def test_gnss_rate_latency_and_errors():
    f = simulate(SimConfig(duration_s=60.0, seed=5))
    g = f.gnss
    assert np.all(np.diff(g.t_ns) == 100_000_000)  # 10 Hz
    delay = f.t_ns[g.index] - g.t_ns
    assert np.all(delay >= 150_000_000) and np.all(delay < 150_000_000 + 2_500_000)  # sent 0.15 s later, at the next IMU tick
    at_fix = np.searchsorted(f.t_ns, g.t_ns)
    vel_err = g.vel_ned_m_s - f.vel_ned_true_m_s[at_fix]
    assert np.std(vel_err, axis=0) == pytest.approx([0.1] * 3, rel=0.1)
    assert np.all(np.abs(np.mean(vel_err, axis=0)) < 0.02)
    assert g.speed_accuracy_m_s == 0.1 and g.fix_type == 3
    m_lat, m_lon = _metres_per_degree(47.4)
    north = (g.lat_deg - f.lat_true_deg[at_fix]) * m_lat
    east = (g.lon_deg - f.lon_true_deg[at_fix]) * m_lon
    up = g.alt_m - f.alt_true_m[at_fix]
    assert np.max(np.abs(north)) < 6 * 1.5 and np.max(np.abs(east)) < 6 * 1.5 and np.max(np.abs(up)) < 6 * 3.0
    assert np.std(north) > 0.05 and np.std(up) > 0.1
    assert np.corrcoef(north[:-1], north[1:])[0, 1] > 0.9  # a wandering error, not white noise
    # the true track itself: the vehicle drifts tens of metres in the turns, which the geodetic positions show
    travelled = np.hypot((f.lat_true_deg - 47.3977) * m_lat, (f.lon_true_deg - 8.5456) * m_lon)
    assert 5.0 < travelled.max() < 500.0


@pytest.mark.parametrize("message", ["GPS_RAW_INT", "GPS_INPUT", "GLOBAL_POSITION_INT"])
def test_gnss_goes_through_mavlink(message):
    f = simulate(SimConfig(duration_s=20.0, seed=2))
    decoder = MavlinkDecoder()
    out = [s for _, _, data in mavlink_stream(f, gnss_message=message) for s in decoder.feed(data)]
    gnss = [s for s in out if isinstance(s, GnssSample)]
    g = f.gnss
    vel = np.array([s.vel_ned_m_s for s in gnss])
    if message == "GLOBAL_POSITION_INT":  # the autopilot's solution: its velocity now, stamped when sent (ms)
        assert [s.t_ns for s in gnss] == ((f.t_ns[g.index] // 1_000_000) * 1_000_000).tolist()
        assert all(s.filtered and s.speed_accuracy_m_s is None for s in gnss)
        np.testing.assert_allclose(vel, g.solution_vel_ned_m_s, atol=0.006)
        err = g.solution_vel_ned_m_s - f.vel_ned_true_m_s[g.index]
        assert np.std(err, axis=0) == pytest.approx([0.1] * 3, rel=0.15)
    else:  # the receiver's fix: measured at its time, sent 0.15 s later
        assert [s.t_ns for s in gnss] == g.t_ns.tolist()
        assert not any(s.filtered for s in gnss)
    if message == "GPS_RAW_INT":  # ground speed (cm/s) and course (cdeg) only
        np.testing.assert_allclose(np.hypot(vel[:, 0], vel[:, 1]), np.hypot(g.vel_ned_m_s[:, 0], g.vel_ned_m_s[:, 1]), atol=0.006)
        assert not any(s.vertical_velocity for s in gnss)
    elif message == "GPS_INPUT":  # NED velocity in m/s (float32) and the speed accuracy
        np.testing.assert_allclose(vel, g.vel_ned_m_s, atol=1e-5)
        assert all(s.vertical_velocity and s.speed_accuracy_m_s == pytest.approx(0.1) for s in gnss)
    np.testing.assert_allclose([s.lat_deg for s in gnss], g.lat_deg, atol=1e-7)
    np.testing.assert_allclose([s.alt_m for s in gnss], g.alt_m, atol=1e-3)
    assert set(decoder.stats) <= {"accepted", "ignored"}  # nothing refused; ignored: the autopilot's heartbeats


def test_without_gnss_nothing_is_sent_and_the_imu_is_the_same():
    a = simulate(SimConfig(duration_s=3.0, seed=9))
    b = simulate(SimConfig(duration_s=3.0, seed=9, gnss=False))
    assert b.gnss is None and a.gnss is not None
    assert not any(isinstance(s, GnssSample) for _, _, tick in samples(b) for s in tick)
    assert np.array_equal(a.gyro_rad_s, b.gyro_rad_s) and np.array_equal(a.accel_m_s2, b.accel_m_s2)


def test_a_scenario_cut_keeps_the_fixes_sent_within_it():
    f = scenario("aggressive", seed=0)  # seconds 4-32 of the programme at 200 Hz
    assert np.all((f.gnss.index >= 0) & (f.gnss.index < len(f.t_ns)))
    assert len(f.gnss.t_ns) == 280
    sent = [s for _, _, tick in samples(f) for s in tick if isinstance(s, GnssSample)]
    assert [s.t_ns for s in sent] == f.gnss.t_ns.tolist()
    assert f.gnss.t_ns[0] < f.t_ns[0]  # the first fix was measured before the cut began and arrives after


def test_world_magnetic_model_field_when_none_is_configured():
    f = simulate(SimConfig(duration_s=1.0, mag_field_ned_gauss=None, decimal_year=2027.0))
    wmm = field_ned_gauss(47.3977, 8.5456, 488.0, 2027.0)
    np.testing.assert_allclose(cq.rotate(f.q_true, f.mag_true_gauss), np.tile(wmm, (len(f.t_ns), 1)), atol=1e-6)
    assert f.mag_field_ned_gauss == pytest.approx(wmm)
    assert simulate(SimConfig(duration_s=0.1)).mag_field_ned_gauss == pytest.approx(field_ned_gauss(47.3977, 8.5456, 488.0, 2026.5))
    assert simulate(SimConfig(duration_s=0.1, mag_field_ned_gauss=(0.21, 0.0, 0.43))).mag_field_ned_gauss == (0.21, 0.0, 0.43)


@pytest.mark.parametrize(
    ("field", "value"),
    [("gnss_rate_hz", 0.0), ("imu_rate_hz", -1.0), ("gnss_latency_s", float("nan")), ("dropout_probability", 1.0),
     ("rotor_drag_1_s", -0.1), ("decimal_year", 2041.0), ("imu_rate_hz", 1e9), ("gnss_rate_hz", 20_000.0), ("seed", -1)],
)
def test_sim_config_rejects_bad_values_naming_the_field(field, value):
    changes = {field: value, "mag_field_ned_gauss": None} if field == "decimal_year" else {field: value}
    with pytest.raises(ValueError, match=field):
        SimConfig(**changes)


def test_fixed_wing_without_jsbsim_is_one_clear_error(monkeypatch, capsys):
    from fuser.cli import main

    monkeypatch.setitem(sys.modules, "jsbsim", None)  # as if not installed: importing it raises ImportError
    assert main(["sim", "--scenario", "fixedwing", "--speed", "0", "--no-zenoh", "-o", ""]) == 2
    err = capsys.readouterr().err
    assert "jsbsim" in err and "pip install" in err and "Traceback" not in err


@pytest.mark.parametrize(("duration_s", "imu_rate_hz", "samples"),
                         [(0.001, 400.0, "0.4"), (1e12, 400.0, "4e+14"), (240.0, 10_000.0, "2.4e+06")])
def test_a_flight_the_simulator_cannot_lay_out_is_refused_with_its_sample_count(duration_s, imu_rate_hz, samples):
    """Fewer than two IMU samples was an IndexError deep in the simulator; a day at 10 kHz a MemoryError (447 GiB)."""
    with pytest.raises(ValueError, match=rf"a flight of {re.escape(samples)} IMU samples: the simulator needs 2 at least"):
        SimConfig(duration_s=duration_s, imu_rate_hz=imu_rate_hz)
    assert len(simulate(SimConfig(duration_s=2 / 400.0)).t_ns) == 2
