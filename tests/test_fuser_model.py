"""The fusion model on controlled inputs with a known answer."""

import math

import numpy as np
import pytest

from core import quaternion as quat
from drivers.samples import AttitudeSample, ImuSample, MagSample, SourceId
from fuser.config import AttitudeSettings, BiasSettings, ExtrapolationSettings, FuserConfig, MagSettings
from fuser.model import FusionModel
from fuser.model.heading import heading_sigma_rad
from fuser.model.tick import TickContext
from fusion_inputs import FIELD, SRC, TICK, imu_at, tick
from model_records import params


INSTANTANEOUS_IMU = ExtrapolationSettings(imu_delay_ms=0.0)
"""These hand-made IMUs sample the rate at their stamps: no delay for the published state to make up."""


def run_static(model, q, ticks, **kw):
    est = None
    for k in range(ticks):
        est = model.step(tick([imu_at(q, (k + 1) * TICK, **kw)], (k + 1) * TICK))
    return est


@pytest.mark.parametrize("q", [quat.IDENTITY, quat.from_rotvec([0.3, -0.5, 2.0]), quat.from_rotvec([2.5, 0.4, -1.0])])
def test_converges_from_uniform_to_a_static_attitude(q):
    model = FusionModel(FuserConfig())
    first = model.step(tick([], TICK))
    assert first.uncertainty_deg > 50  # uniform start: no prior knowledge
    est = run_static(model, q, 300)
    assert math.degrees(quat.angular_distance(est.q_wxyz, q)) < 0.5
    # what is left is the published model error's floors (fuser/model_error.py) and little else
    cfg = model.config
    floors = math.hypot(cfg.model_error.heading_deg, math.sqrt(2) * cfg.model_error.tilt_deg)
    assert est.uncertainty_deg < floors + 1.0


def test_without_magnetometer_heading_stays_unknown():
    model = FusionModel(FuserConfig(mag=MagSettings(enabled=False)))
    est = run_static(model, quat.from_rotvec([0.2, 0.1, 1.0]), 200)
    Z = est.published.Z
    assert Z[2] > -1e-6 and Z[0] < -100  # two tilt axes known, rotation about down free


def test_gyro_integration_follows_a_constant_rotation():
    """No observations (accel gated, no mag): the estimate rotates by the integrated rate."""
    model = FusionModel(FuserConfig(bias=BiasSettings(feedback_enabled=False), extrapolation=INSTANTANEOUS_IMU))
    q0 = quat.from_rotvec([0.1, 0.2, 0.3])
    run_static(model, q0, 200)  # heading from the magnetometer, then none while turning
    rate = np.array([0.3, -0.2, 0.5])
    q = q0
    for k in range(200, 300):  # 1 s at 400 Hz gyro in 100 Hz ticks, free fall so the accelerometer is gated
        samples = [ImuSample(k * TICK + j * 2_500_000, tuple(rate), (0.0, 0.0, 0.0), None, SRC) for j in range(1, 5)]
        est = model.step(tick(samples, (k + 1) * TICK))
    q = quat.multiply(q0, quat.from_rotvec(rate * (1.0 + est.ahead_ns * 1e-9)))  # the estimate is for its stamp
    assert math.degrees(quat.angular_distance(est.q_wxyz, q)) < 0.2
    # the low-passed specific force decays below the gate after 0.22 tau of free fall (0.7 s at the
    # 3-s time constant once the bias is learnt at rest): gated for the rest of the second
    assert model.counters["accel_gated"] >= 25


def test_impacts_are_absorbed_and_sustained_acceleration_is_gated():
    model = FusionModel(FuserConfig())
    q = quat.from_rotvec([0.1, 0.0, 0.0])
    run_static(model, q, 200)
    sideways = (6.0, 3.0, -8.0)  # 1.8 g, mostly not along gravity
    est = model.step(tick([imu_at(q, 201 * TICK, accel_extra=sideways)], 201 * TICK))  # one-tick impact
    assert math.degrees(quat.angular_distance(est.q_wxyz, q)) < 0.3
    before = model.counters["accel_gated"]
    est = run_static(model, q, 100, accel_extra=sideways)  # a second of it: the filtered norm leaves the gate
    assert model.counters["accel_gated"] > before + 10
    # the 3-s low-pass (bias learnt at rest) needs 0.7 s to leave the gate; what leaks in by then
    # tilts the estimate a few degrees (the price of letting less linear acceleration through)
    assert math.degrees(quat.angular_distance(est.q_wxyz, q)) < 6.0


def test_magnet_near_the_sensor_does_not_drag_the_heading():
    model = FusionModel(FuserConfig())
    q = quat.from_rotvec([0.0, 0.0, 0.8])
    run_static(model, q, 300)
    est = run_static(model, q, 300, mag_extra=(0.3, -0.3, 0.0))  # a field stronger than the earth's
    assert math.degrees(quat.angular_distance(est.q_wxyz, q)) < 1.0
    assert model.counters["mag_gated_norm"] + model.counters["mag_gated_dip"] >= 290


def test_learns_a_constant_gyro_bias():
    bias = np.array([0.01, -0.02, 0.015])
    model = FusionModel(FuserConfig(bias=BiasSettings(time_constant_s=5.0)))
    q = quat.from_rotvec([0.1, -0.1, 0.4])
    run_static(model, q, 100)
    run_static(model, q, 3000, gyro=tuple(bias))  # 30 s at rest
    np.testing.assert_allclose(model.state.bias.estimate_rad_s, bias, atol=0.002)


def test_autopilot_attitude_is_an_identity_measurement_when_configured():
    q_ap = quat.from_rotvec([0.3, 0.2, -1.0])
    # no IMU at all: "auto" fuses the attitude too (the IMU is not there to carry the estimate)
    for attitude, expect_used in ((AttitudeSettings(mode="off"), False), (AttitudeSettings(mode="always", sigma_deg=2.0), True),
                                  (AttitudeSettings(mode="auto"), True)):
        model = FusionModel(FuserConfig(attitude=attitude))
        for k in range(50):
            est = model.step(tick([AttitudeSample((k + 1) * TICK, tuple(q_ap), SRC)], (k + 1) * TICK))
        assert (math.degrees(quat.angular_distance(est.q_wxyz, q_ap)) < 1.0) == expect_used


def test_separate_magnetometer_samples_are_used():
    model = FusionModel(FuserConfig())
    q = quat.from_rotvec([0.0, 0.1, -2.0])
    for k in range(300):
        t = (k + 1) * TICK
        imu = imu_at(q, t, mag=False)
        mag = MagSample(t, tuple(quat.rotate(quat.conjugate(q), FIELD)), SourceId("dronecan", 10, 0, 0))
        est = model.step(tick([imu, mag], t))
    assert math.degrees(quat.angular_distance(est.q_wxyz, q)) < 0.5


def test_two_imus_are_fused():
    """Two IMUs with opposite gyro biases: the average rate cancels them."""
    model = FusionModel(FuserConfig(bias=BiasSettings(feedback_enabled=False), extrapolation=INSTANTANEOUS_IMU))
    a, b = SourceId("mavlink", 1, 1, 0), SourceId("mavlink", 1, 1, 1)
    q0 = quat.IDENTITY
    run_static(model, q0, 100)
    for k in range(100, 200):
        t0 = k * TICK
        s = []
        for j in range(1, 5):
            s.append(ImuSample(t0 + j * 2_500_000, (0.0, 0.0, 0.5 + 0.05), (0.0, 0.0, 0.0), None, a))
            s.append(ImuSample(t0 + j * 2_500_000, (0.0, 0.0, 0.5 - 0.05), (0.0, 0.0, 0.0), None, b))
        est = model.step(tick(s, t0 + TICK))
    assert math.degrees(quat.angular_distance(est.q_wxyz, quat.from_rotvec([0.0, 0.0, 0.5 * (1.0 + est.ahead_ns * 1e-9)]))) < 0.2


def test_gap_without_gyro_grows_uncertainty():
    model = FusionModel(FuserConfig())
    run_static(model, quat.IDENTITY, 200)
    gaps_before = model.counters["no_gyro"]
    before = model.step(tick([], 201 * TICK)).uncertainty_deg
    for k in range(202, 300):
        after = model.step(tick([], k * TICK)).uncertainty_deg
    assert after > before + 5 and model.counters["no_gyro"] == gaps_before + 99


def test_heading_sigma_counts_correlated_magnetometer_errors_once_per_correlation_time():
    """Converged: error sqrt(T_c / T) for readings every T, lowered while the bias is poorly known; mag.sigma_rad before."""
    cfg = FuserConfig()
    p = params(cfg)
    dt = 0.01
    q_gyro = cfg.gyro.noise_rad_s_rt_hz**2 * dt  # the white-noise part of the tick's process variance
    ctx = TickContext(dt, q_gyro, 1.0, 1.0)
    assert heading_sigma_rad(p.mag, p.bias, p.updates, False, ctx, 1e-10, dt) == cfg.mag.sigma_rad  # not converged: a fast start
    # a fast start's readings count per 10 ms: at 200 Hz each is sqrt(2) as noisy, at 50 Hz as given
    assert heading_sigma_rad(p.mag, p.bias, p.updates, False, ctx, 1e-10, 0.005) == pytest.approx(cfg.mag.sigma_rad * math.sqrt(2.0), rel=1e-15)
    assert heading_sigma_rad(p.mag, p.bias, p.updates, False, ctx, 1e-10, 0.02) == cfg.mag.sigma_rad
    for every_s in (dt, 0.1):  # a reading every tick, and a 10 Hz magnetometer
        correlated = math.radians(cfg.mag.error_deg) * math.sqrt(cfg.mag.correlation_s / every_s)
        assert heading_sigma_rad(p.mag, p.bias, p.updates, True, ctx, 1e-5**2, every_s) == pytest.approx(correlated)  # bias learnt at rest
    correlated = math.radians(cfg.mag.error_deg) * math.sqrt(cfg.mag.correlation_s / dt)
    sigma_b = cfg.bias.initial_sigma_rad_s  # unknown: correct within heading_bias_error / sigma_b
    tau = math.radians(cfg.mag.heading_bias_error_deg) / sigma_b
    q = sigma_b**2 * cfg.bias.time_constant_s * dt  # the bias term of the process variance
    held = heading_sigma_rad(p.mag, p.bias, p.updates, True, TickContext(dt, q, 1.0, 1.0), sigma_b**2, dt)
    assert held == pytest.approx(math.sqrt(q) * tau / dt) and held < correlated
    # readings every 10 ticks: the process variance over the interval is 10 q, the sigma sqrt(10 q) tau / (10 dt)
    assert heading_sigma_rad(p.mag, p.bias, p.updates, True, TickContext(dt, q, 1.0, 1.0), sigma_b**2, 10 * dt) == pytest.approx(math.sqrt(10 * q) * tau / (10 * dt))
