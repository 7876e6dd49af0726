"""The published state carried ahead of its tick: what a consumer holding the latest estimate sees."""

import math

import numpy as np
import pytest

from core import quaternion as quat
from drivers.samples import ImuSample
from fuser.config import ExtrapolationSettings, FuserConfig, GyroSettings
from fuser.loop import FusionLoop
from fuser.model.extrapolation import ahead_ns, carry_ns, lead
from fusion_inputs import FIELD, GRAVITY_M_S2, SRC
from model_records import gyro_part, params
from motion_inputs import truth_at, turning


def test_how_far_ahead_from_the_settings():
    config = FuserConfig(rate_hz=200.0, latency_ms=5.0, extrapolation=ExtrapolationSettings(to="hold_midpoint", imu_delay_ms=3.5))
    assert ahead_ns(config) == 5_000_000 + 2_500_000  # the latency, then half a period: the middle of the hold
    assert carry_ns(config) == 7_500_000 + 3_500_000  # the state is carried from what the samples describe
    assert ahead_ns(config.replace(extrapolation={"to": "published"})) == 5_000_000
    assert ahead_ns(config.replace(extrapolation={"to": "tick"})) == 0


def test_the_lead_holds_the_last_rate_with_the_held_rates_error():
    """Hand-worked: a sample 2 ms before the tick, carried 10 ms: turned by (rate - bias) 10 ms, variance
    s^2 ((a + L)^3 - a^3) / 3 with a = 2 ms, L = 10 ms."""
    gyro = params(FuserConfig(gyro=GyroSettings(rate_walk_rad_s_rt_s=0.3))).gyro
    track = gyro_part(last_ns=98_000_000, last_rate_rad_s=(0.5, -0.2, 1.0), covered_ns=100_000_000, held_rad=(0.0, 0.0, 0.0))
    bias = (0.1, 0.0, 0.0)
    out = lead(gyro, track, bias, 100_000_000, 10_000_000)
    assert out.has_rotation
    np.testing.assert_allclose(out.rotation, quat.from_rotvec(np.array([0.4, -0.2, 1.0]) * 0.010), atol=1e-15)
    assert out.variance_rad2 == pytest.approx(0.09 * (0.012**3 - 0.002**3) / 3.0, rel=1e-12)


def test_a_hold_that_runs_out_within_the_lead_grows_as_a_gap():
    gyro = params(FuserConfig(gyro=GyroSettings(max_interval_s=0.6, gap_rate_rad_s=1.0, rate_walk_rad_s_rt_s=0.0))).gyro
    track = gyro_part(last_ns=0, last_rate_rad_s=(0.0, 0.0, 2.0), covered_ns=595_000_000, held_rad=(0.0, 0.0, 1.19))
    zero = (0.0, 0.0, 0.0)
    out = lead(gyro, track, zero, 595_000_000, 10_000_000)  # 5 ms more hold, then 5 ms of gap
    assert out.has_rotation
    np.testing.assert_allclose(out.rotation, quat.from_rotvec([0.0, 0.0, 2.0 * 0.005]), atol=1e-15)
    assert out.variance_rad2 == pytest.approx((1.0 * 0.005) ** 2, rel=1e-12)
    assert lead(gyro, gyro_part(), zero, 0, 10_000_000).variance_rad2 == pytest.approx(1e-4)  # no gyro at all
    not_carried = lead(gyro, track, zero, 595_000_000, 0)
    assert not not_carried.has_rotation and not_carried.rotation == (1.0, 0.0, 0.0, 0.0)  # not turned: the identity


def test_no_rotation_without_a_held_rate():
    """The cases :func:`lead` does not turn (``has_rotation`` False, the identity): no gyro yet (the gap's rate), a
    saturated last sample (the range's), a hold run out before the tick (all gap), a zero rate (only its error)."""
    gyro = params(FuserConfig(gyro=GyroSettings(max_interval_s=0.05, gap_rate_rad_s=1.0, range_rad_s=30.0, rate_walk_rad_s_rt_s=0.5))).gyro
    zero, identity = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)
    rate = dict(last_rate_rad_s=(0.0, 0.0, 2.0), held_rad=(0.0, 0.0, 0.0))
    cases = {
        "no gyro": (gyro_part(), 1e-4),
        "saturated": (gyro_part(last_ns=0, covered_ns=10_000_000, saturated=True, **rate), (30.0 * 0.01) ** 2),
        "hold ran out": (gyro_part(last_ns=-50_000_000, covered_ns=10_000_000, **rate), (1.0 * 0.01) ** 2),
        "zero rate": (gyro_part(last_ns=0, covered_ns=10_000_000, last_rate_rad_s=(0.1, 0.0, 0.0), held_rad=zero),
                      0.25 * (0.02**3 - 0.01**3) / 3.0),
    }
    for name, (track, variance) in cases.items():
        out = lead(gyro, track, (0.1, 0.0, 0.0), 10_000_000, 10_000_000)
        assert not out.has_rotation and out.rotation == identity, name
        assert out.variance_rad2 == pytest.approx(variance, rel=1e-12), name


IMU_HZ = 1e9 / 3_500_000
"""BROAD's rate, incommensurate with the loop's 200 Hz: a consumer reads an estimate at every phase of its hold."""


def _held_errors(config: FuserConfig) -> tuple[np.ndarray, np.ndarray, float]:
    """A sensor turning at a varying rate (up to 3 rad/s), its IMU received 1 ms after sampling, into the loop: the
    error of each estimate at its own stamp, of the latest estimate a consumer holds at each sample, and the RMS rate."""
    motion = turning(lambda t: np.array([0.3, -0.4, 3.0 * math.sin(1.5 * t)]), 4.0, imu_hz=IMU_HZ, q0=quat.from_rotvec([0.1, 0.0, 0.0]))
    loop = FusionLoop(config)
    estimates, held = [], []
    for t, q, w in zip(motion.t_s, motion.q_true, motion.rate_rad_s):
        t_ns = round(t * 1e9)
        estimates += loop.advance(t_ns + 1_000_000)
        if estimates and t > 2.0:
            held.append(quat.angular_distance(estimates[-1].q_wxyz, q))
        f = quat.rotate(quat.conjugate(q), [0.0, 0.0, -GRAVITY_M_S2])
        loop.push(ImuSample(t_ns, tuple(w), tuple(f), tuple(quat.rotate(quat.conjugate(q), FIELD)), SRC), t_ns + 1_000_000)
    at_time = [quat.angular_distance(e.q_wxyz, truth_at(motion, e.sensor_t_ns * 1e-9)) for e in estimates if e.sensor_t_ns * 1e-9 > 2.0]
    late = motion.t_s > 2.0
    return np.degrees(at_time), np.degrees(held), float(np.sqrt(np.mean(np.sum(motion.rate_rad_s[late] ** 2, axis=1))))


def test_a_consumer_holding_the_latest_estimate_sees_it_at_the_middle_of_its_hold():
    """Instantaneous samples (no IMU delay), a 200 Hz loop with 5 ms of latency. Not carried, a held estimate is
    6 to 11 ms old (the 1-ms link, the latency, up to a period of holding): its error is the rate times that.
    Carried to the middle of its hold, what is left is the spread of the age over the hold, a period over
    sqrt(12) in RMS: the least any estimate held for a period can have."""
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    base = FuserConfig(rate_hz=200.0, latency_ms=5.0).replace(extrapolation={"every_imu_sample": False})  # one estimate per tick
    _, late, rate = _held_errors(base.replace(extrapolation={"to": "tick", "imu_delay_ms": 0.0}))
    at_time, held, _ = _held_errors(base.replace(extrapolation={"to": "hold_midpoint", "imu_delay_ms": 0.0}))
    spread = math.degrees(rate * 0.005 / math.sqrt(12.0))
    assert rms(at_time) < 0.1 * spread  # perfect readings: the estimate itself is right
    assert rms(held) < 1.2 * spread
    assert rms(late) > math.degrees(rate * 0.006)
