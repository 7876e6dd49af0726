"""The gyro bias learnt in motion (VQF's motion bias estimation): from the plain tilt correction and the heading
correction, at any rate, each through its own measurement model; by integral feedback while GNSS aids the tilt."""

import math
from typing import Callable

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core import quaternion as quat
from core.bingham import Bingham
from core.observations import vector_exponent
from drivers.samples import GnssSample
from fuser.config import BiasSettings, FuserConfig
from fuser.model import FusionModel, bias
from fuser.model.bias import (SETTLE_TIME_CONSTANTS, HeadingEvidence, TiltEvidence, learn_in_motion, low_pass, reading_gain,
                              variance_rad2_s2)
from fuser.model.rest import measure_bias
from fuser.model.state import BIAS as BIAS_FIELDS
from fusion_inputs import SRC
from model_records import params, part, set_fields
from motion_inputs import fly, turning

BIAS = np.array([0.012, -0.009, 0.015])
TAU, INTERVAL = 3.0, 0.01
P = params()
"""The default parameters record (its ``bias`` and ``rest`` groups)."""


def tumbling(t: float) -> np.ndarray:
    """Never at rest and mostly faster than 0.2 rad/s (the slow-motion limit of the integral feedback this replaced:
    learnt in motion now at any rate)."""
    return np.array([1.2 * math.sin(0.9 * t), 0.9 * math.cos(0.6 * t + 0.3), 0.7 * math.sin(0.4 * t + 1.0) + 0.4])


@pytest.fixture(scope="module")
def tumble():
    return turning(tumbling, 25.0)


def _fixes(seconds: float, hz: float = 10.0, vel_ned_m_s=(6.0, 2.0, 0.0)):
    """A receiver's fixes of a vehicle cruising at a constant velocity (what a sensor at the centre of rotation
    that only turns sees: no acceleration) with 0.05 m/s of white noise (seeded) and its 0.1 m/s speed accuracy, no
    position (the configured field stays)."""
    rng = np.random.default_rng(7)
    return [GnssSample(round(k / hz * 1e9), 3, tuple(np.asarray(vel_ned_m_s) + 0.05 * rng.standard_normal(3)), True, 0.1,
                       None, None, None, False, SRC) for k in range(1, int(seconds * hz) + 1)]


def _assert_learnt(bias: np.record):
    error = bias.estimate_rad_s - BIAS
    sigma = np.sqrt(np.diag(bias.covariance_rad2_s2))
    assert np.all(np.abs(error) < 0.4 * np.abs(BIAS)), error  # most of each axis learnt
    assert np.all(np.abs(error) < 3.0 * sigma), (error, sigma)  # and the uncertainty says how well
    assert np.all(sigma < 0.5 * BiasSettings().initial_sigma_rad_s)


def test_a_bias_is_learnt_while_tumbling_without_rest(tumble):
    rates = np.linalg.norm(tumble.rate_rad_s, axis=1)
    assert np.mean(rates > 0.2) > 0.9 and rates.min() > 0.15  # the test's premise: motion all the time
    model = FusionModel(FuserConfig())
    fly(model, tumble, BIAS)
    assert model.counters["rest_ticks"] == 0
    _assert_learnt(model.state.bias)


def test_while_gnss_aids_the_bias_is_learnt_by_integral_feedback_in_slow_motion(tumble):
    """With GNSS the tilt is the aided correction's, whose response the Kalman filter does not model
    (fuser.model.bias): the integral feedback learns instead, only in ticks slower than ``learn_max_rate_rad_s``.
    Tumbling faster than that nearly all the time, the bias stays almost unknown, and says so; slowed to a tenth,
    the same tumble teaches it."""
    fast = FusionModel(FuserConfig())
    results = fly(fast, tumble, BIAS, extra=_fixes(25.0))
    aided = [d for _, r in results for d in r.diagnostics if d.update == "gravity" and dict(d.values).get("aiding") == "gnss"]
    assert len(aided) > 200  # the premise: the tilt is the aided correction's (10 Hz)
    assert fast.counters["rest_ticks"] == 0
    assert math.sqrt(variance_rad2_s2(fast.state.bias)) > 0.5 * BiasSettings().initial_sigma_rad_s
    slow = FusionModel(FuserConfig())
    fly(slow, turning(lambda t: 0.1 * tumbling(t), 25.0), BIAS, extra=_fixes(25.0))
    assert slow.counters["rest_ticks"] == 0
    estimate = slow.state.bias.estimate_rad_s
    assert np.all(np.abs(estimate[:2] - BIAS[:2]) < 0.4 * np.abs(BIAS[:2])), estimate  # the axes the tilt sees, mostly
    assert 0.2 * BIAS[2] < estimate[2] < BIAS[2]  # the vertical through the heading correction only, more slowly
    assert math.sqrt(variance_rad2_s2(slow.state.bias)) < 0.5 * BiasSettings().initial_sigma_rad_s


def test_without_learning_in_motion_the_bias_stays_unknown(tumble):
    model = FusionModel(FuserConfig(bias=BiasSettings(feedback_enabled=False)))
    fly(model, tumble, BIAS)
    np.testing.assert_array_equal(model.state.bias.estimate_rad_s, 0.0)


@pytest.mark.parametrize("prior_deg, sigma_deg", [(0.5, 2.0), (1.0, 1.0), (3.0, 0.5)])
def test_the_gain_is_the_bingham_products(prior_deg, sigma_deg):
    """A vector reading of sigma ``s`` against a prior of angle variance ``P`` on the axes it informs moves the
    Bingham product's mode by ``P / (P + s^2)`` of the innovation: the stage-2 gain of either tilt correction."""
    p, s, angle = math.radians(prior_deg) ** 2, math.radians(sigma_deg), math.radians(0.2)
    prior = Bingham.from_mode(quat.IDENTITY, [-2.0 / p, -2.0 / p, -2.0 / math.radians(10.0) ** 2])  # angle variance 2 / |z|
    down = np.array([0.0, 0.0, 1.0])
    measured_q = quat.from_rotvec([angle, 0.0, 0.0])
    body = quat.rotate(quat.conjugate(measured_q), down)  # what a sensor tilted by ``angle`` about x reads
    moved = quat.to_rotvec(prior.times_exponent(vector_exponent(body, down, s)).mode)
    assert moved[0] / angle == pytest.approx(reading_gain(p, s), rel=0.02)
    assert abs(moved[1]) < 1e-9 and abs(moved[2]) < 1e-6


def _bias_state(sigma: float, estimate=(0.0, 0.0, 0.0)) -> np.record:
    return part("bias", estimate_rad_s=np.asarray(estimate, dtype=float), covariance_rad2_s2=sigma**2 * np.eye(3))


def _q(q: np.ndarray) -> tuple:
    """A quaternion as the compiled functions take it: a tuple of four floats."""
    return tuple(float(x) for x in q)


def _low_passed(state: np.record, predicted_q: np.ndarray, tilt_tau_s: float, interval_s: float, aided: bool, tilt_gain: float | None,
                heading_gain: float | None) -> np.record:
    """:func:`low_pass` of ``state`` (changed in place, and returned); a gain of None holds its stage."""
    low_pass(state, _q(predicted_q), tilt_tau_s, interval_s, aided, tilt_gain is not None, 0.0 if tilt_gain is None else tilt_gain,
             heading_gain is not None, 0.0 if heading_gain is None else heading_gain)
    return state


def _learnt(params_bias: np.record, state: np.record, predicted_q: np.ndarray, posterior_q: np.ndarray, tilt_tau_s: float,
            tilt: TiltEvidence | None, heading: HeadingEvidence | None, rate_rad_s: float, scale_error: float) -> np.record:
    """:func:`learn_in_motion` on a copy of ``state`` (which stays as it was), the copy returned; None: no such evidence."""
    after = state.copy()
    learn_in_motion(params_bias, after, _q(predicted_q), _q(posterior_q), tilt_tau_s, tilt is not None,
                    TiltEvidence(0.0, 0.0, 0.0) if tilt is None else tilt, heading is not None,
                    HeadingEvidence(0.0, 0.0, 0.0, 0.0) if heading is None else heading, rate_rad_s, scale_error)
    return after


def _settled(state: np.record) -> np.record:
    """``state`` as if its stages had long followed the tilt correction (it may teach the bias)."""
    return set_fields(state, tilt_settled_s=math.inf)


def _level(state: np.record, gain: float | None = INTERVAL / TAU) -> np.record:
    return _low_passed(state, quat.IDENTITY, TAU, INTERVAL, False, gain, None)


@pytest.mark.parametrize("gain", [INTERVAL / TAU, 0.25 * INTERVAL / TAU])
def test_one_update_is_the_scalar_kalman_update_on_the_horizontal_axes(gain):
    """Level and still in the stages (R = I): a correction ``c`` over ``T`` measures ``b_hat - c / T`` on north
    and east with noise ``(n / m)^2 m / T``, ``m = max(tau_2, tau)``, ``tau_2 = T / k`` the correction's own time constant
    (``tau`` for the plain update; four times longer here for a correction with a quarter of its gain, as the
    aided one's is with noisy GNSS); hand-worked scalar Kalman updates, down untouched."""
    noise_rad = math.radians(0.5)
    sigma = 0.01
    state = _settled(_level(_bias_state(sigma, (0.001, 0.002, 0.003)), gain))
    drift = np.array([0.004, -0.002, 0.0])  # the true bias is estimate + this: the state turned by -drift T
    posterior = quat.from_rotvec(-drift * INTERVAL)  # the correction undoes it (world frame)
    evidence = TiltEvidence(gain, INTERVAL, noise_rad**2)
    after = _learnt(P.bias, state, quat.IDENTITY, posterior, TAU, evidence, None, 0.0, 0.0)
    m = max(INTERVAL / gain, TAU)
    w = (noise_rad / m) ** 2 * m / INTERVAL
    k = sigma**2 / (sigma**2 + w)
    np.testing.assert_allclose(after.estimate_rad_s, [0.001 + k * 0.004, 0.002 - k * 0.002, 0.003], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.diag(after.covariance_rad2_s2), [(1 - k) * sigma**2, (1 - k) * sigma**2, sigma**2], rtol=1e-9)


def test_the_heading_row_is_the_scalar_kalman_update_on_down():
    """The magnetometer's correction, one stage of its own gain against a world-fixed reference: the down row,
    noise ``(e / m)^2 m / T``, ``m = max(tau_h, correlation)``; here the correlation (10 s) is the longer."""
    sigma, gain, error, correlation = 0.01, 0.002, math.radians(2.0), 10.0
    state = _low_passed(_bias_state(sigma), quat.IDENTITY, TAU, INTERVAL, False, None, gain)
    posterior = quat.from_rotvec([0.0, 0.0, -0.003 * INTERVAL])
    after = _learnt(P.bias, state, quat.IDENTITY, posterior, TAU, None, HeadingEvidence(gain, INTERVAL, error, correlation), 0.0, 0.0)
    assert INTERVAL / gain < correlation
    w = (error / correlation) ** 2 * correlation / INTERVAL
    k = sigma**2 / (sigma**2 + w)
    np.testing.assert_allclose(after.estimate_rad_s, [0.0, 0.0, k * 0.003], rtol=1e-9, atol=1e-15)


def test_the_tilt_teaches_nothing_until_its_stages_have_settled():
    """A first reading, or the switch between the plain and the GNSS-aided tilt correction, starts the stages
    again: for two time constants the correction is the start's transient, not the bias's response."""
    posterior = quat.from_rotvec([-0.004 * INTERVAL, 0.0, 0.0])
    evidence = TiltEvidence(INTERVAL / TAU, INTERVAL, math.radians(0.5) ** 2)
    state = _low_passed(_settled(_level(_bias_state(0.01))), quat.IDENTITY, TAU, INTERVAL, True, INTERVAL / TAU, None)  # the aiding starts
    assert state.tilt_aided and state.tilt_settled_s == 0.0
    steps = 0
    while _learnt(P.bias, state, quat.IDENTITY, posterior, TAU, evidence, None, 0.0, 0.0).estimate_rad_s[0] == 0.0:
        _low_passed(state, quat.IDENTITY, TAU, INTERVAL, True, INTERVAL / TAU, None)
        steps += 1
    assert steps * INTERVAL == pytest.approx(SETTLE_TIME_CONSTANTS * TAU, abs=1.5 * INTERVAL)
    assert _level(state).tilt_settled_s == 0.0  # the aiding ends


def test_the_rotation_rate_makes_the_correction_a_poorer_measurement():
    """A gyro scale error ``s`` turns a rate ``w`` into a correction as a bias ``s w`` would: the gain falls."""
    state = _settled(_level(_bias_state(0.01)))
    posterior = quat.from_rotvec([-0.004 * INTERVAL, 0.0, 0.0])
    evidence = TiltEvidence(INTERVAL / TAU, INTERVAL, math.radians(0.5) ** 2)
    slow = _learnt(P.bias, state, quat.IDENTITY, posterior, TAU, evidence, None, 0.0, 0.01)
    fast = _learnt(P.bias, state, quat.IDENTITY, posterior, TAU, evidence, None, 5.0, 0.01)
    assert 0.0 < fast.estimate_rad_s[0] < 0.2 * slow.estimate_rad_s[0]


def test_learning_in_motion_never_claims_more_than_the_floor_nor_loses_a_rest_measurement():
    params_bias = params(FuserConfig(bias=BiasSettings(floor_sigma_rad_s=0.003))).bias
    posterior = quat.from_rotvec([-1e-5, 0.0, 0.0])
    evidence = TiltEvidence(INTERVAL / TAU, INTERVAL, math.radians(0.5) ** 2)
    for sigma, least in ((0.003, 0.003), (0.0005, 0.0005)):  # at the floor; measured better at rest
        state = _settled(_level(_bias_state(sigma)))
        for _ in range(200):
            state = _learnt(params_bias, state, quat.IDENTITY, posterior, TAU, evidence, None, 0.0, 0.0)
        assert math.sqrt(variance_rad2_s2(state)) == pytest.approx(least, rel=1e-9)


def test_a_body_that_keeps_turning_is_measured_through_the_low_passed_rotation():
    """Turning at 1 rad/s about down for one tilt time constant, a bias on body x shows in the north and east
    corrections as the low-passed rotation predicts: the measurement row is LP2(R), not the current R; a gated
    reading (no gain) holds the second stage."""
    tau = 1.0
    state = _bias_state(0.01)
    for k in range(100):
        _low_passed(state, quat.from_rotvec([0.0, 0.0, k * INTERVAL]), tau, INTERVAL, False, INTERVAL / tau, None)
    # two first-order low-passes in series of R(t) (hand-worked recursion, independent of low_pass)
    r1 = r2 = quat.to_matrix(quat.IDENTITY)
    for k in range(1, 100):
        r = quat.to_matrix(quat.from_rotvec([0.0, 0.0, k * INTERVAL]))
        r1 = r1 + INTERVAL / tau * (r - r1)
        r2 = r2 + INTERVAL / tau * (r1 - r2)
    np.testing.assert_allclose(state.rotation_lp[1], r2, atol=1e-12)
    assert abs(quat.to_matrix(quat.from_rotvec([0.0, 0.0, 0.99]))[1, 0] - state.rotation_lp[1][1, 0]) > 0.5  # far from the current R
    held = _low_passed(state.copy(), quat.from_rotvec([0.0, 0.0, 1.0]), tau, INTERVAL, False, None, None)
    np.testing.assert_array_equal(held.rotation_lp[1], state.rotation_lp[1])


def test_the_tilt_and_heading_rows_together_are_the_joint_kalman_update():
    """Tilted stages (the rows of LP2(R) and LP1(R) not axis-aligned) and a correlated prior: the three rows the tick
    teaches are the joint Kalman update ``K = P H^T (H P H^T + R)^-1`` with a diagonal ``R`` (written out here with
    numpy's inverse, as the model once computed it), whatever order the model takes them in."""
    rng = np.random.default_rng(5)
    turns = [quat.from_rotvec(rng.normal(0.0, 0.6, 3)) for _ in range(3)]
    rotation_lp = np.stack([quat.to_matrix(q) for q in turns])
    estimate = np.array([0.004, -0.003, 0.002])
    rotated_lp = np.stack([r @ (estimate + rng.normal(0.0, 0.002, 3)) for r in rotation_lp])
    a = rng.normal(0.0, 0.006, (3, 3))
    covariance = a @ a.T + 1e-5 * np.eye(3)
    state = part("bias", estimate_rad_s=estimate, covariance_rad2_s2=covariance, rotation_lp=rotation_lp, rotated_lp_rad_s=rotated_lp,
                 tilt_aided=False, tilt_settled_s=math.inf)
    predicted, posterior = quat.IDENTITY, quat.from_rotvec([0.002 * INTERVAL, -0.001 * INTERVAL, 0.003 * INTERVAL])
    tilt = TiltEvidence(0.004, INTERVAL, 3e-7)  # row noises of 1e-5 (rad/s)^2, as large as what the rows know
    heading = HeadingEvidence(0.002, INTERVAL, 1e-3, 10.0)
    after = _learnt(params(FuserConfig(bias=BiasSettings(floor_sigma_rad_s=0.0))).bias, state, predicted, posterior, TAU, tilt, heading,
                    0.0, 0.0)
    held_t, held_h = max(INTERVAL / tilt.gain, TAU), max(INTERVAL / heading.gain, heading.correlation_s)
    noise = np.diag([tilt.noise_rad2 / held_t * 1 / INTERVAL] * 2 + [heading.error_rad**2 / held_h / INTERVAL])
    h = np.stack([rotation_lp[1, 0], rotation_lp[1, 1], rotation_lp[2, 2]])
    correction = quat.to_rotvec(posterior) / INTERVAL
    y = np.array([rotated_lp[1, 0], rotated_lp[1, 1], rotated_lp[2, 2]]) - correction
    innovation_covariance = h @ covariance @ h.T + noise
    sigmas = np.sqrt(np.diag(innovation_covariance))
    correlation = innovation_covariance / np.outer(sigmas, sigmas)
    assert np.all(np.abs(correlation[np.triu_indices(3, 1)]) > 0.05)  # the rows are coupled: each one teaches the others'
    gain = covariance @ h.T @ np.linalg.inv(innovation_covariance)
    np.testing.assert_allclose(after.estimate_rad_s, estimate + gain @ (y - h @ estimate), rtol=1e-12, atol=1e-16)
    np.testing.assert_allclose(after.covariance_rad2_s2, (np.eye(3) - gain @ h) @ covariance, rtol=1e-10, atol=1e-18)
    np.testing.assert_array_equal(after.covariance_rad2_s2, after.covariance_rad2_s2.T)


def test_the_bias_steps_change_only_the_fields_they_update():
    """Each step writes the state's ``bias`` part in place (it once built a new state directly, not with
    ``dataclasses.replace``, and had to carry every field it did not update): it must change exactly the fields it
    updates and leave every other one as it was (a field a step overwrites or clears by mistake, or one added later
    and written, fails here)."""
    rotation_lp, rotated_lp = np.stack([np.eye(3)] * 3), np.full((3, 3), 0.001)
    state = part("bias", estimate_rad_s=np.array([0.001, 0.002, 0.003]), covariance_rad2_s2=1e-4 * np.eye(3), rotation_lp=rotation_lp,
                 rotated_lp_rad_s=rotated_lp, tilt_aided=True, tilt_settled_s=7.0)
    names = BIAS_FIELDS.names
    assert set(names) == {"estimate_rad_s", "covariance_rad2_s2", "has_lp", "rotation_lp", "rotated_lp_rad_s", "tilt_aided", "tilt_settled_s"}
    for defaults in (part("bias"), np.zeros((), BIAS_FIELDS)):  # the premise: no field holds the start's value, nor zero
        for name in names:
            assert not np.array_equal(state[name], defaults[name]), name
    evidence = TiltEvidence(INTERVAL / TAU, INTERVAL, math.radians(0.5) ** 2)
    turned = quat.from_rotvec([1e-4, 0.0, 0.0])
    yawed = quat.from_rotvec([0.0, 0.0, 1e-4])
    rest = part("rest", gyro_lp_rad_s=np.array([0.01, 0.0, 0.0]))

    def after(step: Callable[[np.record], None]) -> np.record:
        copy = state.copy()
        step(copy)
        return copy

    updated = {
        "propagate": (after(lambda b: bias.propagate(P.bias, b, 0.01)), {"covariance_rad2_s2"}),
        "learn_in_motion": (_learnt(P.bias, state, quat.IDENTITY, turned, TAU, evidence, None, 0.0, 0.0),
                            {"estimate_rad_s", "covariance_rad2_s2"}),
        "integral_feedback": (after(lambda b: bias.integral_feedback(P.bias, b, _q(quat.IDENTITY), _q(turned), 0.01)),
                              {"estimate_rad_s", "covariance_rad2_s2"}),
        "heading_feedback": (after(lambda b: bias.heading_feedback(P.bias, b, _q(quat.IDENTITY), _q(yawed), 40.0)), {"estimate_rad_s"}),
        "measure_bias": (after(lambda b: measure_bias(P.rest, rest, b, 0.01)), {"estimate_rad_s", "covariance_rad2_s2"}),
        "low_pass": (_low_passed(state.copy(), turned, TAU, INTERVAL, True, 0.5, 0.5), {"rotation_lp", "rotated_lp_rad_s", "tilt_settled_s"}),
    }
    for step, (changed_state, changed) in updated.items():
        for name in names:
            same = np.array_equal(changed_state[name], state[name])
            assert same != (name in changed), (step, name)


def test_a_magnetometer_reading_alone_feeds_back_its_heading_correction_about_down():
    """:func:`bias.heading_feedback` from a level prediction corrected by the body rotation ``c`` = (roll, 0, a):
    the bias moves by ``-(c . d) d / tau``, ``d`` world down in the corrected body frame (scipy), its covariance
    unchanged; the roll part is not fed back (no aided reading measured it)."""
    tau, c = 40.0, np.array([3e-4, 0.0, 2e-4])
    start = part("bias", estimate_rad_s=np.array([0.001, 0.002, 0.003]), covariance_rad2_s2=1e-4 * np.eye(3))
    fed = start.copy()
    bias.heading_feedback(P.bias, fed, _q(quat.IDENTITY), _q(quat.from_rotvec(c)), tau)
    d = Rotation.from_rotvec(c).inv().apply([0.0, 0.0, 1.0])
    np.testing.assert_allclose(fed.estimate_rad_s, start.estimate_rad_s - np.dot(c, d) * d / tau, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(fed.covariance_rad2_s2, start.covariance_rad2_s2)
