"""The JSBSim fixed-wing flight: its truth obeys the strapdown navigation equations, and it flies the programme.

Independent checks: the attitude JSBSim reports must follow from its gyro rates (minus the earth's
rotation and the transport rate of the local NED frame), and its specific force must equal the NED
acceleration minus gravity and the Coriolis and transport terms (Titterton & Weston, "Strapdown
Inertial Navigation Technology", 2nd ed., eqs. 3.69-3.70: v_dot = C f - (2 w_ie + w_en) x v + g),
with g the WGS84 normal gravity (Somigliana's formula, free-air gradient 3.086e-6 1/s^2) written
down here, not taken from JSBSim.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from core import earth_field
from core import quaternion as cq
from drivers import AttitudeSample, GnssSample, ImuSample, MavlinkDecoder
from drivers.sim import mavlink_stream

jsbsim_flight = pytest.importorskip("drivers.jsbsim_flight")
pytest.importorskip("jsbsim")

EARTH_RATE_RAD_S = 7.292115e-5
WGS84_A_M = 6378137.0
RATE_HZ = 200.0
DT = 1.0 / RATE_HZ


@pytest.fixture(scope="module")
def short():
    """30 s at 200 Hz: level flight, then the roll into the sustained 30-degree turn at 15 s."""
    return jsbsim_flight.simulate_fixed_wing(jsbsim_flight.fixed_wing_config(duration_s=30.0, imu_rate_hz=RATE_HZ, seed=4))


def _euler_deg(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    return np.degrees(np.column_stack([roll, pitch]))


def _frame_rates_ned(f) -> tuple[np.ndarray, np.ndarray]:
    """Earth rate and transport rate of the local NED frame, in NED (T&W eqs. 3.71-3.72, spherical radius)."""
    lat = np.radians(f.lat_true_deg)
    r = WGS84_A_M + f.alt_true_m
    vn, ve = f.vel_ned_true_m_s[:, 0], f.vel_ned_true_m_s[:, 1]
    w_ie = EARTH_RATE_RAD_S * np.column_stack([np.cos(lat), 0 * lat, -np.sin(lat)])
    w_en = np.column_stack([ve / r, -vn / r, -ve * np.tan(lat) / r])
    return w_ie, w_en


def test_gyro_integrates_to_the_attitude(short):
    q = short.q_true
    w_ie, w_en = _frame_rates_ned(short)
    body_rate_over_ned = short.gyro_true_rad_s - cq.rotate(cq.conjugate(q), w_ie + w_en)
    # rate from successive attitudes against the mean rate over each step
    from_attitude = cq.to_rotvec(cq.multiply(cq.conjugate(q[:-1]), q[1:])) / DT
    mean_rate = 0.5 * (body_rate_over_ned[:-1] + body_rate_over_ned[1:])
    err = from_attitude - mean_rate
    assert np.sqrt(np.mean(err**2)) < 2e-4 and np.max(np.abs(err)) < 3e-3  # rad/s; the roll entry peaks near 0.2 rad/s
    # and integrated over the 25 s through the roll entry, the attitude is carried to within 0.05 degree
    q_int = q[5 * int(RATE_HZ)].copy()
    for w in mean_rate[5 * int(RATE_HZ) :]:
        q_int = cq.normalize(cq.multiply(q_int, cq.from_rotvec(w * DT)))
    assert math.degrees(float(cq.angular_distance(q_int, q[-1]))) < 0.05


def test_specific_force_is_acceleration_minus_gravity_in_the_body_frame(short):
    q, v = short.q_true, short.vel_ned_true_m_s
    lat = np.radians(short.lat_true_deg)
    s2 = np.sin(lat) ** 2
    gravity = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999013 * s2) - 3.086e-6 * short.alt_true_m
    w_ie, w_en = _frame_rates_ned(short)
    v_dot = np.gradient(v, DT, axis=0)
    f_ned = v_dot + np.cross(2 * w_ie + w_en, v) - np.column_stack([0 * gravity, 0 * gravity, gravity])
    expected = cq.rotate(cq.conjugate(q), f_ned)
    err = (short.accel_true_m_s2 - expected)[20:-2]  # from 0.1 s on: the autopilot engages at the first step
    assert np.sqrt(np.mean(err**2)) < 0.002 and np.max(np.abs(err)) < 0.03  # m/s^2; measured 4e-4 RMS
    # level flight reads the reaction to gravity: about (0, 0, -9.8)
    assert short.accel_true_m_s2[int(10 * RATE_HZ), 2] == pytest.approx(-9.8, abs=0.4)


def test_the_turn_is_sustained_and_coordinated(short):
    roll, _ = _euler_deg(short.q_true).T
    t = (short.t_ns - short.t_ns[0]) * 1e-9
    turn = t > 20.0
    assert np.all(np.abs(roll[turn] - 30.0) < 3.0)  # 30 degrees of bank held
    assert np.max(np.abs(roll[t < 14.0])) < 3.0  # wings level before
    # coordinated: no sideways specific force (the ball centred), and the turn rate a coordinated turn
    # has, psi_dot = (g + a_up) tan(bank) / V (lift tilted by the bank carries weight and centripetal force)
    assert np.max(np.abs(short.accel_true_m_s2[turn, 1])) < 0.3
    v = short.vel_ned_true_m_s
    course = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    course_rate = np.gradient(course, DT)
    a_up = -np.gradient(v[:, 2], DT)
    predicted = (9.806 + a_up) * np.tan(np.radians(roll)) / np.linalg.norm(v[:, :2], axis=1)
    assert np.median(course_rate[turn] / predicted[turn]) == pytest.approx(1.0, abs=0.03)


def test_the_programme_has_30_and_45_degree_turns_a_climb_and_a_loiter():
    f = jsbsim_flight.fixed_wing_trajectory(jsbsim_flight.fixed_wing_config(imu_rate_hz=50.0))
    roll, _ = _euler_deg(f.q_true).T
    t = f.t_s
    h = f.alt_true_m - f.alt_true_m[0]

    def during(a, b):
        return (t > a) & (t < b)

    assert np.median(roll[during(25, 55)]) == pytest.approx(30.0, abs=2.0)
    assert np.median(roll[during(105, 135)]) == pytest.approx(-45.0, abs=2.0)
    assert np.median(roll[during(160, 240)]) == pytest.approx(35.0, abs=2.0)
    assert np.median(h[during(85, 95)]) == pytest.approx(150.0, abs=20.0)  # climbed
    # the loiter circles: heading turns through more than a full circle
    psi = np.unwrap(np.arctan2(*cq.rotate(f.q_true, np.array([1.0, 0.0, 0.0]))[:, 1::-1].T))
    assert np.degrees(psi[-1] - psi[np.searchsorted(t, 160.0)]) > 360.0
    assert t[-1] == pytest.approx(jsbsim_flight.PROGRAMME_S, abs=0.05)


def test_magnetometer_reads_the_world_magnetic_model_field(short):
    back_to_ned = cq.rotate(short.q_true, short.mag_true_gauss)
    wmm = earth_field.field_ned_gauss(float(short.lat_true_deg[0]), float(short.lon_true_deg[0]),
                                      float(short.alt_true_m[0]), jsbsim_flight.FIXED_WING.decimal_year)
    np.testing.assert_allclose(back_to_ned[0], wmm, atol=1e-9)
    np.testing.assert_allclose(back_to_ned[-1], wmm, atol=2e-4)  # 1.5 km away: the field changes by a few nT
    assert short.mag_field_ned_gauss == pytest.approx(wmm)


def test_same_seed_same_flight():
    config = jsbsim_flight.fixed_wing_config(duration_s=5.0, imu_rate_hz=RATE_HZ, seed=2)
    a, b = jsbsim_flight.simulate_fixed_wing(config), jsbsim_flight.simulate_fixed_wing(config)
    assert np.array_equal(a.q_true, b.q_true) and np.array_equal(a.accel_m_s2, b.accel_m_s2)
    assert np.array_equal(a.gnss.vel_ned_m_s, b.gnss.vel_ned_m_s)


def test_flight_goes_through_the_mavlink_encoders_and_decoders(short):
    decoder = MavlinkDecoder()
    out = [s for _, _, data in mavlink_stream(short) for s in decoder.feed(data)]
    imu = [s for s in out if isinstance(s, ImuSample)]
    gnss = [s for s in out if isinstance(s, GnssSample)]
    assert [s.t_ns for s in imu] == short.t_ns[short.imu_valid].tolist()
    np.testing.assert_allclose([s.accel_m_s2 for s in imu], short.accel_m_s2[short.imu_valid], rtol=1e-6, atol=1e-5)
    assert len([s for s in out if isinstance(s, AttitudeSample)]) == len(short.attitude_index)
    assert len(gnss) == len(short.gnss.t_ns) and 9 * 29 < len(gnss) <= 10 * 30  # 10 Hz, the last fixes still in flight
    speed = np.hypot(short.gnss.vel_ned_m_s[:, 0], short.gnss.vel_ned_m_s[:, 1])
    np.testing.assert_allclose([math.hypot(*s.vel_ned_m_s[:2]) for s in gnss], speed, atol=0.006)  # cm/s on the wire
    assert set(decoder.stats) <= {"accepted", "ignored"}  # nothing refused; ignored: the autopilot's heartbeats
