"""The gyro bias: its uncertainty's random walk, and its integral feedback from the tick's correction.

The orientation stays a Bingham; the bias is a point estimate beside it
whose residual uncertainty enters the process noise as a correlated error
(:func:`fuser.model.propagation.predict`). It is learnt directly at rest
(:mod:`fuser.model.rest`; VQF's section on rest bias estimation) and, in slow
motion, by integral feedback (Mahony-style; VQF's motion bias estimation
plays the same role with a Kalman filter on the inclination correction).
"""

from __future__ import annotations

import numpy as np

from core import quaternion as quat
from fuser.config import BiasSettings
from fuser.model.state import BiasState

__all__ = ["learn_from_correction", "may_learn", "propagate"]


def propagate(params: BiasSettings, state: BiasState, dt_s: float) -> BiasState:
    """The bias uncertainty grows by its random walk over ``dt_s``, up to its initial value."""
    variance = min(state.variance_rad2_s2 + params.walk_rad_s_rt_s**2 * dt_s, params.initial_sigma_rad_s**2)
    return BiasState(state.estimate_rad_s, variance)


def learn_from_correction(params: BiasSettings, state: BiasState, predicted_q: np.ndarray, posterior_q: np.ndarray,
                          dt_s: float) -> BiasState:
    """Integral feedback of the tick's correction into the bias (``dt_s`` since the last such correction).

    A bias error ``e`` makes the prediction drift by ``e dt`` per tick, which
    the updates then correct; feeding ``-correction / tau`` back drives the
    estimate to the bias with time constant ``tau`` (``time_constant_s``).
    The caller decides whether this tick may teach (:func:`may_learn`).
    Learning shrinks the bias uncertainty towards its floor with the same
    time constant, and never raises it (a bias learnt at rest is known
    better than feedback can tell).
    """
    correction = quat.to_rotvec(quat.multiply(quat.conjugate(predicted_q), posterior_q))
    limit = params.max_abs_rad_s
    estimate = np.minimum(np.maximum(state.estimate_rad_s - correction / params.time_constant_s, -limit), limit)
    decay = min(1.0, dt_s / params.time_constant_s)
    variance = state.variance_rad2_s2 - decay * max(0.0, state.variance_rad2_s2 - params.floor_sigma_rad_s**2)
    return BiasState(estimate, variance)


def may_learn(params: BiasSettings, at_rest: bool, accel_trusted: bool, rate_rad_s: float, prior_doubt_deg: float) -> bool:
    """Feedback only in motion (at rest the rest estimate is better), with a trusted accelerometer, while
    turning slowly (manoeuvres must not leak into the bias) and after a confident prediction (the correction
    of a guess, a uniform start or the end of a gap, is not drift)."""
    return (params.feedback_enabled and not at_rest and accel_trusted and rate_rad_s <= params.learn_max_rate_rad_s
            and prior_doubt_deg <= params.learn_max_uncertainty_deg)
