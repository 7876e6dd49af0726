"""The gyro bias: a Gaussian beside the Bingham, measured at rest and learnt in motion from the tick's corrections.

**How the bias and the attitude are coupled.** The orientation stays a
Bingham; the bias is a Gaussian (estimate and 3x3 covariance, body frame)
beside it, coupled to it as VQF couples them (D. Laidig, T. Seel, "VQF",
Information Fusion 91, 2023, sec. 3.2), without a cross-covariance, in two
directions:

* bias -> attitude: the residual bias error enters the attitude's process
  noise as a correlated error (an error ``e`` held for a correlation time
  ``T`` turns the attitude by ``e T``, which white noise of variance
  ``e^2 T`` per second matches over ``T``; :func:`fuser.model.propagation.predict`);
* attitude -> bias: each correction the updates make to the predicted
  attitude is a measurement of the bias (below), through a model of how that
  correction responds to a bias, whose gain is the Bingham product's own.

The cross-covariance is left out on purpose: it would be a covariance
between the bias and a Gaussian attitude error at a fixed base point, while
the Bingham's mode moves every tick, its heading may be unknown (``z = 0``,
6-D), and a gravity reading leaves uninformed the rotation about the
*measured* down, not the predicted one; a linearised joint update would mix
the uninformed heading row into the tilt rows. The correlated process noise
is the conservative stand-in: it widens the attitude by what the bias
uncertainty can do, whatever the correlation.

**At rest** (:mod:`fuser.model.rest`) the low-passed gyro reads the bias
directly (VQF's rest bias estimation).

**In motion** (VQF sec. 3.2, motion bias estimation: a Kalman filter on the
bias whose measurement matrix is the low-passed rotation matrix and whose
measurement is the low-passed correction). A bias error ``e = b - b_hat`` (body frame)
drifts the prediction at ``d = -R e`` (world frame, ``R`` body -> world).
Both tilt corrections are built alike: the specific force low-passed in the
gyro-only strapdown frame S with time constant ``tau`` (stage 1: S drifts
with the prediction, so the low-pass lags the drift by ``tau LP1(d)``),
then a Bingham product that moves the state towards it by the reading's
gain ``k`` (stage 2). Linearised (a small-angle derivation in the world
frame, the Laplace variable ``p``): with the strapdown error ``s' = d``, the
measurement error ``mu = s - LP1_tau(s) = tau LP1_tau(d)``, the estimate
``x' = d + (mu - x) / tau_2`` for the correction's own time constant
``tau_2 = T / k`` (readings every ``T``), the correction rate is

    c / T = (mu - x) / tau_2 = -d / ((1 + tau p)(1 + tau_2 p)) = -LP2(R e),

two first-order low-passes in series, the first the correction's low-pass,
the second its gain. So ``y = LP2(R b_hat) - c / T`` measures ``LP2(R) b``:
a Kalman update with the low-passed rotation's rows as ``H`` (VQF low-passes
``R`` and the correction with one Butterworth filter; here each stage is the
one the correction actually applies). The components that have been
horizontal within the last ``tau`` are observed, whichever way the body
turns, at any rotation rate.

**Which correction produced the evidence.** The stage-2 gain is not a fixed
``T / tau``: it is the gain of the Bingham product that made the correction,
``k = P / (P + sigma^2)`` for the prior's tilt variance ``P`` per axis
(:func:`fuser.model.velocity.tilt_doubt_deg` of the prediction) and the
reading's sigma (:func:`reading_gain`); once steady, for the plain update,
that is ``T / tau`` (its sigma is chosen so, :mod:`fuser.model.gravity`), and
a gated reading corrects nothing. The noise: a correction of time constant
``tau_2`` that follows an error ``n`` correlated over ``tau_c`` turns it into
a correction-rate error of about ``n / max(tau_2, tau_c)`` (an error slower
than the correction is followed at its own rate of change; a faster one is
averaged over ``tau_2``), correlated over ``max(tau_2, tau_c)``, so counted
once per that (consecutive corrections share it). For the plain tilt
``tau_c = tau`` and ``n^2`` is ``accel.lowpass_error_deg`` squared (the linear
acceleration the low-pass leaves) plus the tilt the unaided accelerometer's
norm reveals it cannot see, or the tilt its corrections have absorbed, whichever
is larger (:func:`fuser.model.unaided.unseen_variances_rad2`: in a sustained
coordinated turn the false vertical stays put in the body and its correction
looks exactly like a bias; a turn's entry, before the norm shows it, too).

**While GNSS aids the tilt** (:mod:`fuser.model.velocity`) the Kalman
filter does not learn: the aided correction has the same two stages on paper
(both sides low-passed with ``tau``, then a product whose gain, measured on
the simulated hover, matches ``P / (P + sigma^2)`` within 1 %), but learning
from it so modelled, with the GNSS velocity noise in its noise, replayed on
the simulated multirotor flights, lost to the integral feedback it replaced
everywhere (seed 0: aggressive 1.34 -> 2.00 deg, dropout 2.32 -> 3.05;
seed 3: hover 2.09 -> 4.17, aggressive 3.37 -> 5.65), and not learning from
it at all leaves a large bias unlearnt (seed 3, 1.5 deg/s: hover 5.2 deg).
What the model misses is not found in the time (the estimate converges to
about 70 % of the bias while its uncertainty reaches the floor; suspects:
stage 1's delay by the GNSS latency, neglected here, and the aided world
vector's correction of the heading in turns, which the heading row then
undoes). So while GNSS aids, the tick's whole correction is fed back as
before (:func:`integral_feedback`, Mahony-style integral feedback with
``time_constant_s``, in ticks slower than ``learn_max_rate_rad_s``, over the
aided readings' spacing in motion), and the Kalman filter learns from the
plain and the heading corrections only. The same while the autopilot's
attitude is in use (a telemetry link's slow IMU): its corrections are not
modelled either, and not learning from them at all let the published
uncertainty of the telemetry flight (tests/test_fuser_slow_link.py) grow
to 27 deg. The stages still follow the
rotation while aided, and start again when the correction changes: nothing
is learnt from the plain correction for ``SETTLE_TIME_CONSTANTS`` tilt time
constants after the aiding ends (its low-pass starts again from its first
reading).

The heading correction (the magnetometer's yaw-only likelihood,
:mod:`fuser.model.heading`) is not low-passed: a single stage of its own
gain ``k_h``, against a world-fixed reference, measures the vertical row of
``LP1(R)``, with the magnetometer's correlated error ``mag.error_deg``,
``tau_c = mag.correlation_s``.

A gyro scale error ``s`` makes a rate ``w`` look like a bias of ``s w``: it
is added to each row's noise, so fast rotation teaches less. Motion alone
never brings the uncertainty below ``floor_sigma_rad_s`` (the corrections'
slowly varying errors are not white); a bias measured better at rest keeps
its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from fuser.config import BiasSettings, FuserConfig
from fuser.model.gravity import GravityReading
from fuser.model.heading import HeadingReading
from fuser.model.state import BiasState, UnaidedState
from fuser.model.unaided import unseen_variances_rad2
from fuser.model.tick import TickContext
from fuser.model.velocity import VelocityTrack

__all__ = ["SETTLE_TIME_CONSTANTS", "HeadingEvidence", "TiltEvidence", "integral_feedback", "learn_from_tick", "learn_in_motion",
           "low_pass", "may_learn", "propagate", "reading_gain"]

SETTLE_TIME_CONSTANTS = 2.0
"""The tilt correction teaches the bias once the low-passes have followed it for this many time constants: before,
its response is still the start's transient (a first reading, a first aided pair), not the bias's."""


@dataclass(frozen=True, slots=True)
class TiltEvidence:
    """One fused tilt reading as a measurement of the bias (module docstring)."""

    gain: float
    """The Bingham product's gain ``k`` on the tilt (:func:`reading_gain`): stage 2."""
    interval_s: float
    """Seconds since the previous reading of this correction: the correction is a rate over it."""
    noise_rad2: float
    """Variance of the error of the down it corrects towards (module docstring), correlated over ``tau``."""


@dataclass(frozen=True, slots=True)
class HeadingEvidence:
    """One fused magnetometer heading reading as a measurement of the bias (module docstring)."""

    gain: float
    interval_s: float
    error_rad: float
    """The magnetometer's correlated heading error (``mag.error_deg``)."""
    correlation_s: float


def propagate(params: BiasSettings, state: BiasState, dt_s: float) -> BiasState:
    """The bias uncertainty grows by its random walk over ``dt_s``, each axis up to its initial value."""
    walk = params.walk_rad_s_rt_s**2 * dt_s
    covariance = state.covariance_rad2_s2.tolist()  # 3x3 in plain floats: numpy's per-call cost would dominate
    for i in range(3):
        covariance[i][i] += walk
    limit = params.initial_sigma_rad_s
    scale = [min(1.0, limit / math.sqrt(covariance[i][i])) for i in range(3)]
    if scale != [1.0, 1.0, 1.0]:  # an axis past its initial value: scaled back to it, the correlations kept
        covariance = [[c * (si * sj) for c, sj in zip(row, scale)] for row, si in zip(covariance, scale)]
    return state.with_covariance(np.array(covariance))


def _mean_variance(covariance: list[list[float]]) -> float:
    """:attr:`BiasState.variance_rad2_s2` of a covariance given as plain floats (the same sum, in the same order)."""
    return (covariance[0][0] + covariance[1][1] + covariance[2][2]) / 3.0


def _clipped(vector: list[float], limit: float) -> np.ndarray:
    """``np.clip(vector, -limit, limit)`` of a 3-vector given as plain floats."""
    return np.array([min(max(x, -limit), limit) for x in vector])


def reading_gain(prior_variance_rad2: float, sigma_rad: float) -> float:
    """Gain of a Bingham product on the axes a reading of sigma ``sigma_rad`` informs, for a prior of variance
    ``prior_variance_rad2`` on them: the mode moves by ``P / (P + sigma^2)`` of the innovation. The product adds
    the exponents (QBF paper, sec. 5, eq. 3); both concentrated, each is a Gaussian in the tangent space whose
    angle variance per axis is ``2 / |z|`` (the prior's) and ``sigma^2`` (the vector likelihood's, ``z = -2 /
    sigma^2``; unscented paper, sec. IV-B), and the product of two Gaussians moves by that fraction."""
    total = prior_variance_rad2 + sigma_rad**2
    return prior_variance_rad2 / total if total > 0.0 else 0.0


def low_pass(state: BiasState, predicted_q: np.ndarray, tilt_tau_s: float, interval_s: float, aided: bool,
             tilt_gain: float | None, heading_gain: float | None) -> BiasState:
    """The rotation (body -> world) and the rotated estimate one more interval through the tilt correction's two
    stages (its low-pass, time constant ``tilt_tau_s``; its gain, ``tilt_gain``: None without a tilt reading this
    tick, the stage held) and the heading correction's one (``heading_gain``, likewise).

    ``aided``: the tilt correction is GNSS-aided's. When the correction changes (aiding starts or ends), the
    correction's own low-pass starts again from its first reading, not from the other's history: the memory here
    starts again too, and :func:`learn_in_motion` waits for it to settle."""
    if interval_s <= 0.0:  # a reading at the same time again (or a clock that went back): nothing new
        return state
    rotation = quat.to_matrix(predicted_q)
    rotated = rotation @ state.estimate_rad_s
    if state.rotation_lp is None or state.rotated_lp_rad_s is None or aided != state.tilt_aided:
        return BiasState(state.estimate_rad_s, state.covariance_rad2_s2, np.stack([rotation, rotation, rotation]),
                         np.stack([rotated, rotated, rotated]), aided, 0.0)
    # each stage's rotation and rotated estimate as one row of 12 plain floats (numpy's per-call cost would dominate)
    now = rotation.ravel().tolist() + rotated.tolist()
    r, b = state.rotation_lp.reshape(3, 9).tolist(), state.rotated_lp_rad_s.tolist()
    stage_1, stage_2, heading_stage = r[0] + b[0], r[1] + b[1], r[2] + b[2]
    a = min(1.0, interval_s / tilt_tau_s)
    stage_1 = [x + a * (t - x) for x, t in zip(stage_1, now)]
    if tilt_gain is not None:
        stage_2 = [x + tilt_gain * (t - x) for x, t in zip(stage_2, stage_1)]
    if heading_gain is not None:
        heading_stage = [x + heading_gain * (t - x) for x, t in zip(heading_stage, now)]
    stages = np.array([stage_1, stage_2, heading_stage])
    return BiasState(state.estimate_rad_s, state.covariance_rad2_s2, stages[:, :9].reshape(3, 3, 3), stages[:, 9:], state.tilt_aided,
                     state.tilt_settled_s + interval_s)


def learn_in_motion(params: BiasSettings, state: BiasState, predicted_q: np.ndarray, posterior_q: np.ndarray, tilt_tau_s: float,
                    tilt: TiltEvidence | None, heading: HeadingEvidence | None, rate_rad_s: float, scale_error: float) -> BiasState:
    """Kalman update of the bias with the tick's tilt correction (north and east rows, through ``LP2``) and heading
    correction (the down row, through its single stage); call after :func:`low_pass` with the same gains.

    Each row's noise: the error ``n`` of what the correction follows, correlated over ``tau_c`` (the tilt's
    ``tau``, the magnetometer's ``correlation_s``), through the correction's own time constant ``tau_2 = T / k``,
    ``(n / max(tau_2, tau_c))^2``, plus the scale error's ``(s w)^2``, counted once per ``max(tau_2, tau_c)`` since
    consecutive corrections share it (module docstring). The uncertainty shrinks to ``floor_sigma_rad_s`` at most
    (a bias known better from rest stays as known).
    """
    assert state.rotation_lp is not None and state.rotated_lp_rad_s is not None
    rotvec = quat.rotvec_between(predicted_q, posterior_q, "world").tolist()
    spurious = (scale_error * rate_rad_s) ** 2  # a scale error turns the rate into a correction as a bias would
    rows: list[int] = []
    stage: list[int] = []
    noise: list[float] = []
    correction: list[float] = []
    settled = state.tilt_settled_s >= SETTLE_TIME_CONSTANTS * tilt_tau_s
    if settled and tilt is not None and tilt.interval_s > 0.0 and tilt.gain > 0.0:  # north and east through LP2
        held = max(tilt.interval_s / tilt.gain, tilt_tau_s)
        w = (tilt.noise_rad2 / held**2 + spurious) * held / tilt.interval_s
        rows, stage, noise = [0, 1], [1, 1], [w, w]
        correction = [rotvec[0] / tilt.interval_s, rotvec[1] / tilt.interval_s]
    if heading is not None and heading.interval_s > 0.0 and heading.gain > 0.0:  # down through the heading's stage
        held = max(heading.interval_s / heading.gain, heading.correlation_s)
        rows, stage = rows + [2], stage + [2]
        noise.append(((heading.error_rad / held) ** 2 + spurious) * held / heading.interval_s)
        correction.append(rotvec[2] / heading.interval_s)
    if not rows:
        return state
    # The rows' noises are independent (a diagonal R), so updating with one row at a time is the joint update
    # exactly (sequential Kalman filtering; D. Simon, "Optimal State Estimation", 2006, sec. 6.1): a scalar
    # innovation variance per row, no matrix inverse, in plain floats (3-vectors: numpy's per-call cost would dominate).
    estimate = state.estimate_rad_s.tolist()
    covariance = state.covariance_rad2_s2.tolist()
    rotation_lp, rotated_lp = state.rotation_lp.tolist(), state.rotated_lp_rad_s.tolist()
    floor = min(params.floor_sigma_rad_s**2, state.variance_rad2_s2)
    for row, st, r, c in zip(rows, stage, noise, correction):
        h0, h1, h2 = rotation_lp[st][row]
        y = rotated_lp[st][row] - c
        ph0, ph1, ph2 = [p0 * h0 + p1 * h1 + p2 * h2 for p0, p1, p2 in covariance]  # P h^T
        innovation_variance = h0 * ph0 + h1 * ph1 + h2 * ph2 + r  # h P h^T + r
        gain = (ph0 / innovation_variance, ph1 / innovation_variance, ph2 / innovation_variance)
        innovation = y - (h0 * estimate[0] + h1 * estimate[1] + h2 * estimate[2])
        estimate = [e + k * innovation for e, k in zip(estimate, gain)]
        covariance = [[p0 - k * ph0, p1 - k * ph1, p2 - k * ph2] for (p0, p1, p2), k in zip(covariance, gain)]  # (I - k h) P
    learnt = [[0.5 * (covariance[i][j] + covariance[j][i]) for j in range(3)] for i in range(3)]
    mean = _mean_variance(learnt)
    if mean < floor:  # no surer than the floor (or than it was) from motion alone
        learnt = [[x * (floor / mean) for x in row_l] for row_l in learnt]
    return state.with_estimate(_clipped(estimate, params.max_abs_rad_s), np.array(learnt))


def may_learn(params: BiasSettings, at_rest: bool, prior_doubt_deg: float) -> bool:
    """Learning in motion only in motion (at rest the rest estimate is better) and after a prediction confident
    (``prior_doubt_deg``) on the axes the correction informs (the correction of a guess, a uniform start or the end
    of a gap, is not drift): the tilt's for the tilt rows (so 6-D fusion, its heading unknown, learns too), the
    whole attitude's for the heading row."""
    return params.feedback_enabled and not at_rest and prior_doubt_deg <= params.learn_max_uncertainty_deg


def learn_from_tick(config: FuserConfig, state: BiasState, predicted: Bingham, posterior_q: np.ndarray, tick: TickContext,
                    tilt_tau_s: float, interval_s: float, velocity: VelocityTrack, tilt: GravityReading | None,
                    heading: HeadingReading | None, heading_interval_s: float, unaided: UnaidedState, attitude_in_use: bool,
                    at_rest: bool, rate_rad_s: float, restarted: bool = False) -> BiasState:
    """One tick of bias learning in motion from the tick's readings (``tilt``: the gravity update's, plain or aided,
    ``heading``: the magnetometer's, ``heading_interval_s`` after its previous one; None: none this tick), the
    prediction ``predicted`` they corrected into ``posterior_q`` (``tick``: its doubts), ``interval_s`` after the previous
    IMU readings.

    The stages follow the rotation (:func:`low_pass`, with each fused reading's own gain). Without GNSS aiding the
    plain tilt and the heading corrections teach the bias (:func:`learn_in_motion`) where :func:`may_learn`, from a
    trusted tilt reading (``unaided``: the acceleration the accelerometer's norm reveals,
    :mod:`fuser.model.unaided`, in the tilt noise); while GNSS aids, the integral feedback
    (:func:`integral_feedback`), and likewise while the autopilot's attitude is in use
    (:func:`fuser.model.attitude.attitude_in_use`: the IMU too slow to carry the attitude, or ``attitude.mode =
    "always"``): its corrections, which are not modelled here, interleave with the modelled ones. ``restarted``: the
    strapdown frame broke this tick (a gyro gap or saturation) or the gravity update is in its fast start; nothing
    is learnt, and the memory starts again (the tilt's rows wait ``SETTLE_TIME_CONSTANTS`` for it): after a
    saturated gyro the recovery's corrections taught seed 3's hover a z bias 1.4 deg/s off within 2 s, and the
    estimate drifted 9 deg off reporting 4."""
    aided = velocity.active
    if restarted:  # a broken strapdown frame or a fast start: the corrections that follow are the recovery's, not the bias's
        return replace(state, rotation_lp=None, rotated_lp_rad_s=None)
    prior_doubt_deg = tick.prior_doubt_deg
    tilt_variance = math.radians(tick.prior_tilt_doubt_deg) ** 2
    tilt_gain = heading_gain = None
    if tilt is not None and tilt.exponent is not None and tilt.diagnostic is not None and tilt.diagnostic.sigma_deg is not None:
        tilt_gain = reading_gain(0.5 * tilt_variance, math.radians(tilt.diagnostic.sigma_deg))  # per horizontal axis
    if heading is not None and heading.exponent is not None and heading.diagnostic.sigma_deg is not None:
        heading_variance = max(math.radians(prior_doubt_deg) ** 2 - tilt_variance, 0.0)
        heading_gain = reading_gain(heading_variance, math.radians(heading.diagnostic.sigma_deg))
    predicted_q = predicted.mode
    state = low_pass(state, predicted_q, tilt_tau_s, interval_s, aided, tilt_gain, heading_gain)
    params = config.bias
    tilt_trusted = tilt is not None and tilt.trusted
    if not tilt_trusted:
        return state
    if aided or attitude_in_use:
        if rate_rad_s > params.learn_max_rate_rad_s or not may_learn(params, at_rest, prior_doubt_deg):
            return state
        # the correction spans the ticks since the bias last learnt: in motion with GNSS, the aided readings' spacing
        return integral_feedback(params, state, predicted_q, posterior_q, velocity.interval_s if aided and velocity.moving else interval_s)
    tilt_evidence = heading_evidence = None
    if (tilt is not None and tilt_gain is not None and tilt.diagnostic is not None and tilt.diagnostic.outcome == "fused"
            and may_learn(params, at_rest, math.degrees(math.sqrt(tilt_variance)))):
        unseen_rad2 = unseen_variances_rad2(config.accel, unaided, None)[0]
        tilt_evidence = TiltEvidence(tilt_gain, interval_s, math.radians(config.accel.lowpass_error_deg) ** 2 + unseen_rad2)
    if (heading is not None and heading_gain is not None and heading.diagnostic.outcome == "fused"
            and may_learn(params, at_rest, prior_doubt_deg)):
        heading_evidence = HeadingEvidence(heading_gain, heading_interval_s, math.radians(config.mag.error_deg), config.mag.correlation_s)
    return learn_in_motion(params, state, predicted_q, posterior_q, tilt_tau_s, tilt_evidence, heading_evidence, rate_rad_s,
                           config.gyro.scale_error_fraction)


def integral_feedback(params: BiasSettings, state: BiasState, predicted_q: np.ndarray, posterior_q: np.ndarray,
                      dt_s: float) -> BiasState:
    """Integral feedback of the tick's correction into the bias while the corrections are not the ones the Kalman
    filter models (GNSS aiding, the autopilot's attitude; ``dt_s`` since the last such correction; module docstring).

    A bias error ``e`` makes the prediction drift by ``e dt`` per tick, which
    the updates then correct; feeding ``-correction / tau`` back drives the
    estimate to the bias with time constant ``tau`` (``time_constant_s``).
    Learning shrinks the bias uncertainty towards its floor with the same
    time constant (the covariance scaled, its shape kept), and never raises
    it (a bias learnt at rest is known better than feedback can tell).
    """
    correction = quat.rotvec_between(predicted_q, posterior_q, "body").tolist()
    tau = params.time_constant_s
    estimate = _clipped([b - c / tau for b, c in zip(state.estimate_rad_s.tolist(), correction)], params.max_abs_rad_s)
    decay = min(1.0, dt_s / tau)
    covariance = state.covariance_rad2_s2
    variance = state.variance_rad2_s2
    learnt = variance - decay * max(0.0, variance - params.floor_sigma_rad_s**2)
    return state.with_estimate(estimate, covariance * (learnt / variance if variance > 0.0 else 1.0))
