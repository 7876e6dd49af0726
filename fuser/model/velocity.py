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
:func:`core.observations.vector_exponent`), which in a turn (``w`` not
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
turn the estimate is what is wrong), so the first readings count for little.

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
"""

from __future__ import annotations

import math
from bisect import bisect_left
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numba import njit

from core.bingham import Bingham
from core.bingham_kernels import down_alignment_sq
from core.normalization import Method
from core.observations import vector_exponent
from drivers.samples import GnssSample, Vec3
from fuser.config import AccelSettings, GnssSettings, UpdateSettings
from fuser.model import vec3
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.gate import innovation_gate
from fuser.model.gravity import GnssWorld, GravityReading
from fuser.model.state import GnssStream, GravityState, VelocityState
from fuser.model.tick import TickContext

__all__ = ["VelocityTrack", "raw_world", "tilt_doubt_deg", "track_velocity", "update_gravity_aided"]

FIX_2D = 2
"""MAVLink GPS_FIX_TYPE of the first fix that carries a velocity."""
_ZERO = (0.0, 0.0, 0.0)
_AIDING_3D = (("aiding", "gnss"),)
_AIDING_HORIZONTAL = (("aiding", "gnss_horizontal"),)


@dataclass(frozen=True, slots=True)
class VelocityTrack:
    """One tick of the GNSS side: the state after the tick's fixes, what became of each, and whether it aids."""

    state: VelocityState
    active: bool
    """Aiding is on: the gravity update is the aided one (:func:`update_gravity_aided`), not the plain one."""
    fused: bool
    """A pair entered the low-pass in this tick: the aided update has a new reading."""
    interval_s: float
    """Seconds since the previous tick that fused a pair (the aided readings' spacing)."""
    moving: bool
    """A fix within ``max_age_s`` is faster than ``gnss.moving_speed_m_s``: the vehicle is not at rest."""
    diagnostics: tuple[UpdateDiagnostic, ...]
    events: tuple[str, ...]


def tilt_doubt_deg(state: Bingham, method: Method) -> float:
    """RMS tilt error of a Bingham (its uncertainty about the horizontal axes only, degrees).

    Along principal direction ``m_i`` the body-frame rotation error has variance ``4 E[(m_i . x)^2]`` (the vector
    part of a small rotation is half its angle) about the body axis ``vec(mode^* m_i)``; its tilt share is
    ``1 - cos^2`` of that axis with world down seen in the body, ``cos = m_i . (k mode)`` (as in
    :func:`fuser.model_error.widened_concentrations`). A heading still unknown (6-D, a cold start) does not count.
    """
    return math.degrees(math.sqrt(max(_tilt_variance(state.M, state.moments(method)), 0.0)))


@njit(cache=True, nogil=True)
def _tilt_variance(M: np.ndarray, moments: np.ndarray) -> float:
    """``sum_i 4 E[(m_i . x)^2] (1 - cos_i^2)`` over the three dispersion directions (:func:`tilt_doubt_deg`), compiled."""
    along_down = down_alignment_sq(M)
    variance = 0.0
    for i in range(3):
        variance += 4.0 * moments[i] * (1.0 - min(along_down[i], 1.0))
    return variance


def _force_at(knots: Sequence[tuple[int, np.ndarray, np.ndarray]], t_ns: int) -> Vec3 | None:
    """The integrated specific force at ``t_ns`` (linear between knots), None outside the history."""
    if not knots or t_ns < knots[0][0] or t_ns > knots[-1][0]:
        return None
    i = bisect_left(knots, t_ns, key=_knot_ns)
    t1, f1, _ = knots[i]
    if t1 == t_ns or i == 0:
        return vec3.floats(f1)
    t0, f0, _ = knots[i - 1]
    return vec3.toward(vec3.floats(f0), vec3.floats(f1), (t_ns - t0) / (t1 - t0))


def _knot_ns(knot: tuple[int, np.ndarray, np.ndarray]) -> int:
    return knot[0]


def _knots(params: GnssSettings, state: VelocityState, force_s_m_s2: Vec3 | None, tick_ns: int, dt_ns: int,
           broken: bool) -> tuple[tuple[int, np.ndarray, np.ndarray], ...]:
    """The accelerometer's history after this tick: its mean specific force in S (held without a sample),
    integrated; dropped when the strapdown frame broke (a gyro gap: the frame before is not this one)."""
    knots = () if broken else state.force_knots
    if not knots:
        zero = np.zeros(3)
        force = zero if force_s_m_s2 is None else np.array(force_s_m_s2)
        return ((tick_ns - dt_ns, zero, force), (tick_ns, force * (dt_ns * 1e-9), force))
    last_ns, integral, held = knots[-1]
    force = held if force_s_m_s2 is None else np.array(force_s_m_s2)
    horizon_ns = tick_ns - round((params.max_age_s + max(params.latency_ms, params.filtered_latency_ms) * 1e-3) * 1e9) - 2 * dt_ns
    # the first knot kept is the last one before the horizon (the horizon moves a tick per tick: a step or two)
    first = 0
    while first + 1 < len(knots) and knots[first + 1][0] < horizon_ns:
        first += 1
    step_s = (tick_ns - last_ns) * 1e-9
    fx, fy, fz = force.tolist()
    ix, iy, iz = integral.tolist()
    return knots[first:] + ((tick_ns, np.array((ix + fx * step_s, iy + fy * step_s, iz + fz * step_s)), force),)


def _noise_after(variance: float, covariance: float, alpha: float, span_s: float, noise_m_s: float,
                 previous_noise_m_s: float) -> tuple[float, float]:
    """The velocity noise in a low-pass of differenced fixes after one more: ``y = (1 - a) y + (a / T)(n1 - n0)``,
    ``n0`` shared with the previous difference (module docstring, "Sigma"); (variance, covariance with ``n1``)."""
    gain = alpha / span_s
    variance = (1.0 - alpha) ** 2 * variance + gain**2 * (noise_m_s**2 + previous_noise_m_s**2) - 2.0 * (1.0 - alpha) * gain * covariance
    return variance, gain * noise_m_s**2


def _selected(streams: Sequence[GnssStream], now_measured_ns: int, max_age_ns: int) -> tuple | None:
    """The stream whose pairs aid: among those with a fix within ``max_age``, one with vertical velocity first,
    then a receiver's fix before an autopilot's solution, then the lowest source (a total, stable order)."""
    fresh = [s for s in streams if now_measured_ns - s.measured_ns <= max_age_ns]
    if not fresh:
        return None
    return min(fresh, key=lambda s: (not s.vertical, s.key[1], s.key[0])).key


def track_velocity(params: GnssSettings, gravity_params: AccelSettings, updates: UpdateSettings, state: VelocityState,
                   fixes: Sequence[tuple[GnssSample, int]], gravity: GravityState, accel_body_m_s2: np.ndarray | None, tick_ns: int,
                   dt_ns: int, predicted_q: np.ndarray, prior_doubt_deg: float, prior_tilt_doubt_deg: float, tau_s: float,
                   frame_broken: bool) -> VelocityTrack:
    """The tick's GNSS fixes (each with its placed time) differenced into pairs against the accelerometer's
    history and low-passed (module docstring); ``accel_body_m_s2`` is the tick's mean specific force in the
    state's body frame (None without an IMU sample), ``gravity`` the strapdown frame after this tick's rotation,
    ``predicted_q`` the predicted attitude's mode, ``prior_doubt_deg`` and ``prior_tilt_doubt_deg`` its doubts
    (:class:`~fuser.model.tick.TickContext`). The aiding starts once a tilt has been measured and the predicted tilt
    is known within ``updates.converged_deg`` (before that the plain update's fast start runs), whatever the
    heading's uncertainty (6-D fusion too)."""
    if not params.enabled or not (fixes or state.streams):
        return VelocityTrack(state, False, False, 0.0, False, (), ())
    may_aid = gravity.tilt_known and not frame_broken and prior_tilt_doubt_deg < updates.converged_deg
    to_s = vec3.rotation_rows(gravity.q_strapdown)  # body -> S
    force_s = None if accel_body_m_s2 is None else vec3.mat_vec(to_s, vec3.floats(accel_body_m_s2))
    knots = _knots(params, state, force_s, tick_ns, dt_ns, frame_broken)
    g = gravity_params.gravity_m_s2
    max_age_ns = round(params.max_age_s * 1e9)
    streams = {s.key: s for s in state.streams} if fixes else {}
    to_world = None  # S -> NED through the prediction, for the jump check: once a pair comes
    body_lp, world_lp = state.body_lp_m_s2, state.world_lp_m_s2
    vertical, noise_var, noise_cov, fused = state.vertical, state.noise_var_m2_s4, state.noise_cov_m2_s3, False
    recent_world, recent_ns = state.recent_world_m_s2, state.recent_ns
    recent_var, recent_cov = state.recent_noise_var_m2_s4, state.recent_noise_cov_m2_s3
    if not may_aid:
        body_lp = world_lp = None
    diagnostics: list[UpdateDiagnostic] = []
    for fix, placed_ns in fixes:
        if fix.vel_ned_m_s is None or fix.fix_type < FIX_2D:
            diagnostics.append(UpdateDiagnostic.of("velocity", "gated", "no_fix"))
            continue
        key = (fix.source, fix.filtered)
        measured = placed_ns - round((params.filtered_latency_ms if fix.filtered else params.latency_ms) * 1e6)
        previous = streams.get(key)
        if previous is not None and fix.vel_ned_m_s == previous.vel_ned_m_s and fix.vertical_velocity == previous.vertical:
            diagnostics.append(UpdateDiagnostic.of("velocity", "gated", "stale"))
            continue
        noise_m_s = params.velocity_noise_m_s if fix.speed_accuracy_m_s is None else fix.speed_accuracy_m_s
        streams[key] = GnssStream(key, measured, fix.vel_ned_m_s, fix.vertical_velocity, noise_m_s)
        if previous is None or not 0 < measured - previous.measured_ns <= max_age_ns:
            diagnostics.append(UpdateDiagnostic.of("velocity", "gated", "gap"))
            continue
        span_s = (measured - previous.measured_ns) * 1e-9
        both_vertical = fix.vertical_velocity and previous.vertical
        (v1x, v1y, v1z), (v0x, v0y, v0z) = fix.vel_ned_m_s, previous.vel_ned_m_s
        # the vertical unknown without vertical velocity: left to the low-pass (module docstring)
        accel = ((v1x - v0x) / span_s, (v1y - v0y) / span_s, (v1z - v0z) / span_s if both_vertical else 0.0)
        gravity_less_accel = (-accel[0], -accel[1], g - accel[2])  # g e_z - a
        # aiding or not, into what the gravity update's raw readings measure (gravity.update_gravity)
        mid_ns = (measured + previous.measured_ns) // 2
        if recent_world is None or recent_ns is None or mid_ns - recent_ns > max_age_ns:
            recent_world = np.array(gravity_less_accel)
            recent_var, recent_cov = _noise_after(0.0, 0.0, 1.0, span_s, noise_m_s, previous.noise_m_s)
        else:
            raw_alpha = min(1.0, span_s / params.raw_lowpass_s)
            recent_world = np.array(vec3.toward(vec3.floats(recent_world), gravity_less_accel, raw_alpha))
            recent_var, recent_cov = _noise_after(recent_var, recent_cov, raw_alpha, span_s, noise_m_s, previous.noise_m_s)
        recent_ns = mid_ns
        start, end = _force_at(knots, previous.measured_ns), _force_at(knots, measured)
        if start is None or end is None:
            diagnostics.append(UpdateDiagnostic.of("velocity", "gated", "gap"))
            continue
        force = ((end[0] - start[0]) / span_s, (end[1] - start[1]) / span_s, (end[2] - start[2]) / span_s)  # mean over the interval, in S
        # the jump check: against the accelerometer's acceleration, rotated by the estimate (S -> NED), only when a pair comes
        if to_world is None:
            to_world = vec3.rotation_rows(predicted_q)
        expected = vec3.mat_vec(to_world, vec3.vec_mat(force, to_s))
        difference = (accel[0] - expected[0], accel[1] - expected[1], accel[2] - (expected[2] + g) if both_vertical else 0.0)
        variance = (2.0 * (max(noise_m_s, previous.noise_m_s) / span_s) ** 2 + (vec3.norm(force) * math.radians(prior_doubt_deg)) ** 2
                    + params.accel_error_m_s2**2)
        gate = params.gate_sigma * math.sqrt(variance)
        innovation_m_s2 = vec3.norm(difference)
        values = (("accel_innovation_m_s2", innovation_m_s2), ("accel_gate_m_s2", gate), ("interval_s", span_s), ("vertical", both_vertical))
        ratio = (innovation_m_s2 / gate) ** 2
        if ratio > 1.0:
            diagnostics.append(UpdateDiagnostic("velocity", "gated", "jump", test_ratio=ratio, values=values))
            continue
        if _selected(list(streams.values()), measured, max_age_ns) != key:
            diagnostics.append(UpdateDiagnostic("velocity", "gated", "unselected", test_ratio=ratio, values=values))
            continue
        alpha = min(1.0, span_s / tau_s)
        if body_lp is None or world_lp is None:
            if not may_aid:
                diagnostics.append(UpdateDiagnostic("velocity", "gated", "unconverged", test_ratio=ratio, values=values))
                continue
            alpha, noise_var, noise_cov = 1.0, 0.0, 0.0  # the low-pass starts from this pair: unbiased, its noise counted
            body_lp = world_lp = _ZERO
        body_lp = np.array(vec3.toward(vec3.floats(body_lp), (-force[0], -force[1], -force[2]), alpha))
        world_lp = np.array(vec3.toward(vec3.floats(world_lp), gravity_less_accel, alpha))
        noise_var, noise_cov = _noise_after(noise_var, noise_cov, alpha, span_s, noise_m_s, previous.noise_m_s)
        vertical, fused = both_vertical, True
        diagnostics.append(UpdateDiagnostic("velocity", "fused", test_ratio=ratio, values=values))
    last = tick_ns if fused else state.last_fused_ns
    interval = dt_ns * 1e-9 if state.last_fused_ns is None or not fused else (tick_ns - state.last_fused_ns) * 1e-9
    active = body_lp is not None and last is not None and tick_ns - last <= max_age_ns
    events: tuple[str, ...] = ()
    if not active and state.body_lp_m_s2 is not None:
        events = ("gnss_lost",)
    if not active:
        body_lp = world_lp = None
    kept = tuple(streams[k] for k in sorted(streams, key=lambda k: (k[0], k[1]))) if fixes else state.streams
    # moving: a fix still fresh at this tick (measured within max_age_s plus its latency) is fast; a stream that stopped
    # in flight is not taken as moving for ever (the rest detector would never run again)
    fresh_ns = max_age_ns + round(max(params.latency_ms, params.filtered_latency_ms) * 1e6)
    moving = any(tick_ns - s.measured_ns <= fresh_ns and math.hypot(*s.vel_ned_m_s) > params.moving_speed_m_s for s in kept)
    after = VelocityState(kept, knots, body_lp, world_lp, vertical, noise_var, noise_cov, last, recent_world, recent_ns, recent_var, recent_cov)
    return VelocityTrack(after, active, fused and active, interval, moving, tuple(diagnostics), events)


def raw_world(params: GnssSettings, gravity: AccelSettings, state: VelocityState, tick_ns: int) -> GnssWorld | None:
    """What a raw accelerometer reading measures in the world while fixes come: ``g e_z - a``, ``a`` the pairs'
    acceleration low-passed over ``gnss.raw_lowpass_s``, if the newest was measured within ``gnss.max_age_s``
    (and the fix's latency) of the tick and ``a`` is beyond three times its noise; None: down alone (an
    acceleration the noise could make is better taken as none). In a turn the raw reading is the lift's direction,
    the bank's vertical; with the turn's acceleration taken out it is gravity's, to within the pairs' age times the
    turn rate (2 deg at 0.1 rad/s and 0.35 s)."""
    if not params.enabled or state.recent_world_m_s2 is None or state.recent_ns is None:
        return None
    if tick_ns - state.recent_ns > round((params.max_age_s + max(params.latency_ms, params.filtered_latency_ms) * 1e-3) * 1e9):
        return None
    noise_m_s2 = math.sqrt(max(state.recent_noise_var_m2_s4, 0.0))
    x, y, z = vec3.floats(state.recent_world_m_s2)
    if vec3.norm((-x, -y, gravity.gravity_m_s2 - z)) <= 3.0 * noise_m_s2:  # |g e_z - (g e_z - a)|
        return None
    return GnssWorld(state.recent_world_m_s2, noise_m_s2)


def update_gravity_aided(params: AccelSettings, gnss: GnssSettings, updates: UpdateSettings, state: GravityState, velocity: VelocityTrack,
                         tick: TickContext, tau_s: float, predicted_q: np.ndarray) -> GravityReading:
    """The gravity update while GNSS aids it: the low-passed body vector ``b`` measured as the world vector ``w``
    (module docstring), once per tick with a new pair; between pairs nothing is measured. The plain update's
    low-pass is dropped meanwhile, so that it starts again from the estimate if the aiding ends."""
    v = velocity.state
    if v.body_lp_m_s2 is None or v.world_lp_m_s2 is None:
        dropped = GravityState(q_strapdown=state.q_strapdown, accel_lp_m_s2=None, down_body=state.down_body, converged=state.converged,
                               tilt_known=state.tilt_known, gated_s=state.gated_s, raw_mean_m_s2=None, raw_s=0.0,
                               measured_body=state.measured_body, gnss_checked=state.gnss_checked, measured_world=state.measured_world)
        return GravityReading(dropped, None, False, False, None)
    body = vec3.vec_mat(vec3.floats(v.body_lp_m_s2), vec3.rotation_rows(state.q_strapdown))  # S -> body
    rotation = vec3.rotation_rows(predicted_q)  # body -> NED
    world = vec3.floats(v.world_lp_m_s2)  # its vertical part g - a_v, or g without vertical velocity: free of the estimate
    body_norm, measured_norm = vec3.norm(body), vec3.norm(world)
    measured_world = np.array((world[0] / measured_norm, world[1] / measured_norm, world[2] / measured_norm))
    if not v.vertical:  # the vertical is unknown: measured are the horizontal components only (module docstring)
        world = (world[0], world[1], vec3.dot(rotation[2], body))
    # down in the body (the autopilot attitude's check), every tick: gravity's direction a - f, a seen through the estimate
    seen = vec3.vec_mat((world[0], world[1], world[2] - params.gravity_m_s2), rotation)  # R^T (w - g e_z)
    down = (body[0] - seen[0], body[1] - seen[1], body[2] - seen[2])
    down_norm = vec3.norm(down)
    down_body = np.array((down[0] / down_norm, down[1] / down_norm, down[2] / down_norm))
    measured_body = np.array((body[0] / body_norm, body[1] / body_norm, body[2] / body_norm))
    held = GravityState(q_strapdown=state.q_strapdown, accel_lp_m_s2=None, down_body=down_body, converged=state.converged,
                        tilt_known=state.tilt_known, gated_s=state.gated_s, raw_mean_m_s2=None, raw_s=0.0, measured_body=measured_body,
                        gnss_checked=state.gnss_checked, measured_world=measured_world)
    world_norm = vec3.norm(world)
    norm_error = abs(body_norm - world_norm) / params.gravity_m_s2
    trusted = norm_error < 0.5 * params.norm_gate_fraction
    if not velocity.fused:
        # Between pairs no reading. While the vehicle holds still the bias feedback learns each tick's (magnetometer)
        # correction as without GNSS; in motion only the ticks that measured the tilt teach it: learning every tick
        # let the bias run away in the JSBSim flight's sustained turns (1.8 deg/s off while reporting 0.17).
        return GravityReading(held, None, False, trusted and not velocity.moving, None)
    aiding = _AIDING_3D if v.vertical else _AIDING_HORIZONTAL
    if norm_error > params.norm_gate_fraction:
        return GravityReading(held, None, False, False, UpdateDiagnostic.of("gravity", "gated", "norm", values=aiding))
    predicted_world = vec3.mat_vec(rotation, body)
    innovation = vec3.angle_rad(vec3.dot(predicted_world, world) / (body_norm * world_norm))
    interval = velocity.interval_s
    correction = math.sqrt(tick.process_variance_rad2 * interval / tick.dt_s) * tau_s / max(interval, 1e-6)
    noise = math.sqrt(max(v.noise_var_m2_s4, 0.0)) / world_norm
    sigma = math.sqrt(correction**2 + noise**2 * max(tau_s / interval, 1.0))
    verdict = innovation_gate(updates, state.gated_s, innovation, sigma, tick.prior_doubt_deg, interval)
    diagnostic = UpdateDiagnostic.of("gravity", verdict.outcome, "innovation" if verdict.outcome == "gated" else "", innovation, sigma,
                                     verdict.test_ratio, aiding)
    after = GravityState(q_strapdown=state.q_strapdown, accel_lp_m_s2=None, down_body=down_body, converged=True, tilt_known=True,
                         gated_s=verdict.gated_s, raw_mean_m_s2=None, raw_s=0.0, measured_body=measured_body, gnss_checked=state.gnss_checked,
                         measured_world=measured_world)
    if verdict.outcome == "gated":
        return GravityReading(after, None, False, False, diagnostic)
    return GravityReading(after, vector_exponent(measured_body, world, sigma), False, trusted, diagnostic, innovation + 2.0 * noise)
