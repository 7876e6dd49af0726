"""GNSS velocity aiding: the vehicle's acceleration, from GNSS velocity, taken out of the specific force.

The plain gravity update (:mod:`fuser.model.gravity`) takes the low-passed
specific force for the reaction to gravity: right on average while the
vehicle does not keep accelerating, wrong in a sustained turn, where the
accelerometer reads the lift (1.15-1.41 g along the body's -z at 30-45 deg
of bank), never gravity. GNSS velocity gives the acceleration ``a`` over
ground, and ``f = a - g e_z`` (NED, ``e_z`` down): gravity is ``a - f``.
This is how ArduPilot's DCM uses GPS velocity
(``AP_AHRS_DCM::drift_correction``: the earth-frame accelerometer summed
over the interval between two GPS velocities, ``_ra_sum``, against their
difference over that interval, with the sum delayed by ``ra_delayed`` to
match the GPS lag); here as a Bingham likelihood beside the plain update.

**Pairs, and the latency.** A fix is placed on the loop's timeline at its
arrival; its velocity was measured ``gnss.latency_ms`` earlier
(``gnss.filtered_latency_ms`` for an autopilot's navigation solution).
Two consecutive fixes of a stream, measured at ``m0 < m1``, give the mean
world acceleration over ``(m0, m1]``: ``a = (v1 - v0) / (m1 - m0)``. The
accelerometer path is *delayed* to the same interval: the tick's mean
specific force, turned into the gyro-only strapdown frame S, is integrated
(``F(t) = int f_S dt``, kept ``max_age_s`` plus the latency back), and
``f = (F(m1) - F(m0)) / (m1 - m0)`` is its mean over exactly the GNSS
interval. Delayed rather than predicted: both sides are then the same box
average over the same interval, exactly consistent when the latency is
configured right, and nothing is extrapolated. That the correction
concerns the attitude of ``latency`` ago costs nothing: a direction fixed
in S is fixed in the world, so the low-passed measurement, seen in today's
body frame through today's strapdown attitude, is valid now.

**The low-pass.** Both sides of every pair go through the same first-order
low-pass, VQF's inclination correction (D. Laidig, T. Seel, Information
Fusion 91, 2023; ``updateAcc`` in dlaidig/vqf's ``vqf/pyvqf.py``: the
specific force low-passed in the almost-inertial frame with ``tauAcc``),
with one ``alpha = min(1, (m1 - m0) / tau)`` and the gravity update's
``tau``: the body side in S (``lp_S(-f)``), the world side in NED
(``lp(g e_z - a)``). The stated approximation: S turns against the world
only by the residual gyro bias (0.01 deg over 3 s for a bias learnt to
0.2 deg/min; the earth's rotation, 7e-5 rad/s, is neglected as everywhere in
the fuser), so over the low-pass window ``R_NS lp_S(f) = lp(R_NS f_S) =
lp(a) - g e_z``. Nothing is rotated by the *estimate*: the measurement is
the exact vector observation "the body vector ``b = R_SB^T lp_S(-f)`` is the
world vector ``w = lp(g e_z - a)``" (Davenport's K,
:func:`core.observations.vector_exponent`, compiled as ``_davenport``), which in a turn (``w`` not
vertical) also informs the heading, as it physically does; rotating ``a``
into S by the estimate instead would turn every heading error ``psi`` into
a tilt error ``psi |a_h| / g``.

**Horizontal-only velocity** (GPS_RAW_INT: ground speed and course). The
vertical acceleration is then unknown, and nothing is assumed about it:
only the horizontal components are measured. The world vector's down
component is taken from the body vector as the estimate sees it (``w_d =
(R_est b)_d``), so the innovation is the horizontal mismatch alone, ``g
delta`` for a tilt error ``delta`` and ``psi |a_h|`` for a heading error
``psi``. Taking the low-passed vertical acceleration for zero instead (the
plain update's assumption) cost 3-6 deg in the JSBSim flight's turns, whose
altitude hold pulls 0.3-0.7 m/s^2 up and down for seconds: in a turn a
vertical error ``e`` tilts ``w`` by ``e |a_h| / (g^2 + |a_h|^2)``, 2.8 deg
per m/s^2 at 35 deg of bank. The cost of measuring the horizontal only: a
climb costs nothing, but the vertical plane's information (the tilt error's
``delta x a_h`` along down, in a turn) is not used, and a vertical fault of
the accelerometer is not seen by the norm check. A stream with vertical
velocity is preferred when there is one.

**Sigma.** The gravity update's correction-time sigma (``sigma^2 = Q
(tau/T)^2``, :mod:`fuser.model.gravity`) plus the GNSS velocity noise
differentiated and low-passed: white noise ``s`` per axis (the receiver's
speed accuracy where the message has one, else ``gnss.velocity_noise_m_s``)
differenced over ``T`` and low-passed, ``y = (1 - alpha) y + (alpha / T)(n1 -
n0)``, whose variance is propagated with the covariance two differences
sharing a fix have (they telescope: in the steady state ``2 s^2 / (tau^2 (2 -
alpha))``, a tenth of the raw difference's at 10 Hz and ``tau`` = 3 s); its
direction error, that over ``|w|``, is correlated over ``tau`` and so
counted once per ``tau`` (``sqrt(tau / T)`` per reading, as the
magnetometer's correlated error is). The low-pass starts from the first
pair itself, raw noise and all (not from the estimate: after an outage in a
turn the estimate is what is wrong), and is the running mean of the pairs
until they span ``tau``, as VQF starts its low-passes: the differenced noise
then falls as ``1 / n`` (the differences telescope), where the first pair
taken whole with the low-pass's own ``alpha`` kept ``(1 - alpha)^n`` of it
(after 5 pairs at ``tau`` = 1.3 s, 0.67 of the first pair's 8 deg, against a
fifth). Those first readings counted for so little that the simulated hover
of seed 3, whose 1.5 deg/s bias was not yet learnt, drifted from 3 to 6 deg
of tilt in the aiding's first second and started 9.6-9.9 deg off while
reporting 4.1-4.4 (2-3 s); with the running mean 7.8-7.9 reporting 4.3-5.6.

**Noise.** A receiver's speed accuracy is its own claim, and the claim can
be low: in multipath, or from a receiver that reports none at all
(``gnss.velocity_noise_m_s`` then stands in). Fused as claimed, white
velocity noise of 0.25 m/s under a claim of 0.1 took the simulated
multirotor 2.6-8.1 deg off while it reported 3.4-4.2 (eight noise seeds;
with the check 0.9-1.9 deg on six, tests/test_fuser_gnss_noise.py). PX4's
EKF2 and ArduPilot's EKF3 only floor the claim (``EKF2_GPS_V_NOISE``,
``EK3_VELNE_M_NSE``); here the fixes themselves are
checked, as covariance matching does (R. K. Mehra, "On the identification
of variances and adaptive Kalman filtering", IEEE TAC 15(2), 1970): each
pair's velocity residual against the accelerometer over the same interval,
``e_k = (v_k - v_(k-1)) - f_k T_k`` (``f`` rotated by the estimate, as in
the jump check below), changes from one pair to the next by ``n_k - 2
n_(k-1) + n_(k-2)`` for white per-fix noise ``n`` (variance ``6 s^2`` per
axis), while what persists over a pair's spacing (an attitude error, the
accelerometer's bias, a steady acceleration the latency misplaces) cancels.
The mean square of that change over about ``gnss.noise_window_s``, over six,
is the noise the stream shows; a pair is weighed with the claim or that,
whichever is larger (``velocity_noise_m_s`` in its diagnostic). After a
gap the residuals' chain starts again; the noise measured so far is kept.

**Checked.** The jump check's residual of each pair below shows how far
the state is off, which this reading cannot (its body side drifts with a
gyro bias along with the state): :mod:`fuser.model.velocity_check`.

**Faults**, each in the ``velocity`` diagnostics and counted: a message
without a fix (``no_fix``); a receiver repeating its last solution
(``stale``: the same velocity again; the next new fix pairs with the last
new one, over the longer interval, still a valid mean); a fix whose
acceleration differs from the accelerometer's (``R_est R_SB^T f + g e_z``)
by more than ``gnss.gate_sigma`` sigma (``jump``; sigma from the velocity
noise differenced, the estimate's uncertainty times ``|f|`` and
``gnss.accel_error_m_s2``: kept out of the low-pass, the chain goes on from
it); a fix more than ``max_age_s`` after the stream's previous one or
before the accelerometer's history (``gap``: nothing to difference it
with). A stream that stops: once the last pair is ``max_age_s`` old the
aiding ends (``gnss_lost``), its low-pass is dropped and the plain gravity
update takes over from the estimate, until pairs come again.

**The state** is the ``velocity`` part of the model's record
(:data:`fuser.model.state.VELOCITY`), changed in place here. Each stream,
(source, filtered), has a slot (``GNSS_INPUT.slot``, given by the model's
Python side, which also ranks the slots by (filtered, source) in
``stream_rank``: the order of the stream selection); a slot holds the
stream's last new fix once it has had one (``stream_seen``). The
accelerometer's history is a ring of knots beside the record
(``knots_ns``, ``knots``: the integral and the tick's force), from
``knots_first``, ``knots_count`` long; its capacity
(:func:`fuser.model.state.knot_capacity`) holds ``max_age_s`` plus the
latency at the loop's rate, and should it ever fill the oldest knot goes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.bingham_kernels import down_alignment_sq
from core.observations import _davenport
from core.quaternion_kernels import from_array, rotation_rows
from fuser.model import pair_lowpass, vec3, velocity_check
from fuser.model.diagnostics import (AIDED_3D, AIDED_HORIZONTAL, FUSED, GAP, GATED, GRAVITY, INNOVATION, JUMP, NO_FIX, NO_REASON, NORM,
                                     NOT_AIDED, STALE, UNCONVERGED, UNSELECTED, VELOCITY, Diagnostic, emit, none, of)
from fuser.model.gate import gate_rad, innovation_gate
from fuser.model.gravity import drop_lp, no_reading
from fuser.model.tick import GravityReading, TickContext, VelocityTrack

__all__ = ["raw_world", "tilt_doubt_deg", "track_velocity", "update_gravity_aided"]

FIX_2D = 2
"""MAVLink GPS_FIX_TYPE of the first fix that carries a velocity."""


@njit(cache=True, nogil=True)
def tilt_doubt_deg(M: np.ndarray, moments: np.ndarray) -> float:
    """RMS tilt error of a Bingham (its uncertainty about the horizontal axes only, degrees), from its ``M`` and
    its moments ``E[(M^T x)_i^2]``.

    Along principal direction ``m_i`` the body-frame rotation error has variance ``4 E[(m_i . x)^2]`` (the vector
    part of a small rotation is half its angle) about the body axis ``vec(mode^* m_i)``; its tilt share is
    ``1 - cos^2`` of that axis with world down seen in the body, ``cos = m_i . (k mode)`` (as in
    :func:`fuser.model_error.widened_concentrations`). A heading still unknown (6-D, a cold start) does not count.
    """
    return math.degrees(math.sqrt(max(_tilt_variance(M, moments), 0.0)))


@njit(cache=True, nogil=True)
def _tilt_variance(M: np.ndarray, moments: np.ndarray) -> float:
    """``sum_i 4 E[(m_i . x)^2] (1 - cos_i^2)`` over the three dispersion directions (:func:`tilt_doubt_deg`)."""
    along_down = down_alignment_sq(M)
    variance = 0.0
    for i in range(3):
        variance += 4.0 * moments[i] * (1.0 - min(along_down[i], 1.0))
    return variance


@njit(cache=True, nogil=True)
def _force_at(state: np.record, knots_ns: np.ndarray, knots: np.ndarray, t_ns: int) -> tuple:
    """(inside, integral): the integrated specific force at ``t_ns`` (linear between knots); not inside the
    history: False (and zeros). The ring's knots in time order, bisected (``bisect_left``)."""
    count = state.knots_count
    if count == 0:
        return False, vec3.ZERO
    capacity, first = knots_ns.shape[0], state.knots_first
    if t_ns < knots_ns[first] or t_ns > knots_ns[(first + count - 1) % capacity]:
        return False, vec3.ZERO
    lo, hi = 0, count
    while lo < hi:
        mid = (lo + hi) // 2
        if knots_ns[(first + mid) % capacity] < t_ns:
            lo = mid + 1
        else:
            hi = mid
    j = (first + lo) % capacity
    t1, f1 = knots_ns[j], (knots[j, 0], knots[j, 1], knots[j, 2])
    if t1 == t_ns or lo == 0:
        return True, f1
    k = (first + lo - 1) % capacity
    t0, f0 = knots_ns[k], (knots[k, 0], knots[k, 1], knots[k, 2])
    return True, vec3.toward(f0, f1, (t_ns - t0) / (t1 - t0))


@njit(cache=True, nogil=True)
def _knots(params: np.record, state: np.record, knots_ns: np.ndarray, knots: np.ndarray, has_force: bool, force_s_m_s2: tuple,
           tick_ns: int, dt_ns: int, broken: bool) -> None:
    """The accelerometer's history after this tick, in place: its mean specific force in S (held without a
    sample), integrated; dropped when the strapdown frame broke (a gyro gap: the frame before is not this one)."""
    capacity = knots_ns.shape[0]
    count = 0 if broken else state.knots_count
    if count == 0:
        fx, fy, fz = force_s_m_s2 if has_force else vec3.ZERO
        step_s = dt_ns * 1e-9
        knots_ns[0], knots_ns[1] = tick_ns - dt_ns, tick_ns
        knots[0, 0], knots[0, 1], knots[0, 2], knots[0, 3], knots[0, 4], knots[0, 5] = 0.0, 0.0, 0.0, fx, fy, fz
        knots[1, 0], knots[1, 1], knots[1, 2], knots[1, 3], knots[1, 4], knots[1, 5] = fx * step_s, fy * step_s, fz * step_s, fx, fy, fz
        state.knots_first, state.knots_count = 0, 2
        return
    first = state.knots_first
    last = (first + count - 1) % capacity
    last_ns = knots_ns[last]
    integral = (knots[last, 0], knots[last, 1], knots[last, 2])
    force = force_s_m_s2 if has_force else (knots[last, 3], knots[last, 4], knots[last, 5])
    horizon_ns = tick_ns - pair_lowpass.max_age_with_latency_ns(params) - 2 * dt_ns
    # the first knot kept is the last one before the horizon (the horizon moves a tick per tick: a step or two)
    dropped = 0
    while dropped + 1 < count and knots_ns[(first + dropped + 1) % capacity] < horizon_ns:
        dropped += 1
    first, count = (first + dropped) % capacity, count - dropped
    if count == capacity:  # full (knot_capacity is meant to prevent it): the oldest goes
        first, count = (first + 1) % capacity, count - 1
    step_s = (tick_ns - last_ns) * 1e-9
    fx, fy, fz = force
    ix, iy, iz = integral
    k = (first + count) % capacity
    knots_ns[k] = tick_ns
    knots[k, 0], knots[k, 1], knots[k, 2] = ix + fx * step_s, iy + fy * step_s, iz + fz * step_s
    knots[k, 3], knots[k, 4], knots[k, 5] = fx, fy, fz
    state.knots_first, state.knots_count = first, count + 1


@njit(cache=True, nogil=True)
def _measure_noise(params: np.record, state: np.record, slot: int, difference: tuple, span_s: float, vertical: bool) -> None:
    """Average what the stream's pairs show of its velocity noise (module docstring, "Noise"): the change of the
    velocity residual ``e = (v1 - v0) - f span`` from the previous pair's, whose mean square per axis is six times the
    noise variance of white per-fix noise, while what stays from one pair to the next (an attitude error, the
    accelerometer's bias) cancels."""
    residual = (difference[0] * span_s, difference[1] * span_s, difference[2] * span_s)
    if state.stream_has_residual[slot]:
        dx = residual[0] - state.stream_residual_m_s[slot, 0]
        dy = residual[1] - state.stream_residual_m_s[slot, 1]
        square, axes = dx * dx + dy * dy, 2.0
        if vertical and state.stream_residual_vertical[slot]:
            dz = residual[2] - state.stream_residual_m_s[slot, 2]
            square, axes = square + dz * dz, 3.0
        count = min(state.stream_residual_count[slot] + 1, 1_000_000)
        weight = max(1.0 / count, min(1.0, span_s / params.noise_window_s))
        state.stream_residual_count[slot] = count
        state.stream_measured_var_m2_s2[slot] += weight * (square / (6.0 * axes) - state.stream_measured_var_m2_s2[slot])
    state.stream_has_residual[slot] = True
    state.stream_residual_vertical[slot] = vertical
    state.stream_residual_m_s[slot, 0], state.stream_residual_m_s[slot, 1], state.stream_residual_m_s[slot, 2] = residual


@njit(cache=True, nogil=True)
def _selected(state: np.record, now_measured_ns: int, max_age_ns: int) -> int:
    """The slot of the stream whose pairs aid: among those with a fix within ``max_age``, one with vertical velocity
    first, then a receiver's fix before an autopilot's solution, then the lowest source (``stream_rank``: a
    total, stable order); -1: none."""
    best, best_flat, best_rank = -1, True, 0
    for k in range(state.stream_seen.shape[0]):
        if not state.stream_seen[k] or now_measured_ns - state.stream_measured_ns[k] > max_age_ns:
            continue
        flat, rank = not bool(state.stream_vertical[k]), state.stream_rank[k]
        if best < 0 or (flat < best_flat) or (flat == best_flat and rank < best_rank):
            best, best_flat, best_rank = k, flat, rank
    return best


@njit(cache=True, nogil=True)
def track_velocity(params: np.record, gravity_params: np.record, updates: np.record, state: np.record, knots_ns: np.ndarray,
                   knots: np.ndarray, fixes: np.ndarray, gravity: np.record, has_accel: bool, accel_body_m_s2: tuple, tick_ns: int,
                   dt_ns: int, predicted_q: tuple, prior_doubt_deg: float, prior_tilt_doubt_deg: float, tau_s: float,
                   frame_broken: bool, diagnostics: np.ndarray, n_diag: int) -> tuple:
    """The tick's GNSS fixes (:data:`~fuser.model.tick.GNSS_INPUT`, each with its placed time and stream slot)
    differenced into pairs against the accelerometer's history and low-passed (module docstring), in place on
    ``state`` (the ``velocity`` record) and the knots' ring ``knots_ns``, ``knots``; ``params`` the ``gnss``
    group, ``gravity_params`` the ``accel`` group. ``accel_body_m_s2`` is the tick's mean specific force in the
    state's body frame (``has_accel`` False without an IMU sample), ``gravity`` the strapdown frame after this
    tick's rotation, ``predicted_q`` the predicted attitude's mode, ``prior_doubt_deg`` and
    ``prior_tilt_doubt_deg`` its doubts (:class:`~fuser.model.tick.TickContext`). Each fix's diagnostic is written
    into ``diagnostics`` from ``n_diag`` on. The aiding starts once a tilt has been measured and the predicted tilt
    is known within ``updates.converged_deg`` (before that the plain update's fast start runs), whatever the
    heading's uncertainty (6-D fusion too). Returns (:class:`~fuser.model.tick.VelocityTrack`, the next free
    diagnostic index)."""
    n_fixes = fixes.shape[0]
    any_stream = False
    for k in range(state.stream_seen.shape[0]):
        if state.stream_seen[k]:
            any_stream = True
    if not params.enabled or not (n_fixes > 0 or any_stream):
        return VelocityTrack(False, False, 0.0, False, False), n_diag
    may_aid = gravity.tilt_known and not frame_broken and prior_tilt_doubt_deg < updates.converged_deg
    to_s = rotation_rows(from_array(gravity.q_strapdown))  # body -> S
    force_s = vec3.mat_vec(to_s, accel_body_m_s2) if has_accel else vec3.ZERO
    _knots(params, state, knots_ns, knots, has_accel, force_s, tick_ns, dt_ns, frame_broken)
    g = gravity_params.gravity_m_s2
    max_age_ns = round(params.max_age_s * 1e9)
    to_world = rotation_rows(predicted_q)  # body -> NED through the prediction (after to_s^T: S -> NED), for the jump check
    was_aiding = state.has_lp
    has_lp = was_aiding and may_aid
    body_lp, world_lp = vec3.load(state.body_lp_m_s2), vec3.load(state.world_lp_m_s2)
    vertical, noise_var, noise_cov, fused, lp_s = state.vertical, state.noise_var_m2_s4, state.noise_cov_m2_s3, False, state.lp_s
    has_recent, recent_world, recent_ns = state.has_recent, vec3.load(state.recent_world_m_s2), state.recent_ns
    recent_var, recent_cov, recent_s = state.recent_noise_var_m2_s4, state.recent_noise_cov_m2_s3, state.recent_s
    nan = math.nan

    for i in range(n_fixes):
        fix = fixes[i]
        if not fix.has_velocity or fix.fix_type < FIX_2D:
            n_diag = emit(diagnostics, n_diag, of(VELOCITY, GATED, NO_FIX, nan, nan, nan, NOT_AIDED))
            continue
        slot = fix.slot
        measured = fix.placed_ns - round((params.filtered_latency_ms if fix.filtered else params.latency_ms) * 1e6)
        v1x, v1y, v1z = fix.vel_ned_m_s[0], fix.vel_ned_m_s[1], fix.vel_ned_m_s[2]
        seen, previous_vertical = bool(state.stream_seen[slot]), bool(state.stream_vertical[slot])
        previous_ns, previous_noise = state.stream_measured_ns[slot], state.stream_noise_m_s[slot]
        v0x, v0y, v0z = state.stream_vel_ned_m_s[slot, 0], state.stream_vel_ned_m_s[slot, 1], state.stream_vel_ned_m_s[slot, 2]
        if seen and v1x == v0x and v1y == v0y and v1z == v0z and fix.vertical_velocity == previous_vertical:
            n_diag = emit(diagnostics, n_diag, of(VELOCITY, GATED, STALE, nan, nan, nan, NOT_AIDED))
            continue
        claimed_m_s = fix.speed_accuracy_m_s if fix.has_speed_accuracy else params.velocity_noise_m_s
        noise_m_s = max(claimed_m_s, math.sqrt(state.stream_measured_var_m2_s2[slot]))
        state.stream_seen[slot], state.stream_measured_ns[slot] = True, measured
        state.stream_vel_ned_m_s[slot, 0], state.stream_vel_ned_m_s[slot, 1], state.stream_vel_ned_m_s[slot, 2] = v1x, v1y, v1z
        state.stream_vertical[slot], state.stream_noise_m_s[slot] = fix.vertical_velocity, noise_m_s
        if not seen or not 0 < measured - previous_ns <= max_age_ns:
            state.stream_has_residual[slot] = False
            n_diag = emit(diagnostics, n_diag, of(VELOCITY, GATED, GAP, nan, nan, nan, NOT_AIDED))
            continue
        span_s = (measured - previous_ns) * 1e-9
        both_vertical = fix.vertical_velocity and previous_vertical
        # the vertical unknown without vertical velocity: left to the low-pass (module docstring)
        accel = ((v1x - v0x) / span_s, (v1y - v0y) / span_s, (v1z - v0z) / span_s if both_vertical else 0.0)
        gravity_less_accel = (-accel[0], -accel[1], g - accel[2])  # g e_z - a
        # aiding or not, into what the gravity update's raw readings measure (gravity.update_gravity)
        mid_ns = (measured + previous_ns) // 2
        restart_recent = not has_recent or mid_ns - recent_ns > max_age_ns
        raw_alpha, recent_s, recent_var, recent_cov = pair_lowpass.advance(restart_recent, recent_s, recent_var, recent_cov, span_s,
                                                                           params.raw_lowpass_s, noise_m_s, previous_noise)
        recent_world = gravity_less_accel if restart_recent else vec3.toward(recent_world, gravity_less_accel, raw_alpha)
        has_recent, recent_ns = True, mid_ns
        has_start, start = _force_at(state, knots_ns, knots, previous_ns)
        has_end, end = _force_at(state, knots_ns, knots, measured)
        if not has_start or not has_end:
            state.stream_has_residual[slot] = False
            n_diag = emit(diagnostics, n_diag, of(VELOCITY, GATED, GAP, nan, nan, nan, NOT_AIDED))
            continue
        force = ((end[0] - start[0]) / span_s, (end[1] - start[1]) / span_s, (end[2] - start[2]) / span_s)  # mean over the interval, in S
        # the jump check: against the accelerometer's acceleration, rotated by the estimate (S -> NED)
        expected = vec3.mat_vec(to_world, vec3.vec_mat(force, to_s))
        difference = (accel[0] - expected[0], accel[1] - expected[1], accel[2] - (expected[2] + g) if both_vertical else 0.0)
        _measure_noise(params, state, slot, difference, span_s, both_vertical)
        velocity_m_s2 = max(noise_m_s, previous_noise) / span_s
        attitude_m_s2 = vec3.norm(force) * math.radians(prior_doubt_deg)
        variance = 2.0 * velocity_m_s2 * velocity_m_s2 + attitude_m_s2 * attitude_m_s2 + params.accel_error_m_s2 * params.accel_error_m_s2
        gate = params.gate_sigma * math.sqrt(variance)
        innovation_m_s2 = vec3.norm(difference)
        ratio = (innovation_m_s2 / gate) * (innovation_m_s2 / gate)
        outcome, reason = GATED, NO_REASON
        selected = _selected(state, measured, max_age_ns) == slot
        if ratio <= 1.0 and selected:  # one stream's pairs: consecutive ones share a fix, as the noise's recursion counts
            velocity_check.check_residual(params, state, difference, expected, measured, span_s, noise_m_s, previous_noise, max_age_ns)
        if ratio > 1.0:
            reason = JUMP
        elif not selected:
            reason = UNSELECTED
        elif not has_lp and not may_aid:
            reason = UNCONVERGED
        else:
            # the low-pass starts from this pair if it held none: unbiased, its noise counted
            alpha, lp_s, noise_var, noise_cov = pair_lowpass.advance(not has_lp, lp_s, noise_var, noise_cov, span_s, tau_s, noise_m_s,
                                                                     previous_noise)
            if not has_lp:
                has_lp, body_lp, world_lp = True, vec3.ZERO, vec3.ZERO
            body_lp = vec3.toward(body_lp, (-force[0], -force[1], -force[2]), alpha)
            world_lp = vec3.toward(world_lp, gravity_less_accel, alpha)
            vertical, fused, outcome = both_vertical, True, FUSED
        # the pair's account: its acceleration check (values accel_innovation_m_s2, accel_gate_m_s2, interval_s, vertical,
        # velocity_noise_m_s)
        n_diag = emit(diagnostics, n_diag, Diagnostic(True, VELOCITY, outcome, reason, nan, nan, ratio, NOT_AIDED, True, innovation_m_s2,
                                                      gate, span_s, both_vertical, noise_m_s))
    # the low-pass's new reading goes to the gravity update at the first tick with an IMU sample (with a slower IMU
    # than the loop, a pair fused in a tick without one was never read: a 50 Hz IMU in a 100 Hz loop lost half of
    # them, and with their spacing counted from the lost ones the estimate diverged, 45 deg off in tilt)
    due = fused or state.reading_due
    read = due and has_accel
    had_fused, last_fused_ns = state.has_last_fused_ns, state.last_fused_ns
    interval = dt_ns * 1e-9 if not had_fused or not read else (tick_ns - last_fused_ns) * 1e-9
    if read:
        last_fused_ns = tick_ns
    state.reading_due = due and not has_accel
    has_last = had_fused or read
    active = has_lp and has_last and tick_ns - last_fused_ns <= max_age_ns
    lost = not active and was_aiding
    if not active:
        has_lp, body_lp, world_lp = False, vec3.ZERO, vec3.ZERO
    # moving: a fix still fresh at this tick (measured within max_age_s plus its latency) is fast; a stream that stopped
    # in flight is not taken as moving for ever (the rest detector would never run again)
    fresh_ns = pair_lowpass.max_age_with_latency_ns(params)
    moving = False
    for k in range(state.stream_seen.shape[0]):
        if state.stream_seen[k] and tick_ns - state.stream_measured_ns[k] <= fresh_ns:
            vx, vy, vz = state.stream_vel_ned_m_s[k, 0], state.stream_vel_ned_m_s[k, 1], state.stream_vel_ned_m_s[k, 2]
            moving = moving or math.sqrt(vx * vx + vy * vy + vz * vz) > params.moving_speed_m_s
    state.has_lp = has_lp
    vec3.store(state.body_lp_m_s2, body_lp)
    vec3.store(state.world_lp_m_s2, world_lp)
    state.vertical, state.noise_var_m2_s4, state.noise_cov_m2_s3, state.lp_s = vertical, noise_var, noise_cov, lp_s if has_lp else 0.0
    state.has_last_fused_ns, state.last_fused_ns = has_last, last_fused_ns if has_last else 0
    state.has_recent, state.recent_ns = has_recent, recent_ns
    vec3.store(state.recent_world_m_s2, recent_world)
    state.recent_noise_var_m2_s4, state.recent_noise_cov_m2_s3, state.recent_s = recent_var, recent_cov, recent_s
    return VelocityTrack(active, read and active, interval, moving, lost), n_diag


@njit(cache=True, nogil=True)
def raw_world(params: np.record, gravity_params: np.record, state: np.record, tick_ns: int) -> tuple:
    """What a raw accelerometer reading measures in the world while fixes come: (present, ``g e_z - a``, its noise
    per axis in m/s^2), ``a`` the pairs' acceleration low-passed over ``gnss.raw_lowpass_s`` (their running mean until
    they span it, :func:`fuser.model.pair_lowpass.start_alpha`: a first pair taken whole with ``alpha`` 1/3 kept its noise
    for the restart check of the next pairs; at five times the claimed noise every seed of the simulated hover restarted
    the fast start on it, seven of eight now, and a start in the Cessna's turn is 1.1-1.8 deg RMS off from 1 s after
    it, largest 2.7-9.3, where it was 1.3-2.3, largest 3.9-11.1), if the newest was
    measured within ``gnss.max_age_s`` (and the fix's latency) of the tick and ``a`` is beyond three times its
    noise; not present: down alone (an acceleration the noise could make is better taken as none). In a turn the raw
    reading is the lift's direction, the bank's vertical; with the turn's acceleration taken out it is gravity's, to
    within the pairs' age times the turn rate (2 deg at 0.1 rad/s and 0.35 s)."""
    if not params.enabled or not state.has_recent:
        return False, vec3.ZERO, 0.0
    if tick_ns - state.recent_ns > pair_lowpass.max_age_with_latency_ns(params):
        return False, vec3.ZERO, 0.0
    noise_m_s2 = math.sqrt(max(state.recent_noise_var_m2_s4, 0.0))
    x, y, z = vec3.load(state.recent_world_m_s2)
    if vec3.norm((-x, -y, gravity_params.gravity_m_s2 - z)) <= 3.0 * noise_m_s2:  # |g e_z - (g e_z - a)|
        return False, vec3.ZERO, 0.0
    return True, (x, y, z), noise_m_s2


@njit(cache=True, nogil=True)
def _vector_exponent(b: tuple, r: tuple, sigma: float) -> tuple:
    """(present, exponent): Davenport's ``K / sigma^2`` of the body direction ``b`` measured as the world direction ``r``
    (``core.observations._davenport``) as a plain 4x4 array; not present (zeros) for a zero or not finite vector.
    Copied out of ``_davenport``'s Optional result, so that every branch's :class:`GravityReading` has one type."""
    b_array, r_array = np.empty(3), np.empty(3)
    for i in range(3):
        b_array[i], r_array[i] = b[i], r[i]
    k = _davenport(b_array, r_array, sigma)
    exponent = np.zeros((4, 4))
    if k is None:
        return False, exponent
    for i in range(4):
        for j in range(4):
            exponent[i, j] = k[i, j]
    return True, exponent


@njit(cache=True, nogil=True)
def update_gravity_aided(params: np.record, updates: np.record, state: np.record, velocity: np.record,
                         track: VelocityTrack, tick: TickContext, tau_s: float, predicted_q: tuple) -> GravityReading:
    """The gravity update while GNSS aids it: the low-passed body vector ``b`` measured as the world vector ``w``
    (module docstring), once per tick with a new pair; between pairs nothing is measured. The plain update's
    low-pass is dropped meanwhile, so that it starts again from the estimate if the aiding ends. ``state`` is the
    ``gravity`` record (changed in place), ``velocity`` the ``velocity`` record after this tick's
    :func:`track_velocity`, ``track`` what it returned; ``params`` the ``accel`` group."""
    drop_lp(state)  # the plain update's low-pass and raw mean
    if not velocity.has_lp:
        return no_reading()
    body = vec3.vec_mat(vec3.load(velocity.body_lp_m_s2), rotation_rows(from_array(state.q_strapdown)))  # S -> body
    rotation = rotation_rows(predicted_q)  # body -> NED
    world = vec3.load(velocity.world_lp_m_s2)  # its vertical part g - a_v, or g without vertical velocity: free of the estimate
    body_norm, measured_norm = vec3.norm(body), vec3.norm(world)
    measured_world = (world[0] / measured_norm, world[1] / measured_norm, world[2] / measured_norm)
    if not velocity.vertical:  # the vertical is unknown: measured are the horizontal components only (module docstring)
        world = (world[0], world[1], vec3.dot(rotation[2], body))
    # down in the body (the autopilot attitude's check), every tick: gravity's direction a - f, a seen through the estimate
    seen = vec3.vec_mat((world[0], world[1], world[2] - params.gravity_m_s2), rotation)  # R^T (w - g e_z)
    down = (body[0] - seen[0], body[1] - seen[1], body[2] - seen[2])
    down_norm = vec3.norm(down)
    vec3.store(state.down_body, (down[0] / down_norm, down[1] / down_norm, down[2] / down_norm))
    measured_body = (body[0] / body_norm, body[1] / body_norm, body[2] / body_norm)
    vec3.store(state.measured_body, measured_body)
    vec3.store(state.measured_world, measured_world)
    world_norm = vec3.norm(world)
    norm_error = abs(body_norm - world_norm) / params.gravity_m_s2
    trusted = norm_error < 0.5 * params.norm_gate_fraction
    if not track.fused:
        # Between pairs no reading. While the vehicle holds still the bias feedback learns each tick's (magnetometer)
        # correction as without GNSS; in motion only the ticks that measured the tilt teach it: learning every tick
        # let the bias run away in the JSBSim flight's sustained turns (1.8 deg/s off while reporting 0.17).
        return GravityReading(False, np.zeros((4, 4)), False, trusted and not track.moving, none(), False, 0.0, False)
    aiding = AIDED_3D if velocity.vertical else AIDED_HORIZONTAL
    nan = math.nan
    if norm_error > params.norm_gate_fraction:
        gated = of(GRAVITY, GATED, NORM, nan, nan, nan, aiding)
        return GravityReading(False, np.zeros((4, 4)), False, False, gated, False, 0.0, False)
    predicted_world = vec3.mat_vec(rotation, body)
    innovation = vec3.angle_rad(vec3.dot(predicted_world, world) / (body_norm * world_norm))
    interval = track.interval_s
    correction = math.sqrt(tick.process_variance_rad2 * interval / tick.dt_s) * tau_s / max(interval, 1e-6)
    noise = math.sqrt(max(velocity.noise_var_m2_s4, 0.0)) / world_norm
    sigma = math.sqrt(correction * correction + noise * noise * max(tau_s / interval, 1.0))
    verdict = innovation_gate(updates, state.gated_s, innovation, sigma, tick.prior_doubt_deg, interval)
    # that sigma sets the gain; the reading itself is off by the low-pass's residue and the GNSS acceleration's noise,
    # and a reading further than those allow disputes the state, fused or not (fuser.model.gravity, Disputed)
    own_error = math.hypot(math.radians(params.lowpass_error_deg), noise)
    state.disputed_rad = innovation if innovation > gate_rad(updates, own_error, tick.prior_tilt_doubt_deg) else 0.0
    reason = INNOVATION if verdict.outcome == GATED else NO_REASON
    diagnostic = of(GRAVITY, verdict.outcome, reason, innovation, sigma, verdict.test_ratio, aiding)
    state.converged, state.tilt_known, state.gated_s = True, True, verdict.gated_s
    if verdict.outcome != GATED:
        present, exponent = _vector_exponent(measured_body, world, sigma)
        if present:  # (not: a zero or not finite vector, where the old vector_exponent raised)
            return GravityReading(True, exponent, False, trusted, diagnostic, True, innovation + 2.0 * noise, False)
    return GravityReading(False, np.zeros((4, 4)), False, False, diagnostic, False, 0.0, False)
