"""The gyro bias: a Gaussian beside the Bingham, measured at rest and learnt in motion from the tick's corrections.

**How the bias and the attitude are coupled.** The orientation stays a
Bingham; the bias is a Gaussian (estimate and 3x3 covariance, body frame)
beside it, and the two are coupled as VQF couples them, without a
cross-covariance: the residual bias error enters the attitude's process
noise as a correlated error (an error ``e`` that persists for a correlation
time ``T`` turns the attitude by ``e T``, which white noise of variance
``e^2 T`` per second matches over ``T``; :func:`fuser.model.propagation.predict`),
and the attitude's corrections are measurements of the bias (below), in a
Kalman filter on the bias alone. The cross-covariance is left out on
purpose: it would be a covariance between the bias and a Gaussian attitude
error at a fixed base point, and the Bingham's mode moves every tick, its
heading may be unknown (``z = 0``, 6-D), and a gravity reading leaves
uninformed the rotation about the *measured* down, not the predicted one:
the tangent-space information of prior and likelihood are then nearly but
not exactly aligned, and a linearised joint update would mix the
cross-covariance's uninformed heading row into its tilt rows by a factor
that grows as the innovation shrinks. The correlated process noise is the
conservative stand-in: it widens the attitude by what the bias uncertainty
can do, whatever the correlation.

**At rest** (:mod:`fuser.model.rest`) the low-passed gyro reads the bias
directly (VQF, rest bias estimation).

**In motion** (VQF, "motion bias estimation": D. Laidig, T. Seel,
Information Fusion 91, 2023, sec. 3.2). A bias error ``e = b - b_hat``
(body frame) turns the predicted attitude by ``-R e`` per second (``R`` body
-> world); the updates pull it back. The tilt correction is a low-pass of
the accelerometer in the gyro's strapdown frame followed by a correction of
the state towards it, each with the tilt time constant ``tau``
(:mod:`fuser.model.gravity`); linearised, its correction rate (world frame,
north and east) is ``c / dt = -LP2(R e)``, ``LP2`` two first-order low-passes
of time constant ``tau`` in series. So, as VQF does with its Butterworth
low-pass, ``y = LP2(R b_hat) - c / dt`` measures ``LP2(R) b``: a Kalman
update with the low-passed rotation's rows as ``H``. Whichever way the body
turns, the components that have been horizontal within the last ``tau``
are observed, at any rotation rate. The heading correction (the
magnetometer's, a single low-pass of its own time constant,
:func:`fuser.model.heading.heading_time_constant_s`) measures the vertical
row the same way where the heading update fused.

Each correction rate's noise is the error of what it follows over its time
constant (the low-passed accelerometer's ``motion_tilt_noise_deg``, the
magnetometer's ``mag.error_deg``), counted once per time constant (or per
the magnetometer error's correlation time) since consecutive corrections
share it, plus what a gyro scale error makes of the rotation rate (``s w``
looks like a bias of that size): fast rotation teaches less. Motion alone
never brings the uncertainty below ``floor_sigma_rad_s`` (the corrections'
slowly varying errors are not white); a bias measured better at rest keeps
its own.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from core import quaternion as quat
from fuser.config import BiasSettings
from fuser.model.state import BiasState

__all__ = ["SETTLE_TIME_CONSTANTS", "learn_in_motion", "low_pass", "may_learn", "propagate"]

SETTLE_TIME_CONSTANTS = 2.0
"""The tilt correction teaches the bias once the low-passes have followed it for this many time constants: before,
its response is still the start's transient (a first reading, a first aided pair), not the bias's."""

def propagate(params: BiasSettings, state: BiasState, dt_s: float) -> BiasState:
    """The bias uncertainty grows by its random walk over ``dt_s``, each axis up to its initial value."""
    covariance = state.covariance_rad2_s2 + params.walk_rad_s_rt_s**2 * dt_s * np.eye(3)
    scale = np.minimum(1.0, params.initial_sigma_rad_s / np.sqrt(np.diag(covariance)))
    return state.with_covariance(covariance * np.outer(scale, scale))


def low_pass(state: BiasState, predicted_q: np.ndarray, tilt_tau_s: float, heading_tau_s: float | None, interval_s: float,
             aided: bool = False) -> BiasState:
    """The rotation (body -> world) and the rotated bias estimate one more interval through the tilt
    correction's ``LP2`` (time constant ``tilt_tau_s``) and, for the vertical axis, the heading correction's
    single low-pass (``heading_tau_s``; None: no heading reading this tick, the vertical memory is kept).

    ``aided``: the tilt correction is GNSS-aided's (:mod:`fuser.model.velocity`). When the correction changes
    (aiding starts or ends), the correction's own low-pass starts again from its first reading, not from the
    other's history: the memory here starts again too, and :func:`learn_in_motion` waits for it to settle."""
    if interval_s <= 0.0:  # a reading at the same time again (or a clock that went back): nothing new
        return state
    rotation = quat.to_matrix(predicted_q)
    rotated = rotation @ state.estimate_rad_s
    if state.rotation_lp is None or state.rotated_lp_rad_s is None or aided != state.tilt_aided:
        return replace(state, rotation_lp=np.stack([rotation, rotation, rotation]), rotated_lp_rad_s=np.stack([rotated, rotated, rotated]),
                       tilt_aided=aided, tilt_settled_s=0.0)
    r, b = state.rotation_lp.copy(), state.rotated_lp_rad_s.copy()
    a = min(1.0, interval_s / tilt_tau_s)
    r[0] += a * (rotation - r[0])
    b[0] += a * (rotated - b[0])
    r[1] += a * (r[0] - r[1])
    b[1] += a * (b[0] - b[1])
    if heading_tau_s is not None:
        a = min(1.0, interval_s / heading_tau_s)
        r[2] += a * (rotation - r[2])
        b[2] += a * (rotated - b[2])
    return replace(state, rotation_lp=r, rotated_lp_rad_s=b, tilt_settled_s=state.tilt_settled_s + interval_s)


def learn_in_motion(params: BiasSettings, state: BiasState, predicted_q: np.ndarray, posterior_q: np.ndarray,
                    tilt_interval_s: float | None, tilt_tau_s: float, heading: tuple[float, float, float, float] | None,
                    rate_rad_s: float, scale_error: float, tilt_excess_rad2: float = 0.0) -> BiasState:
    """Kalman update of the bias with the tick's tilt correction (``tilt_interval_s``: the time since the tilt
    was last measured, the correction being a rate over it; None: the tilt was not measured in this tick) and,
    with ``heading = (tau_s, error_rad, correlation_s, interval_s)`` (the heading update fused), its heading
    correction (module docstring); call after :func:`low_pass`.

    Each correction rate's noise is the error of what it corrects towards
    (``motion_tilt_noise_deg``, the magnetometer's ``error_rad``) over its
    time constant, counted once per time constant or, for the
    magnetometer's, once per its error's correlation time if longer
    (consecutive corrections share the error). The uncertainty shrinks to
    ``floor_sigma_rad_s`` at most (a bias known better from rest stays as known).

    ``tilt_excess_rad2``: what the low-passed specific force's norm says of the acceleration left in it. A
    horizontal acceleration that turns it by ``theta`` lengthens it by ``1 / cos(theta)``: a relative norm
    error ``d`` means ``theta^2 ~ 2 d`` of non-gravity in the direction the tilt follows, at least. In a
    sustained coordinated turn (a fixed wing's 1.15 g at 30 deg of bank) that false vertical stays put in the
    body frame and its correction looks exactly like a bias: its variance is added to the tilt noise.
    """
    assert state.rotation_lp is not None and state.rotated_lp_rad_s is not None
    rotvec = quat.to_rotvec(quat.multiply(posterior_q, quat.conjugate(predicted_q)))  # world frame
    spurious = (scale_error * rate_rad_s) ** 2  # a scale error turns the rate into a correction as a bias would
    rows: list[int] = []
    stage: list[int] = []
    noise: list[float] = []
    correction: list[float] = []
    settled = state.tilt_settled_s >= SETTLE_TIME_CONSTANTS * tilt_tau_s
    if settled and tilt_interval_s is not None and tilt_interval_s > 0.0:  # north and east through LP2
        tilt_noise = ((math.radians(params.motion_tilt_noise_deg) ** 2 + tilt_excess_rad2) / tilt_tau_s**2 + spurious) * tilt_tau_s / tilt_interval_s
        rows, stage, noise = [0, 1], [1, 1], [tilt_noise, tilt_noise]
        correction = [rotvec[0] / tilt_interval_s, rotvec[1] / tilt_interval_s]
    if heading is not None and heading[3] > 0.0:  # down through the heading correction's low-pass
        tau, error, correlation, interval_s = heading
        rows, stage = rows + [2], stage + [2]
        noise.append(((error / tau) ** 2 + spurious) * max(tau, correlation) / interval_s)
        correction.append(rotvec[2] / interval_s)
    if not rows:
        return state
    y = state.rotated_lp_rad_s[stage, rows] - np.array(correction)
    h = state.rotation_lp[stage, rows, :]
    covariance = state.covariance_rad2_s2
    gain = covariance @ h.T @ np.linalg.inv(h @ covariance @ h.T + np.diag(noise))
    limit = params.max_abs_rad_s
    estimate = np.clip(state.estimate_rad_s + gain @ (y - h @ state.estimate_rad_s), -limit, limit)
    learnt = (np.eye(3) - gain @ h) @ covariance
    learnt = 0.5 * (learnt + learnt.T)
    floor = min(params.floor_sigma_rad_s**2, state.variance_rad2_s2)
    if np.trace(learnt) / 3.0 < floor:  # no surer than the floor (or than it was) from motion alone
        learnt = learnt * (floor / (np.trace(learnt) / 3.0))
    return state.with_estimate(estimate, learnt)


def may_learn(params: BiasSettings, at_rest: bool, accel_trusted: bool, prior_doubt_deg: float) -> bool:
    """Learning in motion only in motion (at rest the rest estimate is better), from a trusted accelerometer
    (fused, its low-passed norm well inside the gate) and after a confident prediction (the correction of a
    guess, a uniform start or the end of a gap, is not drift)."""
    return params.feedback_enabled and not at_rest and accel_trusted and prior_doubt_deg <= params.learn_max_uncertainty_deg
