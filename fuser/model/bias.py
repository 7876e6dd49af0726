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
plain and the heading corrections only.

Only the ticks with an aided reading were fed back, though the magnetometer
corrects the heading in every tick: at a 100 Hz loop with 10 Hz fixes nine
heading corrections in ten never reached the bias, at 1 Hz 99 in 100, and the
JSBSim Cessna kept its z bias 0.35 deg/s off through its 60 s. A tick with a
magnetometer reading alone now feeds back its correction's part about world
down (:func:`heading_feedback`), with an integral time constant of four times
the heading correction's own (``heading_interval / gain``), at least
``time_constant_s``: with the correction's rate ``1/tau_p`` and the integral's
``1/(tau_p tau_i)`` the heading and bias errors form a second-order loop of
damping ``sqrt(tau_i / tau_p) / 2``, critical at ``tau_i = 4 tau_p``. Fed back
with ``time_constant_s`` alone (5 s against the magnetometer's 10 s and more)
it swung the Cessna's z bias by 0.3-0.5 deg/s in its turns (4-min flights
1.84 -> 3.42 deg). Measured on the Cessna's 60 s (``tests/test_fuser_gnss_flights.py``)
with 10 / 5 / 1 Hz fixes: 2.32 / 2.90 (the truth in the 90 % region on 81 %
of the ticks) / 11.50 deg (48 %) -> 0.89 / 0.92 / 2.75 deg, all 100 %; the
README table's 4-min Cessna 1.98 / 1.84 / 1.45 -> 1.42 / 1.32 / 1.63; the
multirotor's flights (the table's and the short scenarios', seeds 0, 3, 7)
unchanged, its golden logs to the bit. The feedback runs the same way while the autopilot's
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

Compiled (numba) for the tick (:func:`fuser.model.fusion.tick`): the bias is
the state record's ``bias`` part (:data:`fuser.model.state.BIAS`), changed in
place by each function here; the stages' memory is ``rotation_lp`` and
``rotated_lp_rad_s`` with ``has_lp``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from core.quaternion_kernels import rotation_rows, rotvec_between_body, rotvec_between_world
from fuser.model import unaided as unaided_accel
from fuser.model import vec3
from fuser.model.diagnostics import FUSED
from fuser.model.tick import GravityReading, HeadingReading, TickContext, VelocityTrack

__all__ = ["SETTLE_TIME_CONSTANTS", "HeadingEvidence", "TiltEvidence", "correlation_s", "held_heading_variance_rad2", "integral_feedback",
           "learn_from_tick", "learn_in_motion", "low_pass", "may_learn", "propagate", "reading_gain", "variance_rad2_s2"]

SETTLE_TIME_CONSTANTS = 2.0
"""The tilt correction teaches the bias once the low-passes have followed it for this many time constants: before,
its response is still the start's transient (a first reading, a first aided pair), not the bias's."""

_NO_HEADING = np.bool_(False)
"""``unseen_variances_rad2``'s heading flag for the tilt alone, as a numpy bool: numba types a ``False`` passed to
a function as a literal and compiles the function for it again."""


class TiltEvidence(NamedTuple):
    """One fused tilt reading as a measurement of the bias (module docstring)."""

    gain: float
    """The Bingham product's gain ``k`` on the tilt (:func:`reading_gain`): stage 2."""
    interval_s: float
    """Seconds since the previous reading of this correction: the correction is a rate over it."""
    noise_rad2: float
    """Variance of the error of the down it corrects towards (module docstring), correlated over ``tau``."""


class HeadingEvidence(NamedTuple):
    """One fused magnetometer heading reading as a measurement of the bias (module docstring)."""

    gain: float
    interval_s: float
    error_rad: float
    """The magnetometer's correlated heading error (``mag.error_deg``)."""
    correlation_s: float


@njit(cache=True, nogil=True)
def variance_rad2_s2(bias: np.record) -> float:
    """Mean per-axis variance of the bias: the uncertainty the time constants and the process noise scale with."""
    c = bias.covariance_rad2_s2
    return (c[0, 0] + c[1, 1] + c[2, 2]) / 3.0


@njit(cache=True, nogil=True)
def correlation_s(params_bias: np.record) -> float:
    """How long a residual bias error persists in the prediction's process noise: the in-motion learning's time
    constant while it runs, ``correlation_without_feedback_s`` without it."""
    return params_bias.time_constant_s if params_bias.feedback_enabled else params_bias.correlation_without_feedback_s


@njit(cache=True, nogil=True)
def held_heading_variance_rad2(params_bias: np.record, bias: np.record, q_wxyz: tuple, held_s: float) -> float:
    """Heading variance (rad^2) of a bias error along the vertical held uncorrected for ``held_s``, beyond what the
    prediction counted (:func:`fuser.model.propagation.predict`: the mean per-axis bias variance correlated over
    ``tau``, ``sigma^2 tau dt`` per tick). The in-motion learning corrects the horizontal axes within ``tau``; along
    the vertical nothing corrects it while the heading is not measured, and an error ``e`` held for ``T`` turns the
    heading by ``e T``: ``sigma_v^2 T^2 - sigma^2 tau T`` (``q_wxyz`` the attitude, body -> NED)."""
    tau = correlation_s(params_bias)
    down = rotation_rows(q_wxyz)[2]  # world down in the body frame
    c = bias.covariance_rad2_s2
    vertical = 0.0
    for i in range(3):
        for j in range(3):
            vertical += down[i] * c[i, j] * down[j]
    return max(0.0, vertical * held_s * held_s - variance_rad2_s2(bias) * tau * held_s)


@njit(cache=True, nogil=True)
def propagate(params_bias: np.record, bias: np.record, dt_s: float) -> None:
    """The bias uncertainty grows by its random walk over ``dt_s``, each axis up to its initial value."""
    walk = params_bias.walk_rad_s_rt_s * params_bias.walk_rad_s_rt_s * dt_s
    c = bias.covariance_rad2_s2
    for i in range(3):
        c[i, i] += walk
    limit = params_bias.initial_sigma_rad_s
    s0 = min(1.0, limit / math.sqrt(c[0, 0]))
    s1 = min(1.0, limit / math.sqrt(c[1, 1]))
    s2 = min(1.0, limit / math.sqrt(c[2, 2]))
    if s0 != 1.0 or s1 != 1.0 or s2 != 1.0:  # an axis past its initial value: scaled back to it, the correlations kept
        scale = (s0, s1, s2)
        for i in range(3):
            for j in range(3):
                c[i, j] = c[i, j] * (scale[i] * scale[j])


@njit(cache=True, nogil=True)
def _clipped(v: float, limit: float) -> float:
    """``np.clip(v, -limit, limit)``."""
    return min(max(v, -limit), limit)


@njit(cache=True, nogil=True)
def reading_gain(prior_variance_rad2: float, sigma_rad: float) -> float:
    """Gain of a Bingham product on the axes a reading of sigma ``sigma_rad`` informs, for a prior of variance
    ``prior_variance_rad2`` on them: the mode moves by ``P / (P + sigma^2)`` of the innovation. The product adds
    the exponents (QBF paper, sec. 5, eq. 3); both concentrated, each is a Gaussian in the tangent space whose
    angle variance per axis is ``2 / |z|`` (the prior's) and ``sigma^2`` (the vector likelihood's, ``z = -2 /
    sigma^2``; unscented paper, sec. IV-B), and the product of two Gaussians moves by that fraction."""
    total = prior_variance_rad2 + sigma_rad * sigma_rad
    return prior_variance_rad2 / total if total > 0.0 else 0.0


@njit(cache=True, nogil=True)
def low_pass(bias: np.record, predicted_q: tuple, tilt_tau_s: float, interval_s: float, aided: bool, has_tilt_gain: bool,
             tilt_gain: float, has_heading_gain: bool, heading_gain: float) -> None:
    """The rotation (body -> world) and the rotated estimate one more interval through the tilt correction's two
    stages (its low-pass, time constant ``tilt_tau_s``; its gain, ``tilt_gain``: without a tilt reading this tick
    (``has_tilt_gain`` False) the stage held) and the heading correction's one (``heading_gain``, likewise).

    ``aided``: the tilt correction is GNSS-aided's. When the correction changes (aiding starts or ends), the
    correction's own low-pass starts again from its first reading, not from the other's history: the memory here
    starts again too, and :func:`learn_in_motion` waits for it to settle."""
    if interval_s <= 0.0:  # a reading at the same time again (or a clock that went back): nothing new
        return
    rotation = rotation_rows(predicted_q)
    rotated = vec3.mat_vec(rotation, vec3.load(bias.estimate_rad_s))
    r, b = bias.rotation_lp, bias.rotated_lp_rad_s
    if not bias.has_lp or aided != bias.tilt_aided:
        for stage in range(3):
            for i in range(3):
                b[stage, i] = rotated[i]
                for j in range(3):
                    r[stage, i, j] = rotation[i][j]
        bias.has_lp, bias.tilt_aided, bias.tilt_settled_s = True, aided, 0.0
        return
    # each stage's rotation and rotated estimate, entry by entry: stage 1 towards now, stage 2 towards stage 1,
    # the heading's stage towards now
    a = min(1.0, interval_s / tilt_tau_s)
    for i in range(3):
        for j in range(3):
            now = rotation[i][j]
            r[0, i, j] = r[0, i, j] + a * (now - r[0, i, j])
            if has_tilt_gain:
                r[1, i, j] = r[1, i, j] + tilt_gain * (r[0, i, j] - r[1, i, j])
            if has_heading_gain:
                r[2, i, j] = r[2, i, j] + heading_gain * (now - r[2, i, j])
        now = rotated[i]
        b[0, i] = b[0, i] + a * (now - b[0, i])
        if has_tilt_gain:
            b[1, i] = b[1, i] + tilt_gain * (b[0, i] - b[1, i])
        if has_heading_gain:
            b[2, i] = b[2, i] + heading_gain * (now - b[2, i])
    bias.tilt_settled_s = bias.tilt_settled_s + interval_s


@njit(cache=True, nogil=True)
def learn_in_motion(params_bias: np.record, bias: np.record, predicted_q: tuple, posterior_q: tuple, tilt_tau_s: float, has_tilt: bool,
                    tilt: TiltEvidence, has_heading: bool, heading: HeadingEvidence, rate_rad_s: float, scale_error: float) -> None:
    """Kalman update of the bias with the tick's tilt correction (north and east rows, through ``LP2``) and heading
    correction (the down row, through its single stage); call after :func:`low_pass` with the same gains. ``tilt``
    and ``heading`` count only with ``has_tilt`` and ``has_heading``.

    Each row's noise: the error ``n`` of what the correction follows, correlated over ``tau_c`` (the tilt's
    ``tau``, the magnetometer's ``correlation_s``), through the correction's own time constant ``tau_2 = T / k``,
    ``(n / max(tau_2, tau_c))^2``, plus the scale error's ``(s w)^2``, counted once per ``max(tau_2, tau_c)`` since
    consecutive corrections share it (module docstring). The uncertainty shrinks to ``floor_sigma_rad_s`` at most
    (a bias known better from rest stays as known). Without the stages' memory (``has_lp`` False: no interval has
    reached :func:`low_pass` since it started again) nothing is learnt.
    """
    if not bias.has_lp:
        return
    rotvec = rotvec_between_world(predicted_q, posterior_q)
    spurious = (scale_error * rate_rad_s) * (scale_error * rate_rad_s)  # a scale error turns the rate into a correction as a bias would
    settled = bias.tilt_settled_s >= SETTLE_TIME_CONSTANTS * tilt_tau_s
    tilt_rows = settled and has_tilt and tilt.interval_s > 0.0 and tilt.gain > 0.0  # north and east through LP2
    heading_row = has_heading and heading.interval_s > 0.0 and heading.gain > 0.0  # down through the heading's stage
    if not (tilt_rows or heading_row):
        return
    floor = min(params_bias.floor_sigma_rad_s * params_bias.floor_sigma_rad_s, variance_rad2_s2(bias))
    tilt_noise = heading_noise = 0.0
    if tilt_rows:
        held = max(tilt.interval_s / tilt.gain, tilt_tau_s)
        tilt_noise = (tilt.noise_rad2 / (held * held) + spurious) * held / tilt.interval_s
    if heading_row:
        held = max(heading.interval_s / heading.gain, heading.correlation_s)
        heading_noise = ((heading.error_rad / held) * (heading.error_rad / held) + spurious) * held / heading.interval_s
    # The rows' noises are independent (a diagonal R), so updating with one row at a time is the joint update
    # exactly (sequential Kalman filtering; D. Simon, "Optimal State Estimation", 2006, sec. 6.1): a scalar
    # innovation variance per row, no matrix inverse. Rows 0 and 1 (north, east) through stage 2, row 2 (down)
    # through the heading's stage.
    e, P = bias.estimate_rad_s, bias.covariance_rad2_s2
    for row in range(3):
        if row < 2:
            if not tilt_rows:
                continue
            stage, noise, correction = 1, tilt_noise, rotvec[row] / tilt.interval_s
        else:
            if not heading_row:
                continue
            stage, noise, correction = 2, heading_noise, rotvec[2] / heading.interval_s
        h0, h1, h2 = bias.rotation_lp[stage, row, 0], bias.rotation_lp[stage, row, 1], bias.rotation_lp[stage, row, 2]
        y = bias.rotated_lp_rad_s[stage, row] - correction
        ph0 = P[0, 0] * h0 + P[0, 1] * h1 + P[0, 2] * h2  # P h^T
        ph1 = P[1, 0] * h0 + P[1, 1] * h1 + P[1, 2] * h2
        ph2 = P[2, 0] * h0 + P[2, 1] * h1 + P[2, 2] * h2
        innovation_variance = h0 * ph0 + h1 * ph1 + h2 * ph2 + noise  # h P h^T + r
        k0, k1, k2 = ph0 / innovation_variance, ph1 / innovation_variance, ph2 / innovation_variance
        innovation = y - (h0 * e[0] + h1 * e[1] + h2 * e[2])
        e[0], e[1], e[2] = e[0] + k0 * innovation, e[1] + k1 * innovation, e[2] + k2 * innovation
        for i in range(3):  # (I - k h) P
            k = k0 if i == 0 else (k1 if i == 1 else k2)
            P[i, 0], P[i, 1], P[i, 2] = P[i, 0] - k * ph0, P[i, 1] - k * ph1, P[i, 2] - k * ph2
    for i in range(3):
        for j in range(i + 1, 3):
            P[i, j] = P[j, i] = 0.5 * (P[i, j] + P[j, i])
    mean = variance_rad2_s2(bias)
    if mean < floor:  # no surer than the floor (or than it was) from motion alone
        for i in range(3):
            for j in range(3):
                P[i, j] = P[i, j] * (floor / mean)
    for i in range(3):
        e[i] = _clipped(e[i], params_bias.max_abs_rad_s)


@njit(cache=True, nogil=True)
def may_learn(params_bias: np.record, at_rest: bool, prior_doubt_deg: float) -> bool:
    """Learning in motion only in motion (at rest the rest estimate is better) and after a prediction confident
    (``prior_doubt_deg``) on the axes the correction informs (the correction of a guess, a uniform start or the end
    of a gap, is not drift): the tilt's for the tilt rows (so 6-D fusion, its heading unknown, learns too), the
    whole attitude's for the heading row."""
    return params_bias.feedback_enabled and not at_rest and prior_doubt_deg <= params_bias.learn_max_uncertainty_deg


@njit(cache=True, nogil=True)
def learn_from_tick(params: np.record, bias: np.record, predicted_q: tuple, posterior_q: tuple, tick: TickContext, tilt_tau_s: float,
                    interval_s: float, velocity: VelocityTrack, has_tilt: bool, tilt: GravityReading, has_heading: bool,
                    heading: HeadingReading, heading_interval_s: float, unaided: np.record, attitude_in_use: bool, at_rest: bool,
                    rate_rad_s: float, restarted: bool) -> None:
    """One tick of bias learning in motion from the tick's readings (``tilt``: the gravity update's, plain or aided,
    ``heading``: the magnetometer's, ``heading_interval_s`` after its previous one; each only with ``has_tilt``,
    ``has_heading``), the prediction ``predicted_q`` they corrected into ``posterior_q`` (``tick``: its doubts),
    ``interval_s`` after the previous IMU readings; ``params`` the whole parameters record, ``bias`` and ``unaided``
    the state's parts (``bias`` changed in place).

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
        bias.has_lp = False
        for stage in range(3):
            for i in range(3):
                bias.rotated_lp_rad_s[stage, i] = 0.0
                for j in range(3):
                    bias.rotation_lp[stage, i, j] = 0.0
        return
    prior_doubt_deg = tick.prior_doubt_deg
    tilt_variance = math.radians(tick.prior_tilt_doubt_deg) * math.radians(tick.prior_tilt_doubt_deg)
    tilt_gain = heading_gain = 0.0
    has_tilt_gain = has_tilt and tilt.fused and tilt.diagnostic.present and not math.isnan(tilt.diagnostic.sigma_rad)
    if has_tilt_gain:
        tilt_gain = reading_gain(0.5 * tilt_variance, tilt.diagnostic.sigma_rad)  # per horizontal axis
    has_heading_gain = has_heading and heading.fused and not math.isnan(heading.diagnostic.sigma_rad)
    if has_heading_gain:
        heading_variance = max(math.radians(prior_doubt_deg) * math.radians(prior_doubt_deg) - tilt_variance, 0.0)
        heading_gain = reading_gain(heading_variance, heading.diagnostic.sigma_rad)
    low_pass(bias, predicted_q, tilt_tau_s, interval_s, aided, has_tilt_gain, tilt_gain, has_heading_gain, heading_gain)
    p = params.bias
    tilt_trusted = has_tilt and tilt.trusted
    if aided or attitude_in_use:
        if rate_rad_s > p.learn_max_rate_rad_s or not may_learn(p, at_rest, prior_doubt_deg):
            return
        if tilt_trusted:
            # the correction spans the ticks since the bias last learnt: in motion with GNSS, the aided readings' spacing
            integral_feedback(p, bias, predicted_q, posterior_q, velocity.interval_s if aided and velocity.moving else interval_s)
        elif has_heading_gain and heading_gain > 0.0:  # a magnetometer reading alone: critically damped (module docstring)
            heading_feedback(p, bias, predicted_q, posterior_q, max(p.time_constant_s, 4.0 * heading_interval_s / heading_gain))
        return
    if not tilt_trusted:
        return
    tilt_evidence, heading_evidence = TiltEvidence(0.0, 0.0, 0.0), HeadingEvidence(0.0, 0.0, 0.0, 0.0)
    has_tilt_evidence = (has_tilt_gain and tilt.diagnostic.outcome == FUSED
                         and may_learn(p, at_rest, math.degrees(math.sqrt(tilt_variance))))
    if has_tilt_evidence:
        unseen_rad2 = unaided_accel.unseen_variances_rad2(params.accel, unaided, _NO_HEADING, vec3.ZERO)[0]
        noise = math.radians(params.accel.lowpass_error_deg) * math.radians(params.accel.lowpass_error_deg) + unseen_rad2
        tilt_evidence = TiltEvidence(tilt_gain, interval_s, noise)
    has_heading_evidence = has_heading_gain and heading.diagnostic.outcome == FUSED and may_learn(p, at_rest, prior_doubt_deg)
    if has_heading_evidence:
        heading_evidence = HeadingEvidence(heading_gain, heading_interval_s, math.radians(params.mag.error_deg), params.mag.correlation_s)
    learn_in_motion(p, bias, predicted_q, posterior_q, tilt_tau_s, has_tilt_evidence, tilt_evidence, has_heading_evidence,
                    heading_evidence, rate_rad_s, params.gyro.scale_error_fraction)


@njit(cache=True, nogil=True)
def heading_feedback(params_bias: np.record, bias: np.record, predicted_q: tuple, posterior_q: tuple, tau_s: float) -> None:
    """Integral feedback of a tick's heading correction alone (a magnetometer reading between the aided ones, module
    docstring): its part about world down (in the corrected body frame) fed back with time constant ``tau_s``; the
    bias uncertainty is left as it is (the aided ticks' feedback shrinks it)."""
    correction = rotvec_between_body(predicted_q, posterior_q)
    down = rotation_rows(posterior_q)[2]  # world down in the body frame
    about_down = vec3.dot(correction, down)
    _fed_back(params_bias, bias, (about_down * down[0], about_down * down[1], about_down * down[2]), tau_s)


@njit(cache=True, nogil=True, inline="always")  # inlined: three lines, the two feedbacks' shared step
def _fed_back(params_bias: np.record, bias: np.record, correction: tuple, tau_s: float) -> None:
    """The bias estimate less a body-frame ``correction`` over ``tau_s`` (integral feedback), each axis clipped."""
    e = bias.estimate_rad_s
    for i in range(3):
        e[i] = _clipped(e[i] - correction[i] / tau_s, params_bias.max_abs_rad_s)


@njit(cache=True, nogil=True)
def integral_feedback(params_bias: np.record, bias: np.record, predicted_q: tuple, posterior_q: tuple, dt_s: float) -> None:
    """Integral feedback of the tick's correction into the bias while the corrections are not the ones the Kalman
    filter models (GNSS aiding, the autopilot's attitude; ``dt_s`` since the last such correction; module docstring).

    A bias error ``e`` makes the prediction drift by ``e dt`` per tick, which
    the updates then correct; feeding ``-correction / tau`` back drives the
    estimate to the bias with time constant ``tau`` (``time_constant_s``).
    Learning shrinks the bias uncertainty towards its floor with the same
    time constant (the covariance scaled, its shape kept), and never raises
    it (a bias learnt at rest is known better than feedback can tell).
    """
    tau = params_bias.time_constant_s
    _fed_back(params_bias, bias, rotvec_between_body(predicted_q, posterior_q), tau)
    decay = min(1.0, dt_s / tau)
    variance = variance_rad2_s2(bias)
    learnt = variance - decay * max(0.0, variance - params_bias.floor_sigma_rad_s * params_bias.floor_sigma_rad_s)
    scale = learnt / variance if variance > 0.0 else 1.0
    P = bias.covariance_rad2_s2
    for i in range(3):
        for j in range(3):
            P[i, j] = P[i, j] * scale
