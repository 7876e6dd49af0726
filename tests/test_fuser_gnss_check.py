"""The GNSS fixes' check of the state (fuser/model/velocity_check.py), against closed forms.

A level vehicle accelerating north at ``A`` (its specific force ``f = (A, 0, -g)`` in the body, the world and the
strapdown frame alike), a fix every 0.1 s of the velocity it has: each pair's acceleration is ``a = (A, 0, 0)``, so
its residual against a state tilted by ``d`` about x is ``a - (R_d f + g e_z) = f - R_d f``, whose part across ``f``
over ``|f|`` is how far the state is off about the axes that ``f`` shows. The published attitude must cover that
much where it is beyond the residual's noise, and nothing where it is not (the noise alone, or the accelerometer's
scale, which lies along ``f``). Every expected value is computed here from these vectors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from core import quaternion as quat
from drivers.samples import GnssSample, SourceId
from fuser.config import AccelSettings, FuserConfig
from fuser.model.diagnostics import DIAGNOSTIC
from fuser.model.state import FilterState, initial_state
from fuser.model.velocity import track_velocity
from fuser.model.velocity_check import attitude_excess_rad2
from model_records import gnss_input, params, part

G = AccelSettings().gravity_m_s2
P = params()
TICK_NS = 10_000_000
FIX_EVERY = 10  # ticks: 10 Hz
LEVEL = tuple(quat.IDENTITY)
ACCEL_M_S2 = 0.5
F_BODY = np.array([ACCEL_M_S2, 0.0, -G])


def _tilted(deg: float) -> tuple:
    return tuple(quat.from_axis_angle([1.0, 0.0, 0.0], math.radians(deg)))


def _accelerating(state_q: tuple, accuracy_m_s: float, seconds: float = 5.0, scale: float = 1.0,
                  second_stream_error_m_s2: float | None = None) -> tuple[FilterState, int]:
    """A fresh state's velocity part after ``seconds`` of 100 Hz ticks of the level vehicle accelerating north at
    ``ACCEL_M_S2`` (its accelerometer ``scale`` times right) with a fix every 0.1 s (``accuracy_m_s`` claimed, and
    exact), the state's attitude ``state_q`` throughout; (state, the last tick's time). ``second_stream_error_m_s2``:
    an autopilot's solution too (another stream, horizontal only: not selected), in the same ticks, whose velocity
    runs away east at that rate."""
    state = initial_state(FuserConfig())
    gravity = part("gravity")  # its strapdown frame the body's
    tick_ns = 0
    for k in range(1, round(seconds * 100) + 1):
        tick_ns = 1_000_000_000 + k * TICK_NS
        fixes = []
        if k % FIX_EVERY == 0:
            measured_s = (tick_ns - 1_000_000_000) * 1e-9 - P.gnss.latency_ms * 1e-3  # the velocity is the latency old
            fix = GnssSample(tick_ns, 3, (ACCEL_M_S2 * measured_s, 0.0, 0.0), True, accuracy_m_s, None, None, None, False,
                             SourceId("mavlink", 1, 1, 0))
            fixes = [(fix, tick_ns, 0)]
            if second_stream_error_m_s2 is not None:
                now_s = (tick_ns - 1_000_000_000) * 1e-9  # a navigation solution is not late (gnss.filtered_latency_ms 0)
                fixes.append((GnssSample(tick_ns, 3, (ACCEL_M_S2 * now_s, second_stream_error_m_s2 * now_s, 0.0), False, accuracy_m_s,
                                         None, None, None, True, SourceId("mavlink", 1, 1, 0)), tick_ns, 1))
        diagnostics = np.zeros(max(len(fixes), 1), DIAGNOSTIC)  # one per fix (the compiled code does not check bounds)
        track_velocity(P.gnss, P.accel, P.updates, state.velocity, state.knots_ns, state.knots, gnss_input(fixes), gravity, True,
                       tuple(scale * F_BODY), tick_ns, TICK_NS, state_q, 3.0, 2.0, 3.0, False, diagnostics, 0)
    return state, tick_ns


def _expected_rad2(off_deg: float) -> float:
    """The part of ``f - R_d f`` across the force as the state sees it, ``R_d f``, over ``|f|``, squared."""
    seen = quat.to_matrix(_tilted(off_deg)) @ F_BODY
    return float(np.sum(np.cross(F_BODY - seen, seen) ** 2) / np.dot(F_BODY, F_BODY) ** 2)


def _excess_deg(state: FilterState, tick_ns: int) -> float:
    return math.degrees(math.sqrt(attitude_excess_rad2(P.gnss, P.updates, state.velocity, tick_ns)))


@pytest.mark.parametrize("off_deg", [5.0, 10.0, 20.0])
def test_a_state_off_by_d_is_shown_off_by_d(off_deg):
    """Exact fixes (1e-5 m/s claimed: the noise term, 9 x 2 x its low-passed variance, is below 1e-10 rad^2): the
    residual is ``f - R_d f`` and the excess its part across ``f`` over ``|f|``, squared (``sin^2 d`` to within the
    0.5 m/s^2 acceleration's share: 2.9 deg of ``f``'s tilt)."""
    state, now = _accelerating(_tilted(off_deg), 1e-5)
    np.testing.assert_allclose(state.velocity.residual_lp_m_s2, F_BODY - quat.to_matrix(_tilted(off_deg)) @ F_BODY, atol=1e-6)
    excess = attitude_excess_rad2(P.gnss, P.updates, state.velocity, now)
    assert excess == pytest.approx(_expected_rad2(off_deg), rel=1e-6)
    assert math.sqrt(excess) == pytest.approx(math.sin(math.radians(off_deg)), rel=0.01)


def test_a_right_state_is_not_shown_off():
    state, now = _accelerating(LEVEL, 0.001)
    assert attitude_excess_rad2(P.gnss, P.updates, state.velocity, now) == 0.0


def test_the_accelerometers_scale_is_not_taken_for_an_attitude_error():
    """A reading 5 % long (``1.05 f``): the residual is ``-0.05 f``, along ``f``, none across it."""
    state, now = _accelerating(LEVEL, 0.001, scale=1.05)
    np.testing.assert_allclose(state.velocity.residual_lp_m_s2, -0.05 * F_BODY, atol=1e-6)
    assert attitude_excess_rad2(P.gnss, P.updates, state.velocity, now) == 0.0


def test_what_the_fixes_noise_could_make_is_not_taken_for_an_error():
    """0.3 m/s fixes, differenced over 0.1 s and low-passed over ``gnss.residual_lowpass_s`` (2 s, alpha 0.05):
    ``y = (1 - a) y + (a / T)(n1 - n0)``, whose variance (computed below pair by pair, the differences sharing a fix)
    settles at ``2 s^2 a^2 / (T^2 (2 - a))`` per axis; three times its standard deviation on the two axes across ``f``,
    over ``g``, is the least error shown: a state 0.5 deg off is within it (0), one 10 deg off beyond it (``sin^2 d``
    less that least error squared)."""
    s, T, a = 0.3, 0.1, 0.1 / FuserConfig().gnss.residual_lowpass_s
    variance = covariance = 0.0  # y's variance and its covariance with the newest fix's noise, pair by pair
    for _ in range(400):
        variance = (1 - a) ** 2 * variance + (a / T) ** 2 * 2 * s * s - 2 * (1 - a) * (a / T) * covariance
        covariance = (a / T) * s * s
    assert math.degrees(3.0 * math.sqrt(2.0 * variance) / G) == pytest.approx(3.77, abs=0.01)  # 0.5 deg within, 10 beyond
    state, now = _accelerating(_tilted(0.5), s, seconds=30.0)  # the first pair's noise, taken whole, forgotten (0.95^290)
    assert state.velocity.residual_noise_var_m2_s4 == pytest.approx(variance, rel=1e-4)
    assert _excess_deg(state, now) == 0.0
    state, now = _accelerating(_tilted(10.0), s, seconds=30.0)
    least_rad = 3.0 * math.sqrt(2.0 * variance) / np.linalg.norm(F_BODY)
    expected = _expected_rad2(10.0) - least_rad ** 2
    assert attitude_excess_rad2(P.gnss, P.updates, state.velocity, now) == pytest.approx(expected, rel=1e-4)


def test_an_old_check_says_nothing():
    """Past ``gnss.max_age_s`` and the fix's latency after the newest pair: 0, the check is stale."""
    state, now = _accelerating(_tilted(10.0), 0.001)
    newest = state.velocity.residual_ns
    age_ns = round((P.gnss.max_age_s + P.gnss.latency_ms * 1e-3) * 1e9)
    assert _excess_deg(state, newest + age_ns) > 9.0
    assert _excess_deg(state, newest + age_ns + 1) == 0.0


def test_only_the_selected_streams_pairs_check_the_state():
    """A receiver's fixes (vertical velocity: selected) and an autopilot's solution whose velocity runs away east at
    1 m/s^2 (not selected): the check is the receiver's alone, the state right, nothing shown. Its pairs taken in
    too read 0.52 m/s^2 of the runaway, 3.0 deg, as the state's error (and the noise recursion, which counts
    consecutive pairs sharing a fix, would be wrong for pairs of two streams interleaved)."""
    state, now = _accelerating(LEVEL, 1e-5, second_stream_error_m_s2=1.0)
    assert state.velocity.stream_seen[1]  # the second stream was read
    np.testing.assert_allclose(state.velocity.residual_lp_m_s2, 0.0, atol=1e-9)
    assert attitude_excess_rad2(P.gnss, P.updates, state.velocity, now) == 0.0


def test_the_aided_low_pass_starts_as_the_running_mean_of_its_pairs():
    """VQF starts its low-passes as the mean of their first ``tau / Ts`` samples; so do the aided low-pass and the
    check's (fuser/model/velocity.py, "Sigma"). Noisy fixes 0.1 s apart; the accelerometer's history starts with the
    first stream's first fix, so the pairs ending at the first three are gaps (the earlier fix measured before it)
    and six enter, within ``tau`` = 3 s: the world side is ``g e_z`` less their mean acceleration, which telescopes
    to ``(v_8 - v_2) / 0.6 s``, and its noise variance per axis ``2 s^2 / (0.6 s)^2``: a sixth of the first pair's
    standard deviation (an exponential low-pass from the first pair, ``alpha`` = 0.1 / 3, kept 0.84 of it)."""
    s = 0.3
    noise = np.random.default_rng(5).standard_normal((9, 3)) * s
    state = initial_state(FuserConfig())
    gravity = part("gravity", tilt_known=True)  # a tilt known: the aiding may start
    fix_ticks = {50 + 10 * k: k for k in range(9)}
    velocities = []
    for k in range(1, 141):
        tick_ns = 1_000_000_000 + k * TICK_NS
        fixes = []
        if k in fix_ticks:
            measured_s = (tick_ns - 1_000_000_000) * 1e-9 - P.gnss.latency_ms * 1e-3
            velocity = np.array([ACCEL_M_S2 * measured_s, 0.0, 0.0]) + noise[fix_ticks[k]]
            velocities.append(velocity)
            fixes = [(GnssSample(tick_ns, 3, tuple(velocity), True, s, None, None, None, False, SourceId("mavlink", 1, 1, 0)), tick_ns, 0)]
        track_velocity(P.gnss, P.accel, P.updates, state.velocity, state.knots_ns, state.knots, gnss_input(fixes), gravity, True,
                       tuple(F_BODY), tick_ns, TICK_NS, LEVEL, 3.0, 2.0, 3.0, False, np.zeros(1, DIAGNOSTIC), 0)
    v = state.velocity
    mean_accel = (velocities[8] - velocities[2]) / 0.6
    assert v.has_lp and v.lp_s == pytest.approx(0.6)
    np.testing.assert_allclose(v.world_lp_m_s2, [-mean_accel[0], -mean_accel[1], G - mean_accel[2]], atol=1e-9)
    np.testing.assert_allclose(v.body_lp_m_s2, -F_BODY, atol=1e-9)  # the accelerometer's force, the same mean
    assert v.noise_var_m2_s4 == pytest.approx(2.0 * s * s / 0.6 ** 2, rel=1e-9)
    np.testing.assert_allclose(v.residual_lp_m_s2, [mean_accel[0] - ACCEL_M_S2, mean_accel[1], mean_accel[2]], atol=1e-9)
    assert v.residual_noise_var_m2_s4 == pytest.approx(2.0 * s * s / 0.6 ** 2, rel=1e-9)


def test_a_force_near_zero_shows_at_most_a_sine_of_one():
    """An accelerometer reading near 0 (2 % of the force here, against fixes that say otherwise; in free fall it
    reads 0) and a state 10 deg off: the residual across that tiny force over its length is 50 sin d, a sine of
    nothing; the excess is capped at 1 (sin^2 of 90 deg), never more (64 rad^2 without the cap)."""
    state, now = _accelerating(_tilted(10.0), 0.3, seconds=30.0, scale=0.02)
    assert attitude_excess_rad2(P.gnss, P.updates, state.velocity, now) == 1.0
