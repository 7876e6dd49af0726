"""The gravity update: the accelerometer, low-passed in a near-inertial frame, as a direction of down.

Every reading is rotated into an inertial frame by the gyro-only strapdown
attitude (never corrected, so the frame holds still while the estimate is
corrected) and low-passed there, as VQF's inclination correction does (tauAcc): linear and
centripetal accelerations average out over the tilt time constant, gravity
does not, and rotation does not smear the filter. The filtered vector, seen
in the current body frame, is the measurement of down, an exact Bingham
likelihood in the attitude (Davenport's K,
:func:`core.observations.vector_exponent`; unscented paper, sec. IV-B).

Consecutive filtered readings are strongly correlated, so they must not be
counted as independent: the sigma is set so that the correction time
constant is the low-pass's ``tau`` (``sigma^2 = Q (tau/T)^2`` for readings
every ``T`` seconds and the process variance ``Q`` accumulated over ``T``),
which keeps the reported tilt uncertainty honest whatever the IMU rate.
Until the state first converges the raw reading is used with
``accel.sigma_rad``, for a fast start; never after, when a raw reading
mid-manoeuvre is the misleading one. The low-pass starts at convergence from
the mean of the raw readings fused before it (in the strapdown frame): what the
estimate has followed, vibration averaged, and in a turn with the turn's norm,
which the unaided widening (:mod:`fuser.model.unaided`) reads; from the
filter's own estimate of down when there were none (the GNSS-aided update ran
before, or nothing was fused yet).

While GNSS velocity aids it, the velocity-aided variant beside this one
(:func:`fuser.model.velocity.update_gravity_aided`: the world acceleration
from GNSS velocity taken out of the specific force, both low-passed alike)
gives the :class:`GravityReading` instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core import quaternion as quat
from core.observations import vector_exponent
from fuser.config import AccelSettings, BiasSettings, UpdateSettings
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.gate import innovation_gate
from fuser.model.state import GravityState
from fuser.model.tick import TickContext

__all__ = ["DOWN_NED", "GravityReading", "tilt_time_constant_s", "turn_frame", "update_gravity"]

DOWN_NED = np.array([0.0, 0.0, 1.0])
"""World down in NED: the reference direction of the gravity measurement (a frame convention, not a tuning)."""


@dataclass(frozen=True, slots=True)
class GravityReading:
    """One tick's gravity update."""

    state: GravityState
    exponent: np.ndarray | None
    """Likelihood exponent to multiply into the state (None: nothing fused)."""
    apply_now: bool
    """The first tilt ever measured: apply it before the heading update, which needs to know which way is down."""
    trusted: bool
    """The accelerometer was converged and well inside its norm gate: the bias feedback may learn this tick."""
    diagnostic: UpdateDiagnostic | None
    """None: no reading this tick (GNSS-aided, between two fixes)."""
    tilt_bound_rad: float | None = None
    """A GNSS-aided reading's bound on the prediction's tilt error: its innovation plus twice its noise (the GNSS
    velocity's, differenced and low-passed; not the correction-time sigma). None for the plain update."""


def turn_frame(state: GravityState, rotation: np.ndarray | None, gap_s: float) -> GravityState:
    """The strapdown frame after the tick's gyro rotation. A gap in the gyro (``gap_s`` of the tick without a
    rate) breaks the frame: the body turned by an unknown rotation, so the low-pass's memory is dropped and the
    update starts again as before convergence (raw readings until the state is sure again), their mean from the next."""
    q = state.q_strapdown if rotation is None else quat.normalize(quat.multiply(state.q_strapdown, rotation))
    if gap_s > 0.0:  # the raw readings' mean too, converged or not
        return GravityState(q, None, state.down_body, False, state.tilt_known, state.gated_s)
    return GravityState(q, state.accel_lp_m_s2, state.down_body, state.converged, state.tilt_known, state.gated_s, state.raw_mean_m_s2,
                        state.raw_s)


def tilt_time_constant_s(params: AccelSettings, bias: BiasSettings, bias_variance_rad2_s2: float) -> float:
    """Tilt-correction (and low-pass) time constant for the current bias uncertainty.

    A residual bias ``b`` makes the tilt lag by ``b tau`` behind a correction
    loop of time constant ``tau``; a longer ``tau`` lets less linear
    acceleration through. So ``tau = tilt_bias_error / sigma_b``, capped at
    ``lowpass_s``: fast while the bias is unknown (a cold start, a
    multirotor's 1 deg/s bias), VQF's slow 3 s once learnt.
    """
    return min(params.lowpass_s, math.radians(params.tilt_bias_error_deg) / math.sqrt(max(bias_variance_rad2_s2, bias.min_variance_rad2_s2)))


def update_gravity(params: AccelSettings, updates: UpdateSettings, state: GravityState, tick: TickContext, accel_body_m_s2: np.ndarray,
                   tau_s: float, predicted_q: np.ndarray, interval_s: float) -> GravityReading:
    """The gravity update of one tick from the tick's mean specific force in the state's body frame, the
    readings ``interval_s`` after the previous ones."""
    to_inertial = quat.to_matrix(state.q_strapdown)
    f_inertial = to_inertial @ accel_body_m_s2
    converged = state.converged or tick.prior_doubt_deg < updates.converged_deg
    predicted_down = quat.to_matrix(predicted_q)[2]  # R^T e_z: world down in the body
    raw_mean, raw_s = state.raw_mean_m_s2, state.raw_s
    if not converged:
        lowpassed = None
    else:
        # the low-pass starts from what the estimate followed (the raw readings' mean), or from the estimate itself
        start = state.accel_lp_m_s2
        if start is None:
            start = to_inertial @ (-params.gravity_m_s2 * predicted_down) if raw_mean is None else raw_mean
        lowpassed = start + min(1.0, interval_s / tau_s) * (f_inertial - start)
        raw_mean, raw_s = None, 0.0
    measured = f_inertial if lowpassed is None else lowpassed
    norm = math.sqrt(float(measured @ measured))
    norm_error = abs(norm - params.gravity_m_s2) / params.gravity_m_s2
    if norm_error > params.norm_gate_fraction:
        kept = GravityState(state.q_strapdown, lowpassed, state.down_body, converged, state.tilt_known, state.gated_s, raw_mean, raw_s)
        return GravityReading(kept, None, False, False, UpdateDiagnostic.of("gravity", "gated", "norm"))
    filtered_body = measured @ to_inertial
    down_body = -filtered_body / norm
    if converged:  # Q = q T / dt over the interval T
        sigma = math.sqrt(tick.process_variance_rad2 * interval_s / tick.dt_s) * tau_s / max(interval_s, 1e-6)
    else:
        sigma = params.sigma_rad
    innovation = math.acos(max(-1.0, min(1.0, float(down_body @ predicted_down))))
    verdict = innovation_gate(updates, state.gated_s, innovation, sigma, tick.prior_doubt_deg, tick.dt_s)
    # nothing to gate against before the first tilt
    outcome, gated_s = (verdict.outcome, verdict.gated_s) if state.tilt_known else ("fused", state.gated_s)
    diagnostic = UpdateDiagnostic.of("gravity", outcome, "innovation" if outcome == "gated" else "", innovation, sigma, verdict.test_ratio)
    fused = outcome != "gated"
    if fused and lowpassed is None:  # a raw reading the estimate follows, into their mean
        raw_s = raw_s + interval_s
        raw_mean = f_inertial if raw_mean is None else raw_mean + (interval_s / raw_s) * (f_inertial - raw_mean)
    after = GravityState(state.q_strapdown, lowpassed, down_body, converged, state.tilt_known or fused, gated_s, raw_mean, raw_s)
    if not fused:
        return GravityReading(after, None, False, False, diagnostic)
    trusted = converged and norm_error < 0.5 * params.norm_gate_fraction
    return GravityReading(after, vector_exponent(-filtered_body, DOWN_NED, sigma), not state.tilt_known, trusted, diagnostic)
