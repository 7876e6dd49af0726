"""A tick's vector readings averaged in the body frame of the state's time (fuser.model.body_frame)."""

import numpy as np

from core import quaternion as quat
from fuser.model.body_frame import lags_s, mean_in_state_body


def test_lags_are_the_seconds_behind_the_state():
    np.testing.assert_allclose(lags_s([7_500_000, 10_000_000, 2_500_000], 10_000_000), [0.0025, 0.0, 0.0075], rtol=1e-15)


def test_without_a_rate_the_mean_is_the_plain_mean():
    vectors = [(0.1, -9.7, 0.3), (0.2, -9.9, 0.1), (0.0, -9.8, 0.2)]
    np.testing.assert_allclose(mean_in_state_body(vectors, lags_s([1, 2, 3], 4), None), [0.1, -9.8, 0.2], rtol=1e-15)


def test_each_reading_is_turned_by_the_rate_over_its_own_lag():
    """The mean of ``v_i - (w lag_i) x v_i``, each reading turned on its own (numpy's cross product)."""
    rng = np.random.default_rng(2)
    vectors = [tuple(v) for v in rng.normal(0.0, 5.0, (4, 3))]
    lags = lags_s([2_500_000, 5_000_000, 7_500_000, 10_000_000], 10_000_000)
    rate = np.array([3.0, -1.0, 10.0])
    expected = np.mean([np.asarray(v) - np.cross(rate * lag, v) for v, lag in zip(vectors, lags)], axis=0)
    np.testing.assert_allclose(mean_in_state_body(vectors, lags, rate), expected, rtol=1e-13)


def test_a_world_fixed_vector_seen_by_a_turning_body_is_its_reading_at_the_state_time():
    """A body turning at 600 deg/s reads a world-fixed field at four instants of a 10-ms tick; turned to the tick's
    end and averaged it is the field in the body frame of that instant, to the small-angle rotation's second order
    (the plain mean is 1.5 degrees off)."""
    rate = np.radians([0.0, 0.0, 600.0])
    field_world = np.array([0.2, 0.05, 0.4])
    times_ns = [2_500_000, 5_000_000, 7_500_000, 10_000_000]
    body = lambda t_ns: quat.rotate(quat.conjugate(quat.from_rotvec(rate * t_ns * 1e-9)), field_world)  # noqa: E731
    readings = [tuple(body(t)) for t in times_ns]
    at_state = body(10_000_000)
    turned = mean_in_state_body(readings, lags_s(times_ns, 10_000_000), rate)
    plain = mean_in_state_body(readings, lags_s(times_ns, 10_000_000), None)
    angle = lambda a, b: np.degrees(np.arccos(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b)))  # noqa: E731
    assert angle(plain, at_state) > 1.0
    assert angle(turned, at_state) < 0.04  # the second order left: mean(theta^2) / 2 of the horizontal part, 0.03 deg
