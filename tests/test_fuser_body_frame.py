"""A tick's vector readings averaged in the body frame of the state's time (fuser.model.body_frame)."""

import numpy as np

from core import quaternion as quat
from drivers.samples import ImuSample, SourceId
from fuser.config import FuserConfig
from fuser.model import FusionModel
from fuser.model.body_frame import mean_in_state_body
from fuser.model.tick import TickInput

NO_RATE = (0.0, 0.0, 0.0)


def _lags_s(placed_ns: list[int], state_ns: int) -> np.ndarray:
    """Seconds each sample (at its time on the loop's timeline) lies behind the state's time, as the tick computes
    them (``fuser.model.fusion.tick``)."""
    return np.array([(state_ns - t) * 1e-9 for t in placed_ns])


def _angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def test_lags_are_the_seconds_behind_the_state():
    """``lags_s`` is gone: the compiled tick computes each IMU sample's lag itself, from its placed time (its own
    time plus its stream's clock offset), so this is the tick's check. Samples placed 7.5, 10 and 2.5 ms into a first
    tick ending at 10 ms lag it by 2.5, 0 and 7.5 ms (their own clock 5 s ahead: not what counts); the raw reading
    the gravity update takes for down at a cold start (``gravity.measured_body``, the measured specific force's
    direction negated) is then the mean of ``v_i - (w lag_i) x v_i`` with those lags, computed here by hand (numpy's
    cross product), ``w`` the gyro's constant rate over the tick."""
    rate = np.array([3.0, -1.0, 10.0])
    vectors = [(2.0, -0.5, -9.5), (-1.5, 1.0, -9.6), (0.3, -1.8, -9.4)]
    placed_ns = [7_500_000, 10_000_000, 2_500_000]
    lags = [0.0025, 0.0, 0.0075]
    source = SourceId("sim", 1, 1, 0)
    samples = [ImuSample(t + 5_000_000_000, tuple(rate), v, None, source) for v, t in zip(vectors, placed_ns)]
    model = FusionModel(FuserConfig())
    model.step(TickInput(10_000_000, 10_000_000, samples, placed_ns))
    expected = np.mean([np.asarray(v) - np.cross(rate * lag, v) for v, lag in zip(vectors, lags)], axis=0)
    np.testing.assert_allclose(model.state.gravity.measured_body, -expected / np.linalg.norm(expected), atol=1e-12)
    # the premise: each sample's own lag shows (the lags the other way round, or none, are measurably elsewhere)
    swapped = np.mean([np.asarray(v) - np.cross(rate * lag, v) for v, lag in zip(vectors, lags[::-1])], axis=0)
    assert _angle_deg(expected, swapped) > 0.1 and _angle_deg(expected, np.mean(vectors, axis=0)) > 0.5


def test_without_a_rate_the_mean_is_the_plain_mean():
    vectors = [(0.1, -9.7, 0.3), (0.2, -9.9, 0.1), (0.0, -9.8, 0.2)]
    np.testing.assert_allclose(mean_in_state_body(np.array(vectors), _lags_s([1, 2, 3], 4), False, NO_RATE), [0.1, -9.8, 0.2], rtol=1e-15)


def test_each_reading_is_turned_by_the_rate_over_its_own_lag():
    """The mean of ``v_i - (w lag_i) x v_i``, each reading turned on its own (numpy's cross product)."""
    rng = np.random.default_rng(2)
    vectors = [tuple(v) for v in rng.normal(0.0, 5.0, (4, 3))]
    lags = _lags_s([2_500_000, 5_000_000, 7_500_000, 10_000_000], 10_000_000)
    rate = np.array([3.0, -1.0, 10.0])
    expected = np.mean([np.asarray(v) - np.cross(rate * lag, v) for v, lag in zip(vectors, lags)], axis=0)
    np.testing.assert_allclose(mean_in_state_body(np.array(vectors), lags, True, tuple(rate)), expected, rtol=1e-13)


def test_a_world_fixed_vector_seen_by_a_turning_body_is_its_reading_at_the_state_time():
    """A body turning at 600 deg/s reads a world-fixed field at four instants of a 10-ms tick; turned to the tick's
    end and averaged it is the field in the body frame of that instant, to the small-angle rotation's second order
    (the plain mean is 1.5 degrees off)."""
    rate = np.radians([0.0, 0.0, 600.0])
    field_world = np.array([0.2, 0.05, 0.4])
    times_ns = [2_500_000, 5_000_000, 7_500_000, 10_000_000]
    body = lambda t_ns: quat.rotate(quat.conjugate(quat.from_rotvec(rate * t_ns * 1e-9)), field_world)  # noqa: E731
    readings = np.array([body(t) for t in times_ns])
    at_state = body(10_000_000)
    turned = mean_in_state_body(readings, _lags_s(times_ns, 10_000_000), True, tuple(rate))
    plain = mean_in_state_body(readings, _lags_s(times_ns, 10_000_000), False, NO_RATE)
    angle = lambda a, b: np.degrees(np.arccos(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b)))  # noqa: E731
    assert angle(plain, at_state) > 1.0
    assert angle(turned, at_state) < 0.04  # the second order left: mean(theta^2) / 2 of the horizontal part, 0.03 deg
