"""The gravity update: the accelerometer, low-passed in a near-inertial frame, as a direction of down.

Every reading is rotated into an inertial frame by the gyro-only strapdown
attitude (never corrected, so the frame holds still while the estimate is
corrected) and low-passed there, as VQF's inclination correction does (tauAcc): linear and
centripetal accelerations average out over the tilt time constant, gravity
does not, and rotation does not smear the filter. The filtered vector, seen
in the current body frame, is the measurement of down, an exact Bingham
likelihood in the attitude (Davenport's K,
:func:`core.observations.vector_exponent`, compiled as ``_davenport``; unscented paper, sec. IV-B).

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
direction, not gravity's. Such readings are checked against the state built
before them, from readings all taken for down, the first one and each after
it until the state has converged: beyond the gate (a start in a turn, the
bank's vertical) the fast start runs again (``restart``: the state's tilt and
heading widened, unconverged, the magnetometer a whole vector,
:mod:`fuser.model.heading`). Not the first alone: its GNSS acceleration, one
pair's, is the noisiest (started 31 s into the JSBSim Cessna's 30-deg turn it
disagreed by 27.2 deg against a gate of 27.6, the state converged 24 deg off
in tilt and stayed 20 deg RMS off for the flight's 29 s while reporting 4.8);
the next pairs' low-passed acceleration shows the turn before the state has
converged (1.8 deg RMS).

**Disputed.** A reading kept out by the gate says that the state or the reading is wrong, and the model cannot
tell which: a linear acceleration the low-pass left, or a state the gyro took away (a bias that appeared in
flight). Until a reading agrees again, the published tilt covers the one kept out: its innovation, per axis, when
larger than what the unaided accounts already publish (``disputed_rad``; :func:`fuser.model.fusion.tick`). The
aided update's readings are fused with a gain far wider than their own error, so one further from the state than
that error (the low-pass's residue and the GNSS acceleration's noise) and the state's tilt doubt allow disputes
the state though it is fused. A 0.05 rad/s x bias appearing at 4 s in the simulated hover without GNSS: over twice
the reported uncertainty on 32.8 % of the estimates before, 14.9 % after (``tests/test_fuser_admitted_faults.py``).
The state itself is not widened when a gated reading is re-anchored: tried, it made the state follow the false
vertical of sustained turns (the JSBSim Cessna without GNSS 11.1 -> 30.8 deg RMS, the aggressive multirotor
3.4 -> 5.4), even where the norm's account of the acceleration was taken out first. With GNSS the aided readings
cannot show a bias that appeared in flight (their body side is low-passed in the frame the biased gyro turns); the
fixes' residuals against the state can, and are read the same way (:mod:`fuser.model.velocity_check`).

While GNSS velocity aids it, the velocity-aided variant beside this one
(:func:`fuser.model.velocity.update_gravity_aided`: the world acceleration
from GNSS velocity taken out of the specific force, both low-passed alike)
gives the :class:`~fuser.model.tick.GravityReading` instead.

Compiled (numba) for the tick (:mod:`fuser.model.fusion`): the memory is the
``gravity`` part of the state record (:data:`fuser.model.state.GRAVITY`),
changed in place; vectors are tuples (:mod:`fuser.model.vec3`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.observations import _davenport
from core.quaternion_kernels import from_array, multiply, normalize, rotation_rows
from fuser.model import diagnostics, vec3
from fuser.model.diagnostics import AIDED_RAW, FUSED, GATED, GRAVITY, INNOVATION, NO_REASON, NORM, NOT_AIDED
from fuser.model.gate import fast_start_sigma_rad, innovation_gate
from fuser.model.tick import GravityReading, TickContext

__all__ = ["DOWN_NED", "drop_lp", "no_reading", "tilt_time_constant_s", "turn_frame", "update_gravity"]

DOWN_NED = (0.0, 0.0, 1.0)
"""World down in NED: the reference direction of the gravity measurement (a frame convention, not a tuning)."""


@njit(cache=True, nogil=True, inline="always")  # inlined: called with literal flags and with variables
def _store_lp(gravity: np.record, has_lp: bool, lp_m_s2: tuple, has_raw_mean: bool, raw_mean_m_s2: tuple, raw_s: float) -> None:
    """The low-pass and the raw readings' mean into ``gravity`` (zeros where absent)."""
    gravity.has_accel_lp = has_lp
    vec3.store(gravity.accel_lp_m_s2, lp_m_s2 if has_lp else vec3.ZERO)
    gravity.has_raw_mean = has_raw_mean
    vec3.store(gravity.raw_mean_m_s2, raw_mean_m_s2 if has_raw_mean else vec3.ZERO)
    gravity.raw_s = raw_s


@njit(cache=True, nogil=True, inline="always")  # inlined: two lines, called from two modules' updates
def drop_lp(gravity: np.record) -> None:
    """The low-pass and the raw readings' mean dropped (a gyro gap; the GNSS-aided update running instead)."""
    _store_lp(gravity, False, vec3.ZERO, False, vec3.ZERO, 0.0)


@njit(cache=True, nogil=True)
def turn_frame(gravity: np.record, has_rotation: bool, rotation: tuple, gap_s: float) -> None:
    """The strapdown frame after the tick's gyro rotation (``has_rotation`` False: none known), in place. A gap in
    the gyro (``gap_s`` of the tick without a rate) breaks the frame: the body turned by an unknown rotation, so the
    low-pass's memory is dropped and the update starts again as before convergence (raw readings until the state is
    sure again), their mean from the next."""
    if has_rotation:
        q = normalize(multiply(from_array(gravity.q_strapdown), rotation))
        for i in range(4):
            gravity.q_strapdown[i] = q[i]
    if gap_s > 0.0:  # the raw readings' mean too, converged or not
        drop_lp(gravity)
        gravity.converged = False


@njit(cache=True, nogil=True)
def tilt_time_constant_s(params: np.record, bias: np.record, bias_variance_rad2_s2: float) -> float:
    """Tilt-correction (and low-pass) time constant for the current bias uncertainty (``params`` the ``accel``
    group, ``bias`` the ``bias`` group of :mod:`fuser.model.params`).

    A residual bias ``b`` makes the tilt lag by ``b tau`` behind a correction
    loop of time constant ``tau``; a longer ``tau`` lets less linear
    acceleration through. So ``tau = tilt_bias_error / sigma_b``, capped at
    ``lowpass_s``: fast while the bias is unknown (a cold start, a
    multirotor's 1 deg/s bias), VQF's slow 3 s once learnt.
    """
    return min(params.lowpass_s, math.radians(params.tilt_bias_error_deg) / math.sqrt(max(bias_variance_rad2_s2, bias.min_variance_rad2_s2)))


@njit(cache=True, nogil=True)
def no_reading() -> GravityReading:
    """No gravity reading this tick (no IMU sample): nothing fused, no diagnostic."""
    return GravityReading(False, np.zeros((4, 4)), False, False, diagnostics.none(), False, 0.0, False)


@njit(cache=True, nogil=True, inline="always")  # inlined: called with literal flags and with variables
def _reading(fused: bool, exponent: np.ndarray, apply_now: bool, trusted: bool, diagnostic: diagnostics.Diagnostic,
             restart: bool) -> GravityReading:
    """A plain update's reading (no tilt bound: that is the GNSS-aided one's)."""
    return GravityReading(fused, exponent, apply_now, trusted, diagnostic, False, 0.0, restart)


@njit(cache=True, nogil=True)
def update_gravity(params: np.record, updates: np.record, gravity: np.record, tick: TickContext, accel_body_m_s2: tuple,
                   tau_s: float, predicted_q: tuple, interval_s: float, heading_measured: bool, has_gnss_world: bool,
                   gnss_world_m_s2: tuple, gnss_noise_m_s2: float) -> GravityReading:
    """The gravity update of one tick from the tick's mean specific force in the state's body frame, the
    readings ``interval_s`` after the previous ones; ``gravity`` (the state's part) changed in place, ``params`` and
    ``updates`` the ``accel`` and ``updates`` groups. The state
    has converged once its doubt is below ``updates.converged_deg``: the whole doubt's, or without a heading
    measurement (6-D: the magnetometer off) the tilt's, as the heading is never known and the raw readings would
    be taken for ever. ``has_gnss_world``: GNSS fixes come (:func:`fuser.model.velocity.raw_world`), and a raw reading
    measures ``gnss_world_m_s2`` = ``g e_z - a`` in the world (module docstring), ``a``'s noise ``gnss_noise_m_s2``
    per axis."""
    g = params.gravity_m_s2
    fast_sigma = fast_start_sigma_rad(updates, params.sigma_rad, interval_s)
    raw_sigma = math.hypot(fast_sigma, gnss_noise_m_s2 / vec3.norm(gnss_world_m_s2)) if has_gnss_world else fast_sigma
    to_inertial = rotation_rows(from_array(gravity.q_strapdown))
    accel = accel_body_m_s2
    f_inertial = vec3.mat_vec(to_inertial, accel)
    rotation = rotation_rows(predicted_q)  # body -> NED
    predicted_down = rotation[2]  # R^T e_z: world down in the body
    # from the first GNSS acceleration until converged: what the state measured before it took every raw reading for down
    restart = (has_gnss_world and (not gravity.gnss_checked or not gravity.converged) and gravity.tilt_known
               and _disagrees(raw_sigma, updates, tick.prior_tilt_doubt_deg, vec3.mat_vec(rotation, (-accel[0], -accel[1], -accel[2])),
                              gnss_world_m_s2))
    # a restart: converged on raw readings the GNSS acceleration shows wrong (a start in a turn), the fast start again
    has_lp = gravity.has_accel_lp and not restart
    has_raw_mean = gravity.has_raw_mean and not restart
    raw_mean = vec3.load(gravity.raw_mean_m_s2)
    raw_s = 0.0 if restart else gravity.raw_s
    gnss_checked = gravity.gnss_checked or has_gnss_world
    doubt_deg = tick.prior_doubt_deg if heading_measured else tick.prior_tilt_doubt_deg
    converged = not restart and (gravity.converged or doubt_deg < updates.converged_deg)
    lowpassed = vec3.ZERO
    if converged:
        # the low-pass starts from what the estimate followed (the raw readings' mean), or from the estimate itself
        if has_lp:
            start = vec3.load(gravity.accel_lp_m_s2)
        elif not has_raw_mean:
            start = vec3.mat_vec(to_inertial, (-g * predicted_down[0], -g * predicted_down[1], -g * predicted_down[2]))
        else:
            start = raw_mean
        lowpassed = vec3.toward(start, f_inertial, min(1.0, interval_s / tau_s))
        has_raw_mean, raw_mean, raw_s = False, vec3.ZERO, 0.0
    # a raw reading with the GNSS acceleration taken out measures g e_z - a; every other, down
    gnss_raw = not converged and has_gnss_world
    if gnss_raw:
        world_norm = vec3.norm(gnss_world_m_s2)
        world_unit = (gnss_world_m_s2[0] / world_norm, gnss_world_m_s2[1] / world_norm, gnss_world_m_s2[2] / world_norm)
    else:
        world_norm, world_unit = g, DOWN_NED
    measured = lowpassed if converged else f_inertial
    norm = vec3.norm(measured)
    norm_error = abs(norm - world_norm) / g
    if norm_error > params.norm_gate_fraction:
        _store_lp(gravity, converged, lowpassed, has_raw_mean, raw_mean, raw_s)
        gravity.converged, gravity.gnss_checked = converged, gnss_checked
        nan = math.nan
        return _reading(False, np.zeros((4, 4)), False, False, diagnostics.of(GRAVITY, GATED, NORM, nan, nan, nan, NOT_AIDED), restart)
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
    verdict = innovation_gate(updates, gravity.gated_s, innovation, gate_sigma, tick.prior_doubt_deg, tick.dt_s)
    # nothing to gate against before the first tilt, nor in a fast start the GNSS acceleration called for
    tilt_known = gravity.tilt_known
    if tilt_known and not restart:
        outcome, gated_s = verdict.outcome, verdict.gated_s
    else:
        outcome, gated_s = FUSED, gravity.gated_s
    # a reading kept out further from the state than its own error allows: the state, not it, may be what is wrong
    gravity.disputed_rad = innovation if outcome == GATED else 0.0
    diagnostic = diagnostics.of(GRAVITY, outcome, INNOVATION if outcome == GATED else NO_REASON, innovation, sigma, verdict.test_ratio,
                                AIDED_RAW if gnss_raw else NOT_AIDED)
    fused = outcome != GATED
    if fused and not converged and not gnss_raw:  # a raw reading the estimate follows as down, into their mean
        raw_s = raw_s + interval_s
        raw_mean = vec3.toward(raw_mean, f_inertial, interval_s / raw_s) if has_raw_mean else f_inertial
        has_raw_mean = True
    measured_world = world_unit if gnss_raw else DOWN_NED
    _store_lp(gravity, converged, lowpassed, has_raw_mean, raw_mean, raw_s)
    vec3.store(gravity.down_body, down)
    vec3.store(gravity.measured_body, down)
    vec3.store(gravity.measured_world, measured_world)
    gravity.converged, gravity.tilt_known, gravity.gated_s, gravity.gnss_checked = converged, tilt_known or fused, gated_s, gnss_checked
    if not fused:
        return _reading(False, np.zeros((4, 4)), False, False, diagnostic, restart)
    trusted = converged and norm_error < 0.5 * params.norm_gate_fraction
    exponent = _davenport(np.array(down), np.array(measured_world), sigma) if sigma > 0.0 else None
    if exponent is None:  # not a likelihood (a unit down, a unit world direction and a positive sigma always are)
        return _reading(False, np.zeros((4, 4)), False, False, diagnostic, restart)
    return _reading(True, np.asarray(exponent), not tilt_known or restart, trusted, diagnostic, restart)


@njit(cache=True, nogil=True)
def _disagrees(sigma_rad: float, updates: np.record, prior_tilt_deg: float, predicted_world: tuple, gnss_world_m_s2: tuple) -> bool:
    """The raw reading, seen in the world through the prediction, is further from ``g e_z - a`` than the innovation
    gate allows a raw reading (``sigma_rad``, ``accel.sigma_rad`` with the GNSS acceleration's noise, and the state's
    tilt doubt: its heading's does not count). A reading or an acceleration without a direction (a norm that
    underflows to 0) shows no disagreement."""
    norms = vec3.norm(predicted_world) * vec3.norm(gnss_world_m_s2)
    if not norms > 0.0:
        return False
    cos = vec3.dot(predicted_world, gnss_world_m_s2) / norms
    gate = updates.innovation_gate_sigma * math.hypot(sigma_rad, math.radians(prior_tilt_deg))
    return vec3.angle_rad(cos) > gate
