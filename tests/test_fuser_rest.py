"""Rest detection with direct bias estimation, the bias-adaptive tilt time constant and the published model error."""

import math

import numpy as np
import pytest

from core import quaternion as quat
from core.bingham import Bingham
from core.filters import rms_angle_deg
from drivers.samples import ImuSample
from fuser.config import BiasSettings, FuserConfig, ModelErrorSettings, RestSettings
from fuser.model import FusionModel
from fuser.model.bias import variance_rad2_s2
from fuser.model.gravity import tilt_time_constant_s
from fuser.model.rest import detect_rest, measure_bias
from fuser.model_error import with_model_error
from fusion_inputs import FIELD, GRAVITY_M_S2, SRC, TICK, tick
from model_records import params, part

NO_FEEDBACK = BiasSettings(feedback_enabled=False)


def still(model: FusionModel, q: np.ndarray, seconds: float, gyro, start_tick: int = 0, seed: int = 0) -> int:
    """Feed a sensor at rest at attitude q: 4 IMU samples per tick with gyro ``gyro`` and white noise."""
    rng = np.random.default_rng(seed)
    f = quat.rotate(quat.conjugate(q), [0.0, 0.0, -GRAVITY_M_S2])
    m = quat.rotate(quat.conjugate(q), FIELD)
    k = start_tick
    for k in range(start_tick, start_tick + round(seconds * 100)):
        samples = [
            ImuSample(k * TICK + j * 2_500_000, tuple(np.asarray(gyro) + 0.003 * rng.standard_normal(3)),
                      tuple(f + 0.03 * rng.standard_normal(3)), tuple(m), SRC)
            for j in range(1, 5)
        ]
        model.step(tick(samples, (k + 1) * TICK))
    return k + 1


def test_rest_detection_recovers_a_known_bias_without_feedback():
    """Integral feedback off: only the rest-phase estimate can find the bias, and it does within seconds."""
    bias = np.array([0.01, -0.02, 0.015])
    model = FusionModel(FuserConfig(bias=NO_FEEDBACK))
    still(model, quat.from_rotvec([0.1, -0.1, 0.4]), 4.0, bias)
    assert model.state.rest.at_rest and model.counters["rest_ticks"] > 200
    np.testing.assert_allclose(model.state.bias.estimate_rad_s, bias, atol=5e-4)
    assert math.sqrt(variance_rad2_s2(model.state.bias)) < 0.001


def test_without_rest_detection_the_bias_is_not_found():
    bias = np.array([0.01, -0.02, 0.015])
    model = FusionModel(FuserConfig(bias=NO_FEEDBACK, rest=RestSettings(enabled=False)))
    still(model, quat.IDENTITY, 4.0, bias)
    assert not model.state.rest.at_rest and np.all(model.state.bias.estimate_rad_s == 0.0)


def test_the_rest_measurement_is_the_kalman_update_of_the_bias():
    """A correlated prior and the low-passed gyro with noise ``sigma^2 filter_s / dt``: the update is
    ``K = P (P + R)^-1``, ``b + K (g - b)``, ``(I - K) P`` (written out with numpy's inverse), and the stages of the
    motion estimate pass through untouched (the update writes the state's ``bias`` part in place)."""
    settings = RestSettings()
    rng = np.random.default_rng(3)
    a = rng.normal(0.0, 0.004, (3, 3))
    prior = a @ a.T + 1e-6 * np.eye(3)
    stages = np.stack([np.eye(3)] * 3)
    estimate = np.array([0.001, -0.002, 0.0005])
    after = part("bias", estimate_rad_s=estimate, covariance_rad2_s2=prior, rotation_lp=stages, rotated_lp_rad_s=np.zeros((3, 3)),
                 tilt_aided=True, tilt_settled_s=4.0)
    gyro_lp = np.array([0.006, -0.004, 0.002])
    dt = 0.01
    measure_bias(params(FuserConfig(rest=settings)).rest, part("rest", gyro_lp_rad_s=gyro_lp, accel_lp_m_s2=np.zeros(3), still_s=1.0,
                                                               at_rest=True), after, dt)
    noise = settings.bias_sigma_rad_s**2 * settings.filter_s / dt * np.eye(3)
    gain = prior @ np.linalg.inv(prior + noise)
    assert np.min(np.abs(gain)) > 1e-3  # the premise: every axis teaches every other
    np.testing.assert_allclose(after.estimate_rad_s, estimate + gain @ (gyro_lp - estimate), rtol=1e-12)
    np.testing.assert_allclose(after.covariance_rad2_s2, (np.eye(3) - gain) @ prior, rtol=1e-10, atol=1e-20)
    np.testing.assert_array_equal(after.covariance_rad2_s2, after.covariance_rad2_s2.T)
    np.testing.assert_array_equal(after.rotation_lp, stages)
    np.testing.assert_array_equal(after.rotated_lp_rad_s, np.zeros((3, 3)))
    assert after.has_lp and after.tilt_aided and after.tilt_settled_s == 4.0


def test_the_detector_follows_its_low_passes_and_its_three_thresholds():
    """Hand-worked low-pass steps (``a = dt / filter_s``) and each of the three tests (the gyro's change, the
    low-passed rate, the specific force's change) alone keeping the detector from rest. Each call changes the
    state's ``rest`` part in place: every case starts from a part of its own."""
    settings = RestSettings()
    rest_params = params(FuserConfig(rest=settings)).rest
    dt = 0.01
    a = dt / settings.filter_s
    gyro, accel = np.array([0.001, 0.0, -0.001]), np.array([0.0, 0.0, -9.81])
    gyro_lp, accel_lp = np.array([0.0, 0.002, 0.0]), np.array([0.01, 0.0, -9.8])
    after = part("rest", gyro_lp_rad_s=gyro_lp, accel_lp_m_s2=accel_lp, still_s=settings.min_s - dt / 2, at_rest=False)
    detect_rest(rest_params, after, tuple(gyro), tuple(accel), dt)
    np.testing.assert_allclose(after.gyro_lp_rad_s, [a * 0.001, 0.002 - a * 0.002, -a * 0.001], rtol=1e-12)
    np.testing.assert_allclose(after.accel_lp_m_s2, [0.01 - a * 0.01, 0.0, -9.8 - a * 0.01], rtol=1e-12)
    assert after.at_rest and after.still_s == pytest.approx(settings.min_s + dt / 2)
    jump = 2.0 * settings.gyro_rad_s / (1.0 - a)  # leaves its low-pass by more than the threshold
    turning = np.array([0.0, 0.0, 1.5 * settings.gyro_rad_s])  # steady, so its own low-pass follows it
    for rate, force, lp in ((gyro + [jump, 0.0, 0.0], accel, None),
                            (turning, accel, turning),
                            (gyro, accel + [0.0, 2.0 * settings.accel_m_s2 / (1.0 - a), 0.0], None)):
        moved = part("rest", gyro_lp_rad_s=lp if lp is not None else gyro_lp, accel_lp_m_s2=accel_lp, still_s=5.0, at_rest=True)
        detect_rest(rest_params, moved, tuple(rate), tuple(force), dt)
        assert not moved.at_rest and moved.still_s == 0.0


@pytest.mark.parametrize("motion", ["steady turn", "oscillation"])
def test_rest_detector_does_not_fire_in_motion(motion):
    """A slow steady turn (3 deg/s, above the 2 deg/s bias clip) or a wobble is not rest: the bias stays put."""
    model = FusionModel(FuserConfig(bias=NO_FEEDBACK))
    q = quat.IDENTITY.copy()
    for k in range(600):
        t = k * 0.01
        rate = np.array([0.0, 0.0, 0.05]) if motion == "steady turn" else np.array([0.3 * math.sin(2 * math.pi * t), 0.2 * math.cos(3 * t), 0.0])
        samples = []
        for j in range(1, 5):
            q = quat.multiply(q, quat.from_rotvec(rate * 0.0025))
            f = quat.rotate(quat.conjugate(q), [0.0, 0.0, -GRAVITY_M_S2])
            samples.append(ImuSample(k * TICK + j * 2_500_000, tuple(rate), tuple(f), tuple(quat.rotate(quat.conjugate(q), FIELD)), SRC))
        model.step(tick(samples, (k + 1) * TICK))
    assert model.counters["rest_ticks"] == 0
    assert np.all(model.state.bias.estimate_rad_s == 0.0)


def test_tilt_time_constant_is_short_until_the_bias_is_learnt():
    cfg = FuserConfig()
    p = params(cfg)
    model = FusionModel(cfg)
    tau = lambda: tilt_time_constant_s(p.accel, p.bias, variance_rad2_s2(model.state.bias))  # noqa: E731
    assert tau() == pytest.approx(math.radians(0.5) / 0.015)  # tilt_bias_error / sigma_b: fast while the bias is unknown
    still(model, quat.IDENTITY, 4.0, (0.01, 0.0, -0.01))
    assert tau() == pytest.approx(cfg.accel.lowpass_s)


def test_model_error_matches_composition_with_isotropic_noise():
    """Isotropic model error: the cheap tangent-space form agrees with the moment-matched composition."""
    state = Bingham.from_mode(quat.from_rotvec([0.3, -0.2, 1.0]), [-2e5, -1e5, -2e4])
    sigma = math.radians(2.0)
    z = -2.0 / sigma**2
    composed = Bingham.from_mode(quat.IDENTITY, [z, z, z]).compose(state)
    ours = Bingham(*with_model_error(state.M, state.Z, sigma**2, sigma**2))
    assert rms_angle_deg(ours) == pytest.approx(rms_angle_deg(composed), rel=0.03)
    assert quat.angular_distance(ours.mode, state.mode) < 1e-12


def test_model_error_widens_heading_and_tilt_separately_and_keeps_unknown_axes_unknown():
    q = quat.from_rotvec([0.0, 0.0, 0.7])  # level: body z is world down
    state = Bingham.from_mode(q, [-1e6, -1e6, -1e5])  # tilt 0.08 deg, heading 0.26 deg
    wide = Bingham(*with_model_error(state.M, state.Z, 0.0, math.radians(3.0) ** 2))
    assert rms_angle_deg(wide) > 2.5
    assert wide.Z[1] < -5e5  # the two tilt axes barely move
    uniform = Bingham.uniform()
    assert np.all(with_model_error(uniform.M, uniform.Z, 1e-3, 1e-3)[1] == 0.0)


def test_published_uncertainty_includes_the_configured_model_error():
    plain = FusionModel(FuserConfig(model_error=ModelErrorSettings(heading_deg=0.0, tilt_deg=0.0)))
    wide = FusionModel(FuserConfig(model_error=ModelErrorSettings(heading_deg=3.0, tilt_deg=1.0)))
    for model in (plain, wide):
        still(model, quat.IDENTITY, 3.0, (0.0, 0.0, 0.0))
    a = plain.step(tick([], 301 * TICK))
    b = wide.step(tick([], 301 * TICK))
    # independent errors add in quadrature: heading 3 deg and tilt 1 deg on each of two axes
    assert b.uncertainty_deg**2 - a.uncertainty_deg**2 == pytest.approx(3.0**2 + 2 * 1.0**2, rel=0.15)
    assert quat.angular_distance(a.q_wxyz, b.q_wxyz) < 1e-9  # the estimate itself is unchanged
