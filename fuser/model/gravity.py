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
That sigma sets a gain, not the reading's error: it grows as ``1 / sqrt(T)``
and with the process noise (11 deg per reading at a 100 Hz loop with the bias
at its motion floor, 16 deg at 200 Hz), so an innovation gate of a few of
those never fired, and whether the accelerometer was gated in a turn depended
on the loop rate. The gate is therefore against the smaller of it and what
the low-passed down may be off by, ``accel.lowpass_error_deg`` (the linear
acceleration the low-pass leaves), with the state's doubt. The JSBSim
Cessna's 30-deg turn without GNSS at a 200 Hz loop: 48 deg RMS total before,
15 after; the same at 100 Hz 11.7 and 11.1; BROAD unchanged but trial 16
(0.86 -> 0.88 deg).
Until the state first converges the raw reading is used with
``accel.sigma_rad`` (per ``updates.fast_start_interval_s`` of readings,
:func:`fuser.model.gate.fast_start_sigma_rad`), for a fast start; never after, when a raw reading
mid-manoeuvre is the misleading one. The low-pass starts at convergence from
the mean of the raw readings fused before it (in the strapdown frame): what the
estimate has followed, vibration averaged, and in a turn with the turn's norm,
which the unaided widening (:mod:`fuser.model.unaided`) reads; from the
filter's own estimate of down when there were none (the GNSS-aided update ran
before, or nothing was fused yet).

While GNSS fixes come, a raw reading measures ``g e_z - a`` instead of down,
``a`` the pairs of fixes' acceleration low-passed (:func:`fuser.model.velocity.raw_world`),
its noise in the reading's sigma: in a turn the raw reading is the lift's
direction, not gravity's. The first such reading is checked against the state
built before it, from readings all taken for down: beyond the gate (a start in
a turn, the bank's vertical) the fast start runs again (``restart``: the
state's tilt and heading widened, unconverged, the magnetometer a whole vector,
:mod:`fuser.model.heading`).

While GNSS velocity aids it, the velocity-aided variant beside this one
(:func:`fuser.model.velocity.update_gravity_aided`: the world acceleration
from GNSS velocity taken out of the specific force, both low-passed alike)
gives the :class:`GravityReading` instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from core import quaternion as quat
from core.observations import vector_exponent
from drivers.samples import Vec3
from fuser.config import AccelSettings, BiasSettings, UpdateSettings
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model import vec3
from fuser.model.gate import fast_start_sigma_rad, innovation_gate
from fuser.model.state import GravityState
from fuser.model.tick import TickContext

__all__ = ["DOWN_NED", "GnssWorld", "GravityReading", "tilt_time_constant_s", "turn_frame", "update_gravity"]

DOWN_NED = np.array([0.0, 0.0, 1.0])
"""World down in NED: the reference direction of the gravity measurement (a frame convention, not a tuning)."""
_DOWN = (0.0, 0.0, 1.0)
""":data:`DOWN_NED` in floats (:mod:`fuser.model.vec3`)."""
_DOWN_NED_READ_ONLY = np.array(_DOWN)
_DOWN_NED_READ_ONLY.setflags(write=False)  # shared by every state that measured down
_GNSS_RAW = (("aiding", "gnss_raw"),)


class GnssWorld(NamedTuple):
    """What a raw reading measures in the world while GNSS fixes come (:func:`fuser.model.velocity.raw_world`)."""

    vector_m_s2: np.ndarray
    """``g e_z - a`` (NED), ``a`` the vehicle's acceleration from GNSS velocity."""
    noise_m_s2: float
    """One-sigma noise per axis of ``a``."""


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
    restart: bool = False
    """The fast start runs again: the state had converged on raw readings the GNSS acceleration shows wrong."""


def turn_frame(state: GravityState, rotation: np.ndarray | None, gap_s: float) -> GravityState:
    """The strapdown frame after the tick's gyro rotation. A gap in the gyro (``gap_s`` of the tick without a
    rate) breaks the frame: the body turned by an unknown rotation, so the low-pass's memory is dropped and the
    update starts again as before convergence (raw readings until the state is sure again), their mean from the next."""
    q = state.q_strapdown if rotation is None else quat.normalize(quat.multiply(state.q_strapdown, rotation))
    broken = gap_s > 0.0  # the raw readings' mean too, converged or not
    return GravityState(q_strapdown=q, accel_lp_m_s2=None if broken else state.accel_lp_m_s2, down_body=state.down_body,
                        converged=not broken and state.converged, tilt_known=state.tilt_known, gated_s=state.gated_s,
                        raw_mean_m_s2=None if broken else state.raw_mean_m_s2, raw_s=0.0 if broken else state.raw_s,
                        measured_body=state.measured_body, gnss_checked=state.gnss_checked, measured_world=state.measured_world)


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
                   tau_s: float, predicted_q: np.ndarray, interval_s: float, heading_measured: bool = True,
                   gnss: GnssWorld | None = None) -> GravityReading:
    """The gravity update of one tick from the tick's mean specific force in the state's body frame, the
    readings ``interval_s`` after the previous ones. The state
    has converged once its doubt is below ``updates.converged_deg``: the whole doubt's, or without a heading
    measurement (6-D: the magnetometer off) the tilt's, as the heading is never known and the raw readings would
    be taken for ever. ``gnss`` (:func:`fuser.model.velocity.raw_world`) what a raw reading measures in the world
    while GNSS fixes come, ``g e_z - a`` (module docstring). In plain floats (:mod:`fuser.model.vec3`)."""
    g = params.gravity_m_s2
    gnss_world = None if gnss is None else vec3.floats(gnss.vector_m_s2)
    fast_sigma = fast_start_sigma_rad(updates, params.sigma_rad, interval_s)
    raw_sigma = fast_sigma if gnss is None or gnss_world is None else math.hypot(fast_sigma, gnss.noise_m_s2 / vec3.norm(gnss_world))
    to_inertial = vec3.rotation_rows(state.q_strapdown)
    accel = vec3.floats(accel_body_m_s2)
    f_inertial = vec3.mat_vec(to_inertial, accel)
    rotation = vec3.rotation_rows(predicted_q)  # body -> NED
    predicted_down = rotation[2]  # R^T e_z: world down in the body
    # once, at the first GNSS acceleration: what the state measured before it took every raw reading for down
    restart = gnss_world is not None and not state.gnss_checked and state.tilt_known and _disagrees(
        raw_sigma, updates, tick.prior_tilt_doubt_deg, vec3.mat_vec(rotation, (-accel[0], -accel[1], -accel[2])), gnss_world)
    # a restart: converged on raw readings the GNSS acceleration shows wrong (a start in a turn), the fast start again
    accel_lp = None if restart else state.accel_lp_m_s2
    raw_mean, raw_s = (None, 0.0) if restart else (state.raw_mean_m_s2, state.raw_s)
    gnss_checked = state.gnss_checked or gnss_world is not None
    doubt_deg = tick.prior_doubt_deg if heading_measured else tick.prior_tilt_doubt_deg
    converged = not restart and (state.converged or doubt_deg < updates.converged_deg)
    if not converged:
        lowpassed = None
    else:
        # the low-pass starts from what the estimate followed (the raw readings' mean), or from the estimate itself
        if accel_lp is not None:
            start = vec3.floats(accel_lp)
        elif raw_mean is None:
            start = vec3.mat_vec(to_inertial, (-g * predicted_down[0], -g * predicted_down[1], -g * predicted_down[2]))
        else:
            start = vec3.floats(raw_mean)
        lowpassed = vec3.toward(start, f_inertial, min(1.0, interval_s / tau_s))
        raw_mean, raw_s = None, 0.0
    # a raw reading with the GNSS acceleration taken out measures g e_z - a; every other, down
    gnss_raw = lowpassed is None and gnss_world is not None
    if gnss_raw:
        world_norm = vec3.norm(gnss_world)  # type: ignore[arg-type]
        world_unit = (gnss_world[0] / world_norm, gnss_world[1] / world_norm, gnss_world[2] / world_norm)  # type: ignore[index]
    else:
        world_norm, world_unit = g, _DOWN
    measured = f_inertial if lowpassed is None else lowpassed
    norm = vec3.norm(measured)
    norm_error = abs(norm - world_norm) / g
    lowpassed_m_s2 = None if lowpassed is None else np.array(lowpassed)
    if norm_error > params.norm_gate_fraction:
        kept = GravityState(q_strapdown=state.q_strapdown, accel_lp_m_s2=lowpassed_m_s2, down_body=state.down_body, converged=converged,
                            tilt_known=state.tilt_known, gated_s=state.gated_s, raw_mean_m_s2=raw_mean, raw_s=raw_s,
                            measured_body=state.measured_body, gnss_checked=gnss_checked, measured_world=state.measured_world)
        return GravityReading(kept, None, False, False, UpdateDiagnostic.of("gravity", "gated", "norm"), restart=restart)
    filtered_body = vec3.vec_mat(measured, to_inertial)
    down = (-filtered_body[0] / norm, -filtered_body[1] / norm, -filtered_body[2] / norm)
    if converged:  # Q = q T / dt over the interval T
        sigma = math.sqrt(tick.process_variance_rad2 * interval_s / tick.dt_s) * tau_s / max(interval_s, 1e-6)
        # gated against what the low-passed down may be off by: the sigma above sets the correction's gain (T / tau),
        # not the reading's error, and grows as 1 / sqrt(T) (module docstring)
        gate_sigma = min(sigma, math.radians(params.lowpass_error_deg))
    else:
        sigma = gate_sigma = raw_sigma if gnss_raw else fast_sigma
    innovation = vec3.angle_rad(vec3.dot(vec3.mat_vec(rotation, down), world_unit))
    verdict = innovation_gate(updates, state.gated_s, innovation, gate_sigma, tick.prior_doubt_deg, tick.dt_s)
    # nothing to gate against before the first tilt, nor in a fast start the GNSS acceleration called for
    outcome, gated_s = (verdict.outcome, verdict.gated_s) if state.tilt_known and not restart else ("fused", state.gated_s)
    diagnostic = UpdateDiagnostic.of("gravity", outcome, "innovation" if outcome == "gated" else "", innovation, sigma, verdict.test_ratio,
                                     _GNSS_RAW if gnss_raw else ())
    fused = outcome != "gated"
    if fused and lowpassed is None and not gnss_raw:  # a raw reading the estimate follows as down, into their mean
        raw_s = raw_s + interval_s
        raw_mean = np.array(f_inertial if raw_mean is None else vec3.toward(vec3.floats(raw_mean), f_inertial, interval_s / raw_s))
    down_body, measured_world = np.array(down), np.array(world_unit) if gnss_raw else _DOWN_NED_READ_ONLY
    after = GravityState(q_strapdown=state.q_strapdown, accel_lp_m_s2=lowpassed_m_s2, down_body=down_body, converged=converged,
                         tilt_known=state.tilt_known or fused, gated_s=gated_s, raw_mean_m_s2=raw_mean, raw_s=raw_s, measured_body=down_body,
                         gnss_checked=gnss_checked, measured_world=measured_world)
    if not fused:
        return GravityReading(after, None, False, False, diagnostic, restart=restart)
    trusted = converged and norm_error < 0.5 * params.norm_gate_fraction
    return GravityReading(after, vector_exponent(down_body, measured_world, sigma),
                          not state.tilt_known or restart, trusted, diagnostic, restart=restart)


def _disagrees(sigma_rad: float, updates: UpdateSettings, prior_tilt_deg: float, predicted_world: Vec3,
               gnss_world_m_s2: Vec3) -> bool:
    """The raw reading, seen in the world through the prediction, is further from ``g e_z - a`` than the innovation
    gate allows a raw reading (``sigma_rad``, ``accel.sigma_rad`` with the GNSS acceleration's noise, and the state's
    tilt doubt: its heading's does not count)."""
    cos = vec3.dot(predicted_world, gnss_world_m_s2) / (vec3.norm(predicted_world) * vec3.norm(gnss_world_m_s2))
    gate = updates.innovation_gate_sigma * math.hypot(sigma_rad, math.radians(prior_tilt_deg))
    return vec3.angle_rad(cos) > gate
