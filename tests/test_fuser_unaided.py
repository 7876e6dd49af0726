"""The tilt error an unaided accelerometer cannot see, against the closed form of a coordinated turn.

In a level coordinated turn banked ``phi`` the specific force is ``g / cos(phi)`` along the body's down axis, so the
low-passed down is ``phi`` off the true one: with no tolerance the unseen angle must be exactly ``phi``; within the
tolerance (the accelerometer's own scale error) nothing; a vertical acceleration that comes and goes averages out of
the followed (signed) excess while a turn's stays; the heading's share follows the field's inclination (``tan I / sqrt 2`` in RMS over the tilt's axis)."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import pytest

from core import quaternion as quat
from fuser.config import FuserConfig
from fuser.model.gravity import turn_frame, update_gravity
from fuser.model.tick import TickContext
from fuser.model.unaided import absorbed, cleared, corrected, excess_norm_sq_m2_s4, followed, learn_norm, unaided_target, unseen_variances_rad2
from model_records import params as parameters, part, set_fields

G = 9.80665
LEVEL = tuple(quat.IDENTITY)
ZERO = (0.0, 0.0, 0.0)
NO_FIELD = (False, ZERO)
"""No magnetometer heading (``heading_measured`` False and no reference field)."""


def _accel(**settings: float) -> np.record:
    """The ``accel`` parameters, the defaults but ``settings`` (``AccelSettings(**settings)``)."""
    return parameters(FuserConfig().replace(accel=settings)).accel


def _after(function: Callable, params: np.record, state: np.record, *args) -> np.record:
    """A copy of ``state`` after ``function(params, copy, *args)``, which changes it in place (``state`` unchanged)."""
    copy = state.copy()
    function(params, copy, *args)
    return copy


def _turn_specific_force(bank_deg: float) -> np.ndarray:
    """Specific force in a level coordinated turn (inertial frame, NED): centripetal acceleration east, gravity up."""
    return np.array([0.0, G * math.tan(math.radians(bank_deg)), -G])


def _u(excess_m2_s4: float) -> np.record:
    """An excess with no learnt norm (the tolerance alone)."""
    return part("unaided", excess_m2_s4=excess_m2_s4)


def _excess(params: np.record, f: np.ndarray) -> float:
    """``excess_norm_sq_m2_s4`` of a low-passed specific force ``f`` (there is one)."""
    return excess_norm_sq_m2_s4(params, True, tuple(f))


def _unseen_tilt_deg(params: np.record, f: np.ndarray, field=None) -> float:
    heading = NO_FIELD if field is None else (True, field)
    return math.degrees(math.sqrt(unseen_variances_rad2(params, _u(_excess(params, f)), *heading)[0]))


@pytest.mark.parametrize("bank_deg", [5.0, 20.0, 30.0, 45.0, 60.0])
def test_without_tolerance_the_unseen_angle_is_the_bank(bank_deg):
    params = _accel(unaided_norm_tolerance_fraction=0.0)
    f = _turn_specific_force(bank_deg)
    assert np.linalg.norm(f) == pytest.approx(G / math.cos(math.radians(bank_deg)))
    assert _unseen_tilt_deg(params, f) == pytest.approx(bank_deg, abs=1e-9)


def test_the_tolerance_hides_shallow_turns_and_trims_steep_ones():
    params = _accel()  # 3 %: turns banked less than acos(1 / 1.03) = 13.9 deg stay unseen
    assert math.degrees(math.acos(1 / 1.03)) == pytest.approx(13.86, abs=0.01)
    assert _unseen_tilt_deg(params, _turn_specific_force(13.0)) == 0.0
    # at 30 deg: |a|^2 = g^2 (1/cos^2 30 - 1.03^2) = g^2 (4/3 - 1.0609)
    expected = math.degrees(math.atan(math.sqrt(4 / 3 - 1.0609)))
    assert _unseen_tilt_deg(params, _turn_specific_force(30.0)) == pytest.approx(expected, abs=1e-9)
    assert 27.0 < expected < 30.0
    # gravity alone (hover), a low-pass not started yet, and less than g (free fall) are no turn
    assert _unseen_tilt_deg(params, np.array([0.0, 0.0, -G])) == 0.0
    assert excess_norm_sq_m2_s4(params, False, ZERO) == 0.0
    assert _unseen_tilt_deg(params, np.array([0.0, 0.0, -0.5 * G])) == 0.0


def test_a_vertical_acceleration_that_comes_and_goes_averages_out_and_a_turn_stays():
    params, tau, dt = _accel(), 3.0, 0.01
    bobbing, turning = _u(0.0), _u(0.0)
    for k in range(3000):  # 30 s: +-1.5 m/s^2 up and down at 0.5 Hz, against a steady 30 deg turn
        a_up = 1.5 * math.sin(2 * math.pi * 0.5 * k * dt)
        followed(params, bobbing, _excess(params, np.array([0.0, 0.0, -G - a_up])), dt, tau)
        followed(params, turning, _excess(params, _turn_specific_force(30.0)), dt, tau)
    assert unseen_variances_rad2(params, bobbing, *NO_FIELD) == (0.0, 0.0)
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, turning, *NO_FIELD)[0])) > 27.0
    # the instantaneous excess of the bobbing alone would have claimed a turn
    assert _unseen_tilt_deg(params, np.array([0.0, 0.0, -G - 1.5])) > 20.0


def test_the_excess_is_followed_with_a_first_order_lag_and_a_floor():
    params, tau, dt, target = _accel(), 3.0, 0.01, 25.0
    v = _u(0.0)
    for _ in range(300):
        followed(params, v, target, dt, tau)
    assert v.excess_m2_s4 == pytest.approx(target * (1 - (1 - dt / tau) ** 300), rel=1e-12)
    assert _after(followed, params, v, target, 10.0, tau).excess_m2_s4 == target  # an interval longer than tau lands on the target
    # a norm persistently low sits at minus the tolerance's excess, not below: a turn after it shows within ~tau
    allowed = (1.03**2 - 1.0) * G * G
    low = _after(followed, params, _u(0.0), -50.0, 10.0, tau)
    assert low.excess_m2_s4 == pytest.approx(-allowed)


def test_the_heading_share_follows_the_inclination():
    params = _accel(unaided_norm_tolerance_fraction=0.0)
    excess = _u((G * math.tan(math.radians(10.0))) ** 2)  # a 10 deg turn
    tilt = math.radians(10.0) ** 2
    assert unseen_variances_rad2(params, excess, True, (0.2, 0.0, 0.4)) == pytest.approx((tilt, 2.0 * tilt))  # tan I = 2: 4 / 2
    assert unseen_variances_rad2(params, excess, True, (0.15, 0.15, 0.0)) == pytest.approx((tilt, 0.0))  # horizontal field
    assert unseen_variances_rad2(params, excess, *NO_FIELD) == pytest.approx((tilt, 0.0))  # no magnetometer heading
    assert unseen_variances_rad2(params, excess, True, (0.0, 0.0, 0.5))[1] == pytest.approx(math.pi**2)  # at the pole


def _excess_for_unseen_tilt(params: np.record, tilt_deg: float) -> float:
    """The excess whose unseen tilt is ``tilt_deg``: the tolerance's ``((1 + t)^2 - 1) g^2`` plus ``(g tan tilt)^2``."""
    allowed = ((1.0 + params.unaided_norm_tolerance_fraction) ** 2 - 1.0) * G**2
    return allowed + (G * math.tan(math.radians(tilt_deg))) ** 2


def test_an_aided_reading_shrinks_the_unseen_tilt_by_its_own_gain():
    """After a turn flown unaided, a GNSS-aided reading corrects the estimate by its gain ``k = p / (p + s^2)``
    per axis (prior tilt 10 deg RMS over two axes: ``p`` = 50 deg^2; sigma 5 deg: ``k`` = 2/3), so a 30-deg unseen
    tilt is 10 deg after it, and 10 / 3 after a second; a prior sure of itself (sigma huge) corrects nothing; and never more
    than the reading's innovation and noise allow."""
    params = _accel()
    five_deg = math.radians(5.0)  # the reading's sigma (corrected takes radians)
    excess = _u(_excess_for_unseen_tilt(params, 30.0))
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, excess, *NO_FIELD)[0])) == pytest.approx(30.0, abs=1e-9)
    once = _after(corrected, params, excess, 10.0, five_deg, math.pi)
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, once, *NO_FIELD)[0])) == pytest.approx(10.0, abs=1e-9)
    twice = _after(corrected, params, once, 10.0, five_deg, math.pi)
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, twice, *NO_FIELD)[0])) == pytest.approx(10.0 / 3.0, abs=1e-9)
    # an aided reading whose innovation and noise allow 4 deg at most: what the excess stood for was no tilt
    bounded = _after(corrected, params, excess, 10.0, five_deg, math.radians(4.0))
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, bounded, *NO_FIELD)[0])) == pytest.approx(4.0, abs=1e-9)
    assert _after(corrected, params, excess, 10.0, math.radians(1e6), math.pi).excess_m2_s4 == pytest.approx(excess.excess_m2_s4, rel=1e-6)
    # an excess within the tolerance stays unseen (at most the tolerance's, never negative growth)
    assert unseen_variances_rad2(params, _after(corrected, params, _u(-1.0), 10.0, five_deg, math.pi), *NO_FIELD) == (0.0, 0.0)


def _gravity_tick(state: np.record, f_body: np.ndarray, prior_doubt_deg: float, interval_s: float = 0.01) -> np.record:
    """A copy of the gravity ``state`` after one plain update (default parameters, level, no GNSS)."""
    tick = TickContext(dt_s=interval_s, process_variance_rad2=1e-6, prior_doubt_deg=prior_doubt_deg, prior_tilt_doubt_deg=prior_doubt_deg)
    after = state.copy()
    p = parameters()
    update_gravity(p.accel, p.updates, after, tick, tuple(f_body), 3.0, LEVEL, interval_s, True, False, ZERO, 0.0)
    return after


def test_raw_readings_are_followed_at_once_and_the_low_pass_starts_from_their_mean():
    """The fast start (prior doubt above ``updates.converged_deg``) fuses raw readings: in a 30-deg turn each is
    the turn's specific force, so the unseen tilt is the turn's at once (no tilt time constant: the estimate
    follows raw readings within ticks), and at convergence the low-pass starts from their time-weighted mean
    (hand-computed), not from ``-g`` along the estimate's down, which would hide the turn's norm."""
    params = _accel(unaided_norm_tolerance_fraction=0.0)
    f1, f2 = _turn_specific_force(30.0), _turn_specific_force(20.0)
    first = _gravity_tick(part("gravity"), f1, 40.0, 0.01)
    second = _gravity_tick(first, f2, 40.0, 0.03)
    assert not second.has_accel_lp and second.raw_s == pytest.approx(0.04)
    np.testing.assert_allclose(second.raw_mean_m_s2, 0.25 * f1 + 0.75 * f2, atol=1e-12)
    target, follow_s = unaided_target(params, first, 0.01, 3.0)
    assert follow_s == 0.01
    following = _after(followed, params, _u(0.0), target, 0.01, follow_s)
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, following, *NO_FIELD)[0])) == pytest.approx(30.0, abs=1e-9)
    converged = _gravity_tick(second, f1, 1.0, 0.01)  # alpha = 0.01 / 3
    np.testing.assert_allclose(converged.accel_lp_m_s2, second.raw_mean_m_s2 + (0.01 / 3.0) * (f1 - second.raw_mean_m_s2), atol=1e-12)
    assert not converged.has_raw_mean
    # a gyro gap breaks the frame: the low-pass and the raw readings' mean are dropped alike (no rotation known: identity)
    broken = second.copy()
    turn_frame(broken, False, LEVEL, 0.005)
    assert not broken.has_raw_mean and broken.raw_s == 0.0 and not broken.converged
    kept = second.copy()
    turn_frame(kept, False, LEVEL, 0.0)
    np.testing.assert_array_equal(kept.raw_mean_m_s2, second.raw_mean_m_s2)


def test_the_sensors_own_norm_is_learnt_and_a_turn_is_seen_beyond_it():
    """A sensor reading 1 % high (``|f| = 1.01 g`` at rest) is within the 3 % tolerance of an unlearnt norm, which
    hides a 10-deg turn. After 60 s its norm is learnt as the norm of the mean specific force (hand-computed:
    the mean of a constant is itself, and of a turn flown in a full circle the gravity alone), and beyond it only
    the learnt tolerance stays: ``((1.005)^2 - 1) g^2 + 2 g dv / T`` (0.5 %, 1 m/s over 60 s), hand-computed."""
    params = _accel()
    scale = 1.01
    gravity = part("gravity")  # identity strapdown frame: body = S
    at_rest = np.array([0.0, 0.0, -scale * G])
    state = part("unaided")
    for _ in range(6000):
        learn_norm(params, state, gravity, tuple(at_rest), 0.01, False)
    np.testing.assert_allclose(state.norm_mean_m_s2, at_rest, rtol=1e-12)
    assert state.norm_mean_s == pytest.approx(60.0)
    # a turn banked 10 deg, its norm seen by the same sensor: beyond the learnt norm by (scale g)^2 tan^2(10 deg)
    turn = scale * _turn_specific_force(10.0)
    excess = _excess(params, turn)
    allowed = (1.005**2 - 1.0) * G**2 + 2.0 * G * 1.0 / 60.0
    hidden = (scale * G * math.tan(math.radians(10.0))) ** 2 - allowed
    learnt = set_fields(state.copy(), excess_m2_s4=excess)
    expected = math.degrees(math.atan2(math.sqrt(hidden), G))
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, learnt, *NO_FIELD)[0])) == pytest.approx(expected, abs=1e-9)
    assert 7.5 < expected < 8.0  # 7.7 deg of the 10 seen
    assert unseen_variances_rad2(params, _u(excess), *NO_FIELD) == (0.0, 0.0)  # unlearnt: within 3 %, unseen
    # the autopilot's attitude fused: nothing unseen; a broken frame keeps the learnt norm, along the last down
    assert unseen_variances_rad2(params, _after(cleared, params, learnt), *NO_FIELD) == (0.0, 0.0)
    tilted = part("gravity", down_body=np.array([0.0, math.sin(0.3), math.cos(0.3)]))
    kept = _after(learn_norm, params, state, tilted, tuple(turn), 0.01, True)
    np.testing.assert_allclose(kept.norm_mean_m_s2, -scale * G * tilted.down_body, rtol=1e-12)
    assert kept.norm_mean_s == state.norm_mean_s


def test_the_learnt_norm_is_a_mean_in_the_strapdown_frame():
    """A circle flown at constant speed: the centripetal acceleration turns with the flight and averages out of
    the strapdown-frame mean over whole circles, leaving gravity's norm; the mean of the norms would not."""
    params = _accel()
    gravity, state, dt = part("gravity"), part("unaided"), 0.01
    a, omega = 3.0, 2.0 * math.pi / 10.0  # 3 m/s^2, one circle per 10 s; six circles
    for k in range(6000):
        heading = omega * k * dt
        f = (a * math.cos(heading), a * math.sin(heading), -G)
        learn_norm(params, state, gravity, f, dt, False)
    assert np.linalg.norm(state.norm_mean_m_s2) == pytest.approx(G, rel=2e-3)
    assert math.hypot(a, G) > 1.04 * G


def test_a_norm_learnt_in_a_turn_does_not_hide_it():
    """Started in a sustained 30-deg turn, the first minute's mean specific force is the turn's, not gravity's (the
    circle is far from closed): learnt as the sensor's norm it would read the turn as no acceleration. Learning may
    only reveal: the unseen tilt is at least what the unlearnt 3 % tolerance leaves, ``atan(sqrt(4/3 - 1.0609))``."""
    params = _accel()
    turn = _turn_specific_force(30.0)
    state = part("unaided")
    for _ in range(6000):
        learn_norm(params, state, part("gravity"), tuple(turn), 0.01, False)
    in_turn = set_fields(state.copy(), excess_m2_s4=_excess(params, turn))
    expected = math.degrees(math.atan(math.sqrt(4 / 3 - 1.0609)))
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, in_turn, *NO_FIELD)[0])) == pytest.approx(expected, abs=1e-9)
    assert unseen_variances_rad2(params, _after(cleared, params, in_turn), *NO_FIELD) == (0.0, 0.0)


def _about(axis, angle_rad: float) -> np.ndarray:
    return quat.from_axis_angle(np.asarray(axis, dtype=float), angle_rad)


def test_the_absorbed_corrections_sum_to_the_error_a_false_vertical_left():
    """A first-order tilt correction (time constant tau) following a down that is 5 deg off for 2 s (a multirotor's
    acceleration) and then right again, with an exact gyro: the estimate's error is the sum of its corrections
    (x' = (a - x) / tau, so x(t) = integral of the corrections). With a memory far longer than the flight the
    absorbed tilt is that error at every tick; with the default memory (2 tau) it is the error high-passed,
    ``x - LP_{2 tau}(x)``, computed here in closed form beside it."""
    tau, dt = 3.0, 0.01
    long_memory = _accel(unaided_memory_time_constants=1e9)
    default = _accel()
    state_long, state_default = part("unaided"), part("unaided")
    x, low = 0.0, 0.0  # the error (rad, about north) and its low-pass over the default memory
    for k in range(800):
        false_vertical = math.radians(5.0) if k < 200 else 0.0
        x_next = x + (false_vertical - x) * dt / tau
        correction = (True, tuple(_about([1, 0, 0], x)), tuple(_about([1, 0, 0], x_next)))
        absorbed(long_memory, state_long, dt, tau, *correction)
        absorbed(default, state_default, dt, tau, *correction)
        low = low + (x_next - low) * dt / (default.unaided_memory_time_constants * tau)
        x = x_next
        assert state_long.absorbed_rad[0] == pytest.approx(x, abs=1e-9) and state_long.absorbed_rad[1] == pytest.approx(0.0, abs=1e-12)
        assert state_default.absorbed_rad[0] == pytest.approx(x - low, abs=2e-4)
    # the error outlives the false vertical by far (its closed form: 5 (1 - e^(-2/3)) e^(-6/3) deg), and so does its account
    assert math.degrees(x) == pytest.approx(5.0 * (1.0 - math.exp(-2.0 / 3.0)) * math.exp(-2.0), rel=1e-2)


def test_the_memory_leaks_a_steady_correction_to_its_closed_form():
    """A steady correction ``c`` per tick (a residual bias ``b``, ``c = b dt``) sums to the geometric series'
    limit ``c / (1 - keep)``, ``keep = 1 - dt / (K tau)``: ``b K tau``, the bias times the memory. A correction
    about east lands east, with its sign; one about down (a heading correction) adds nothing."""
    params, tau, dt, b = _accel(), 3.0, 0.01, math.radians(0.5)
    state = part("unaided")
    east_turn = (tuple(_about([0, 1, 0], 0.3)), tuple(_about([0, 1, 0], 0.3 - b * dt)))
    heading_turn = (tuple(_about([0, 0, 1], 1.0)), tuple(_about([0, 0, 1], 1.2)))
    for _ in range(20000):
        absorbed(params, state, dt, tau, True, *east_turn)
        absorbed(params, state, 0.0, tau, True, *heading_turn)
    assert state.absorbed_rad[1] == pytest.approx(-b * params.unaided_memory_time_constants * tau, rel=1e-6)
    assert state.absorbed_rad[0] == pytest.approx(0.0, abs=1e-12)
    leaked = _after(absorbed, params, state, dt, tau, False, LEVEL, LEVEL)  # no correction this tick
    assert leaked.absorbed_rad[1] == pytest.approx(state.absorbed_rad[1] * (1 - dt / (2 * tau)))


def test_the_published_tilt_is_the_larger_account_and_the_heading_follows_it():
    params, field = _accel(unaided_norm_tolerance_fraction=0.0), (0.2, 0.0, 0.4)  # tan I = 2
    turn = _u(_excess(params, _turn_specific_force(10.0)))
    small, large = math.radians(3.0), math.radians(20.0)
    for north, east in ((small, 0.0), (0.0, large)):
        state = set_fields(turn.copy(), absorbed_rad=(north, east))
        tilt, heading = unseen_variances_rad2(params, state, True, field)
        expected = max(math.radians(10.0), math.hypot(north, east))
        assert math.sqrt(tilt) == pytest.approx(expected, rel=1e-9)
        assert heading == pytest.approx(0.5 * expected**2 * 4.0, rel=1e-9)


def test_aided_readings_shrink_the_absorbed_tilt_by_their_gain_and_bound():
    params = _accel()
    state = part("unaided", absorbed_rad=(math.radians(6.0), math.radians(8.0)))  # 10 deg
    prior_deg, sigma_deg = 2.0, 1.0
    prior = 0.5 * math.radians(prior_deg) ** 2
    keep = 1.0 - prior / (prior + math.radians(sigma_deg) ** 2)  # the product's gain (QBF paper, sec. 5)
    shrunk = _after(corrected, params, state, prior_deg, math.radians(sigma_deg), math.pi)
    assert tuple(shrunk.absorbed_rad) == pytest.approx((keep * math.radians(6.0), keep * math.radians(8.0)), rel=1e-12)
    bounded = _after(corrected, params, state, prior_deg, math.radians(sigma_deg), math.radians(1.0))
    assert math.hypot(*bounded.absorbed_rad) == pytest.approx(math.radians(1.0), rel=1e-12)
    assert tuple(_after(cleared, params, state).absorbed_rad) == (0.0, 0.0)
