"""The GNSS fixes' check of the state: how far off it is, for the published attitude to cover.

The aided gravity reading (:mod:`fuser.model.velocity`) cannot show a drift the gyro gives the state: its body side
is low-passed in S, which a gyro bias turns along with the prediction, so a bias that appears in flight moves
reading and state together (a 2.9 deg/s x bias step in the simulated hover: 7.5-11.5 deg off while every aided
innovation was 1-3 deg against a sigma of 4, fused, the published uncertainty 3.3 deg). Each pair's residual of its
jump check (there, "Faults"), ``r = a - (R_est R_SB^T f + g e_z)`` with ``f`` the pair's own mean force, is free of
that: it compares the state of now with this interval's acceleration, and an attitude error ``d`` makes it
``d x f`` (to within ``d`` times the bias times the latency). The selected stream's pairs alone (consecutive pairs then
share a fix, as the noise's recursion counts; an autopilot's solution running away beside a receiver read 3 deg of
error into a right state otherwise). It is low-passed in the world with ``gnss.residual_lowpass_s``, the force
beside it; its noise is the velocity noise differenced and low-passed alike (:mod:`fuser.model.pair_lowpass`).
The accelerometer's bias and scale lie along ``f`` and do not count: the part across ``f`` is read. Where that part,
over ``|f|``, is beyond ``updates.innovation_gate_sigma`` times its noise, its square less that
(:func:`attitude_excess_rad2`) is the least the state is off by, and the published attitude covers it as it covers
a disputed gravity reading (:mod:`fuser.model.gravity`, "Disputed"; counted as ``gnss_disputes``). The state is not
changed by it.

Bias step, simulated hover, seeds 0-3, the share of the estimates over twice their reported uncertainty from 4 to
30 s: 43.6 / 39.0 / 37.6 / 54.7 % before, 0.5 / 0 / 0 / 12.2 % with it (seed 3's from its start, 9-10 deg off
reporting 4 with its unlearnt 1.5 deg/s bias, before the step), 0 % on all four once the low-passes started as a
running mean (:func:`fuser.model.pair_lowpass.start_alpha`); the nominal flights' published uncertainty did not
move (the 30-s multirotor, aggressive and Cessna flights 3.35 / 3.56 / 3.03 deg).

Tried on seed 0: a 1-s low-pass, 13.5 %; a 3-s one, 5.3 % (it lags the error's growth); the noise counted once
instead of three times, 0 % but every nominal flight 0.14-0.37 deg wider; the accelerometer's error
(``accel_error_m_s2``) counted as the residual's own, 15.5 % (at equilibrium the state has taken the bias in, both
sides agree).

The low-pass's memory is the ``residual`` part of the ``velocity`` record (:data:`fuser.model.state.VELOCITY`);
each pair enters from :func:`fuser.model.velocity.track_velocity`, and the tick reads
:func:`attitude_excess_rad2` when it publishes (:func:`fuser.model.fusion.tick`). Compiled (numba) for the tick.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fuser.model import pair_lowpass, vec3

__all__ = ["attitude_excess_rad2", "check_residual"]


@njit(cache=True, nogil=True)
def check_residual(params: np.record, state: np.record, difference: tuple, force_ned_m_s2: tuple, measured_ns: int, span_s: float,
                   noise_m_s: float, previous_noise_m_s: float, max_age_ns: int) -> None:
    """One pair's acceleration residual against the estimate (the jump check's ``difference``) and the specific
    force it was checked with (in NED through the estimate) into the world-frame low-passes
    :func:`attitude_excess_rad2` reads, with the velocity noise they hold (module docstring); they start
    again from this pair after ``max_age_s`` without one."""
    restart = not state.has_residual_lp or measured_ns - state.residual_ns > max_age_ns
    alpha, state.residual_s, state.residual_noise_var_m2_s4, state.residual_noise_cov_m2_s3 = pair_lowpass.advance(
        restart, state.residual_s, state.residual_noise_var_m2_s4, state.residual_noise_cov_m2_s3, span_s, params.residual_lowpass_s,
        noise_m_s, previous_noise_m_s)
    vec3.store(state.residual_lp_m_s2, vec3.toward(vec3.load(state.residual_lp_m_s2), difference, alpha))
    vec3.store(state.residual_force_m_s2, vec3.toward(vec3.load(state.residual_force_m_s2), force_ned_m_s2, alpha))
    state.has_residual_lp, state.residual_ns = True, measured_ns


@njit(cache=True, nogil=True)
def attitude_excess_rad2(params: np.record, updates: np.record, state: np.record, tick_ns: int) -> float:
    """How far the estimate is off, as the fixes show it (module docstring): the part of the pairs'
    low-passed acceleration residual across the specific force (an attitude error ``d`` turns ``f`` by ``d x f``;
    along ``f`` are the accelerometer's scale and bias) over the force, squared, less ``updates.innovation_gate_sigma``
    squared times the velocity noise left in the low-pass on those two axes (what noise alone makes is not taken
    for an error), at most 1 (a sine, squared); 0 without a pair within ``max_age_s`` and the fix's latency.
    ``params`` the ``gnss`` group, ``updates`` the ``updates`` group, ``state`` the ``velocity`` record."""
    if not state.has_residual_lp:
        return 0.0
    if tick_ns - state.residual_ns > pair_lowpass.max_age_with_latency_ns(params):
        return 0.0
    force = vec3.load(state.residual_force_m_s2)
    force_sq = vec3.dot(force, force)
    if not force_sq > 0.0:
        return 0.0
    across = vec3.cross(vec3.load(state.residual_lp_m_s2), force)  # |r x f| = |r_across| |f|
    noise_m2_s4 = updates.innovation_gate_sigma * updates.innovation_gate_sigma * 2.0 * max(state.residual_noise_var_m2_s4, 0.0)
    # the part across f over |f| is the sine of the error: at most 1 (a force near 0, in free fall, shows no attitude)
    return min(max(vec3.dot(across, across) / force_sq - noise_m2_s4, 0.0) / force_sq, 1.0)
