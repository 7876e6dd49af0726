"""The gyro bias learnt in motion (VQF's motion bias estimation): from the tilt and heading corrections, at any rate."""

import dataclasses
import math

import numpy as np
import pytest

from core import quaternion as quat
from fuser.config import BiasSettings, FuserConfig
from fuser.model import FusionModel
from fuser.model.bias import learn_in_motion, low_pass
from fuser.model.state import BiasState
from motion_inputs import fly, turning

BIAS = np.array([0.012, -0.009, 0.015])


def tumbling(t: float) -> np.ndarray:
    """Never at rest and mostly faster than 0.2 rad/s (the slow-motion limit of the integral feedback this replaced)."""
    return np.array([1.2 * math.sin(0.9 * t), 0.9 * math.cos(0.6 * t + 0.3), 0.7 * math.sin(0.4 * t + 1.0) + 0.4])


@pytest.fixture(scope="module")
def tumble():
    return turning(tumbling, 25.0)


def test_a_bias_is_learnt_while_tumbling_without_rest(tumble):
    rates = np.linalg.norm(tumble.rate_rad_s, axis=1)
    assert np.mean(rates > 0.2) > 0.9 and rates.min() > 0.15  # the test's premise: motion all the time
    model = FusionModel(FuserConfig())
    fly(model, tumble, BIAS)
    bias = model.state.bias
    error = bias.estimate_rad_s - BIAS
    sigma = np.sqrt(np.diag(bias.covariance_rad2_s2))
    assert model.counters["rest_ticks"] == 0
    assert np.all(np.abs(error) < 0.4 * np.abs(BIAS)), error  # most of each axis learnt
    assert np.all(np.abs(error) < 3.0 * sigma), (error, sigma)  # and the uncertainty says how well
    assert np.all(sigma < 0.5 * BiasSettings().initial_sigma_rad_s)


def test_without_learning_in_motion_the_bias_stays_unknown(tumble):
    model = FusionModel(FuserConfig(bias=BiasSettings(feedback_enabled=False)))
    fly(model, tumble, BIAS)
    np.testing.assert_array_equal(model.state.bias.estimate_rad_s, 0.0)


def _bias_state(sigma: float, estimate=(0.0, 0.0, 0.0)) -> BiasState:
    return BiasState(np.asarray(estimate, dtype=float), sigma**2 * np.eye(3))


def _settled(state: BiasState) -> BiasState:
    """``state`` as if its low-passes had long followed the tilt correction (it may teach the bias)."""
    return dataclasses.replace(state, tilt_settled_s=math.inf)


def test_one_update_is_the_scalar_kalman_update_on_the_horizontal_axes():
    """Level and still in the low-passes (R = I): a correction ``c`` over ``T`` measures ``b_hat - c / T`` on north
    and east with noise ``(noise / tau)^2 tau / T``; hand-worked scalar Kalman updates, down untouched."""
    params = BiasSettings(motion_tilt_noise_deg=0.5)
    sigma, tau, interval = 0.01, 3.0, 0.01
    state = _settled(low_pass(_bias_state(sigma, (0.001, 0.002, 0.003)), quat.IDENTITY, tau, None, interval))
    drift = np.array([0.004, -0.002, 0.0])  # the true bias is estimate + this: the state turned by -drift T
    predicted = quat.IDENTITY
    posterior = quat.from_rotvec(-drift * interval)  # the correction undoes it (world frame)
    after = learn_in_motion(params, state, predicted, posterior, interval, tau, None, 0.0, 0.0)
    w = (math.radians(0.5) / tau) ** 2 * tau / interval
    k = sigma**2 / (sigma**2 + w)
    np.testing.assert_allclose(after.estimate_rad_s, [0.001 + k * 0.004, 0.002 - k * 0.002, 0.003], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.diag(after.covariance_rad2_s2), [(1 - k) * sigma**2, (1 - k) * sigma**2, sigma**2], rtol=1e-9)


def test_the_tilt_teaches_nothing_until_its_low_passes_have_settled():
    """A first reading, or the switch between the plain and the GNSS-aided tilt correction, starts the low-passes
    again: for two time constants the correction is the start's transient, not the bias's response."""
    tau, interval = 3.0, 0.01
    posterior = quat.from_rotvec([-0.004 * interval, 0.0, 0.0])
    state = low_pass(_settled(low_pass(_bias_state(0.01), quat.IDENTITY, tau, None, interval)), quat.IDENTITY, tau, None, interval,
                     aided=True)  # the aiding starts
    assert state.tilt_aided and state.tilt_settled_s == 0.0
    steps = 0
    while learn_in_motion(BiasSettings(), state, quat.IDENTITY, posterior, interval, tau, None, 0.0, 0.0).estimate_rad_s[0] == 0.0:
        state = low_pass(state, quat.IDENTITY, tau, None, interval, aided=True)
        steps += 1
    assert steps * interval == pytest.approx(2.0 * tau, abs=1.5 * interval)
    assert low_pass(state, quat.IDENTITY, tau, None, interval, aided=False).tilt_settled_s == 0.0  # the aiding ends


def test_the_rotation_rate_makes_the_correction_a_poorer_measurement():
    """A gyro scale error ``s`` turns a rate ``w`` into a correction as a bias ``s w`` would: the gain falls."""
    state = _settled(low_pass(_bias_state(0.01), quat.IDENTITY, 3.0, None, 0.01))
    posterior = quat.from_rotvec([-0.004 * 0.01, 0.0, 0.0])
    slow = learn_in_motion(BiasSettings(), state, quat.IDENTITY, posterior, 0.01, 3.0, None, 0.0, 0.01)
    fast = learn_in_motion(BiasSettings(), state, quat.IDENTITY, posterior, 0.01, 3.0, None, 5.0, 0.01)
    assert 0.0 < fast.estimate_rad_s[0] < 0.2 * slow.estimate_rad_s[0]


def test_learning_in_motion_never_claims_more_than_the_floor_nor_loses_a_rest_measurement():
    params = BiasSettings(floor_sigma_rad_s=0.003)
    posterior = quat.from_rotvec([-1e-5, 0.0, 0.0])
    for sigma, least in ((0.003, 0.003), (0.0005, 0.0005)):  # at the floor; measured better at rest
        state = _settled(low_pass(_bias_state(sigma), quat.IDENTITY, 3.0, None, 0.01))
        for _ in range(200):
            state = learn_in_motion(params, state, quat.IDENTITY, posterior, 0.01, 3.0, None, 0.0, 0.0)
        assert math.sqrt(state.variance_rad2_s2) == pytest.approx(least, rel=1e-9)


def test_a_body_that_keeps_turning_is_measured_through_the_low_passed_rotation():
    """Turning at 1 rad/s about down for one tilt time constant, a bias on body x shows in the north and east
    corrections as the low-passed rotation predicts: the measurement row is LP2(R), not the current R."""
    tau, interval = 1.0, 0.01
    state = _bias_state(0.01)
    for k in range(100):
        state = low_pass(state, quat.from_rotvec([0.0, 0.0, k * interval]), tau, None, interval)
    # two first-order low-passes in series of R(t) (hand-worked recursion, independent of low_pass)
    r1 = r2 = quat.to_matrix(quat.IDENTITY)
    for k in range(1, 100):
        r = quat.to_matrix(quat.from_rotvec([0.0, 0.0, k * interval]))
        r1 = r1 + interval / tau * (r - r1)
        r2 = r2 + interval / tau * (r1 - r2)
    np.testing.assert_allclose(state.rotation_lp[1], r2, atol=1e-12)
    assert abs(quat.to_matrix(quat.from_rotvec([0.0, 0.0, 0.99]))[1, 0] - state.rotation_lp[1][1, 0]) > 0.5  # far from the current R
