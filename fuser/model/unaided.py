"""What the accelerometer cannot tell from gravity without velocity aiding: the acceleration its norm reveals, the tilt its
corrections absorbed.

Without GNSS velocity (:mod:`fuser.model.velocity`) the gravity update takes
the low-passed specific force for down (:mod:`fuser.model.gravity`). In a
sustained level turn that low-pass does not average the centripetal
acceleration out: in a coordinated turn ``f = a_c - g`` with ``a_c``
horizontal, so the filter follows a down that is ``atan(|a_c| / g)`` off (the
bank angle, tens of degrees in a fixed-wing loiter), and nothing in its
innovations shows it: the accelerometer and the gyro agree. What does show it
is the norm: ``|f|^2 - g^2 = |a_c|^2`` for a horizontal acceleration.

A vertical acceleration ``a_v`` changes the norm too, but linearly and with
its sign (``|f|^2 - g^2 ~ -2 g a_v``), and no vehicle sustains one (a climb
rate cannot grow for ever), while a horizontal one adds a positive square
that a turn sustains. So the *signed* excess ``|f_lp|^2 - g^2`` of the
low-passed specific force is followed as the estimate follows the low-pass
(a first-order lag of the tilt time constant, gated readings included: a
reading gated for long is re-anchored to; at once while the update fuses raw
readings, its fast start, which the estimate follows within ticks; none once
the autopilot's attitude is fused, whose down is its own estimator's), so that the up-and-down of a hand-held or hovering sensor averages out and a
turn's steady excess remains. Only then is it read as a horizontal
acceleration, beyond the sensor's own norm and a tolerance: a sensor 1 % off
would otherwise read as an 8 deg turn, the angle growing as the square root
of the excess. The sensor's norm is learnt (:func:`learn_norm`) as the norm of
the specific force's long-run mean in the strapdown frame: the vehicle's
velocity is bounded, so its acceleration averages out of the mean (a circle
flown over and over too, as the mean is of the vector, not of its norm), and
gravity as this sensor reads it, scale error and bias included, remains.
Until it is, the tolerance is ``accel.unaided_norm_tolerance_fraction`` (turns
banked less than ``acos(1 / (1 + tolerance))`` stay unseen, 14 deg at the
default 3 %); once it is, ``accel.unaided_learnt_tolerance_fraction`` (0.5 %:
the norm changes with the orientation when the axes' scale errors differ) and
what a vertical speed change ``dv`` over the window ``T`` puts into the learnt
norm, ``2 g dv / T``. Learning may only reveal, never hide more than the
unlearnt tolerance: a window flown in a turn throughout (a start mid-turn)
learns the turn's norm, not the sensor's. On the simulated multirotor without GNSS (norm 1.8 %
high) the followed excess rose 2 m^2/s^4 above the learnt norm in the turns,
where the tilt error was 7 deg, which the 3 % hid entirely.

The published Bingham is widened in tilt by that angle
(:func:`fuser.model_error.published`), and in heading by what the tilt error
does to the magnetometer's heading: a down wrong by ``d`` about a horizontal
axis at ``a`` to the field's horizontal turns the field's projection by
``d tan(I) sin(a)`` (``I`` the field's inclination; ``tan I`` = 2 in central
Europe), ``d tan(I) / sqrt(2)`` in RMS over the axis, which the turn's
direction sets and the model does not know. An estimate that cannot see the
turn does not claim to.

**What the corrections absorbed.** The norm shows a sustained horizontal
acceleration; a transient one it shows only as the square of its size: a
multirotor accelerating at ``a`` tilts its thrust by ``atan(a / g)`` while the
norm grows by ``a^2 / 2g``, so a 5-deg error is a 0.4 % excess, within the
learnt tolerance. What does show it is where the estimate went. With an exact
gyro the tilt error the plain update takes from a false vertical is the sum of
its corrections: the estimate ``x`` follows the reference ``r = truth + a`` as
``x' = (a - x) / tau`` in the error, and the corrections are ``(a - x) dt /
tau``, which sum to ``x``. So the tick's correction (the posterior's mode
against the prediction's, world frame, north and east) is summed
(:func:`absorbed`), with a leak of ``accel.unaided_memory_time_constants`` tilt
time constants: a correction that cancels a residual gyro bias ``b`` instead
reads as ``b`` times that memory, where the lag it leaves is ``b tau``. The
leaked sum is the error high-passed; the part slower than the memory is the
sustained acceleration's, which the norm shows. The published tilt is the
larger of the two accounts, and the bias's tilt evidence counts it as noise
(:mod:`fuser.model.bias`): a turn's entry makes corrections that all point one
way in the body, as a bias's would, and taught the JSBSim Cessna's bias
2 deg/s at a 200 Hz loop, its estimate then 41 deg off in a 30-deg bank. Only
the plain update's converged corrections count (not the fast start's, not an
aided or the autopilot's attitude's, whose references are not the
accelerometer's); the autopilot's attitude clears the sum, and aided readings
shrink it by their gain as they do the excess (:func:`corrected`). On the
simulated multirotor without GNSS the 90 % region held the truth on 48 % of
ticks, 2.9 deg RMS off reporting 3.6; with it, 97 %, 2.4 deg off reporting 4.0
(``tests/test_fuser_gnss_flights.py``).

When GNSS velocity aiding starts (again) with an excess left, the tilt it
stands for is not gone: the aided readings pull the estimate back by their
gain, reading by reading (:func:`corrected`), and the widening shrinks only as
fast. After a saturated gyro in a 20-deg banked turn (``tests/fault_flights.py``)
the estimate is 15 deg off for 3 s while the first aided readings, noisy, count
for little; it reported 5 deg before this, 12-15 deg with it.

Compiled (numba) for the tick (:mod:`fuser.model.fusion`): the memory is the
``unaided`` part of the state record (:data:`fuser.model.state.UNAIDED`),
changed in place; ``params`` is the ``accel`` group of :mod:`fuser.model.params`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.quaternion_kernels import from_array, rotation_rows, rotvec_between_world
from fuser.model import vec3

__all__ = ["absorbed", "cleared", "corrected", "excess_norm_sq_m2_s4", "followed", "heading_through_dip_rad2", "learn_norm", "unaided_target",
           "unseen_variances_rad2"]


@njit(cache=True, nogil=True)
def excess_norm_sq_m2_s4(params: np.record, has_lowpassed: bool, lowpassed_m_s2: tuple) -> float:
    """``|f_lp|^2 - g^2`` of the low-passed specific force, signed (0 with no low-pass yet: ``has_lowpassed`` False)."""
    if not has_lowpassed:
        return 0.0
    x, y, z = lowpassed_m_s2
    g = params.gravity_m_s2
    return (x * x + y * y + z * z) - g * g


@njit(cache=True, nogil=True)
def learn_norm(params: np.record, unaided: np.record, gravity: np.record, accel_body_m_s2: tuple, interval_s: float,
               frame_broken: bool) -> None:
    """The sensor's own norm, learnt: the tick's mean specific force (body frame), turned into the strapdown
    frame, into the long-run mean (a growing window up to ``accel.unaided_norm_window_s``, then a low-pass of
    that time constant), with or without GNSS. A gyro gap breaks the frame: the mean's direction in it is lost,
    its norm (the sensor's) is not, so the mean is kept along the last measured down (``gravity.down_body``)
    and learns again from the next tick."""
    to_s = rotation_rows(from_array(gravity.q_strapdown))
    if unaided.has_norm_mean and frame_broken:
        norm = vec3.norm(vec3.load(unaided.norm_mean_m_s2))
        dx, dy, dz = vec3.load(gravity.down_body)
        vec3.store(unaided.norm_mean_m_s2, vec3.mat_vec(to_s, (-norm * dx, -norm * dy, -norm * dz)))
        return
    f_s = vec3.mat_vec(to_s, accel_body_m_s2)
    if not unaided.has_norm_mean:
        unaided.has_norm_mean = True
        vec3.store(unaided.norm_mean_m_s2, f_s)
        unaided.norm_mean_s = interval_s
        return
    seconds = unaided.norm_mean_s + interval_s
    alpha = interval_s / min(seconds, params.unaided_norm_window_s)
    vec3.store(unaided.norm_mean_m_s2, vec3.toward(vec3.load(unaided.norm_mean_m_s2), f_s, alpha))
    unaided.norm_mean_s = seconds


@njit(cache=True, nogil=True)
def _baseline_m2_s4(params: np.record, unaided: np.record) -> float:
    """``|f|^2 - g^2`` of gravity as the sensor reads it (0 until learnt)."""
    return excess_norm_sq_m2_s4(params, unaided.has_norm_mean, vec3.load(unaided.norm_mean_m_s2))


@njit(cache=True, nogil=True)
def _scale_error_m2_s4(params: np.record, fraction: float) -> float:
    """The excess ``|f|^2 - g^2`` a norm ``fraction`` too high makes: ``((1 + fraction)^2 - 1) g^2``."""
    g = params.gravity_m_s2
    return ((1.0 + fraction) * (1.0 + fraction) - 1.0) * (g * g)


@njit(cache=True, nogil=True)
def _allowed_m2_s4(params: np.record, unaided: np.record) -> float:
    """The excess over the baseline the sensor itself may make: ``((1 + t)^2 - 1) g^2`` for its scale error ``t``
    (``accel.unaided_norm_tolerance_fraction`` until its norm is learnt), and, while the window is short, what a
    vertical speed change ``dv`` over it (``accel.unaided_speed_change_m_s``) puts into the learnt norm, ``2 g dv / T``."""
    g = params.gravity_m_s2
    initial = _scale_error_m2_s4(params, params.unaided_norm_tolerance_fraction)
    if not unaided.has_norm_mean:
        return initial
    window_s = min(unaided.norm_mean_s, params.unaided_norm_window_s)
    learnt = _scale_error_m2_s4(params, params.unaided_learnt_tolerance_fraction) + 2.0 * g * params.unaided_speed_change_m_s / window_s
    return min(initial, learnt)


@njit(cache=True, nogil=True)
def _hidden_m2_s4(params: np.record, unaided: np.record) -> float:
    """The largest excess read as no acceleration: the learnt norm's plus its tolerance, never more than the
    unlearnt tolerance's alone. Learning the norm may only reveal: a window flown in a turn throughout (a start
    mid-turn, a long loiter) learns the turn's norm, not the sensor's, and must not hide the turn."""
    return min(_scale_error_m2_s4(params, params.unaided_norm_tolerance_fraction), _baseline_m2_s4(params, unaided) + _allowed_m2_s4(params, unaided))


@njit(cache=True, nogil=True)
def _nothing_unseen_m2_s4(params: np.record, unaided: np.record) -> float:
    """The excess of no unseen acceleration: the learnt norm's, or the largest hidden one if that is smaller."""
    return min(_baseline_m2_s4(params, unaided), _hidden_m2_s4(params, unaided))


@njit(cache=True, nogil=True)
def unaided_target(params: np.record, gravity: np.record, interval_s: float, tau_s: float) -> tuple:
    """(target, time constant): what the excess follows this tick without GNSS aiding, and with which time constant:
    the low-passed reading's with the tilt time constant ``tau_s`` while the plain gravity update uses the low-pass;
    while it uses raw readings (its fast start, again after a gyro gap or saturation broke the strapdown frame) their
    mean's at once: the estimate follows them within ticks, in a turn straight to the bank's tilt (:mod:`fuser.model.gravity`)."""
    if not gravity.has_accel_lp:
        return excess_norm_sq_m2_s4(params, gravity.has_raw_mean, vec3.load(gravity.raw_mean_m_s2)), interval_s
    return excess_norm_sq_m2_s4(params, gravity.has_accel_lp, vec3.load(gravity.accel_lp_m_s2)), tau_s  # has_accel_lp: True here


@njit(cache=True, nogil=True)
def followed(params: np.record, unaided: np.record, target_m2_s4: float, interval_s: float, tau_s: float) -> None:
    """The followed excess after ``interval_s`` more of following ``target_m2_s4`` with the time constant
    ``tau_s`` (a first-order lag, as the estimate follows its low-pass), never below the baseline minus the
    tolerance: a norm persistently low (the strapdown frame turning with an unlearnt bias) must not hide a turn."""
    lagged = unaided.excess_m2_s4 + min(1.0, interval_s / tau_s) * (target_m2_s4 - unaided.excess_m2_s4)
    floor = _baseline_m2_s4(params, unaided) - _allowed_m2_s4(params, unaided)
    unaided.excess_m2_s4 = max(lagged, floor)


@njit(cache=True, nogil=True)
def cleared(params: np.record, unaided: np.record) -> None:
    """No unseen acceleration, nothing absorbed: the autopilot's attitude was fused, whose down is its own estimator's."""
    unaided.excess_m2_s4 = _nothing_unseen_m2_s4(params, unaided)
    unaided.absorbed_rad[0], unaided.absorbed_rad[1] = 0.0, 0.0


@njit(cache=True, nogil=True)
def absorbed(params: np.record, unaided: np.record, interval_s: float, tau_s: float, has_correction: bool, predicted_q: tuple,
             posterior_q: tuple) -> None:
    """The tilt the plain gravity update's corrections have moved the estimate by, ``interval_s`` later: the
    world-frame rotation of this tick's correction (``has_correction``: the plain update corrected the predicted mode
    ``predicted_q`` into the posterior's ``posterior_q``; False: no plain correction this tick), north and east added
    to the sum, which leaks with ``accel.unaided_memory_time_constants`` tilt time constants ``tau_s`` (module
    docstring)."""
    keep = 1.0 - min(1.0, interval_s / (params.unaided_memory_time_constants * tau_s))
    north, east = keep * unaided.absorbed_rad[0], keep * unaided.absorbed_rad[1]
    if has_correction:
        turn = rotvec_between_world(predicted_q, posterior_q)
        north, east = north + turn[0], east + turn[1]
    unaided.absorbed_rad[0], unaided.absorbed_rad[1] = north, east


@njit(cache=True, nogil=True)
def corrected(params: np.record, unaided: np.record, prior_tilt_deg: float, sigma_rad: float, bound_rad: float) -> None:
    """The excess after a GNSS-aided gravity reading of sigma ``sigma_rad`` is fused: the tilt it stood for shrinks
    as the estimate is corrected, by the reading's gain ``k = p / (p + sigma^2)`` per axis (``p`` the prior's per-axis
    tilt variance, half ``prior_tilt_deg`` squared; the Bingham product moves the mode by that share of the
    innovation, QBF paper, sec. 5), not faster: after a turn flown unaided the aided readings need seconds to pull the
    tilt back, and the estimate is as far off meanwhile as it was. Nor is it larger than the reading allows
    (``bound_rad``: its innovation plus twice its noise), which the excess cannot tell from a vertical acceleration (a
    take-off). The tilt absorbed before the aiding (:func:`absorbed`) shrinks alike."""
    prior_tilt_rad = math.radians(prior_tilt_deg)
    prior = 0.5 * (prior_tilt_rad * prior_tilt_rad)
    keep = 1.0 - (prior / (prior + sigma_rad * sigma_rad) if prior > 0.0 else 0.0)
    north, east = unaided.absorbed_rad[0], unaided.absorbed_rad[1]
    absorbed_rad = math.hypot(north, east)
    shrink = min(keep, bound_rad / absorbed_rad) if absorbed_rad > 0.0 else 0.0
    tilt_rad = _unseen_tilt_rad(params, unaided)
    if tilt_rad == 0.0:  # the aided reading takes out what the excess within the tolerance may have been
        unaided.excess_m2_s4 = min(unaided.excess_m2_s4, _nothing_unseen_m2_s4(params, unaided))
    else:
        tilt_rad = min(keep * tilt_rad, bound_rad)
        horizontal_m_s2 = params.gravity_m_s2 * math.tan(tilt_rad)
        unaided.excess_m2_s4 = _hidden_m2_s4(params, unaided) + horizontal_m_s2 * horizontal_m_s2
    unaided.absorbed_rad[0], unaided.absorbed_rad[1] = shrink * north, shrink * east


@njit(cache=True, nogil=True)
def _unseen_tilt_rad(params: np.record, unaided: np.record) -> float:
    """The tilt the excess beyond the hidden one (:func:`_hidden_m2_s4`), read as a horizontal acceleration, makes:
    ``atan(|a_h| / g)``."""
    horizontal_sq_m2_s4 = unaided.excess_m2_s4 - _hidden_m2_s4(params, unaided)
    return math.atan2(math.sqrt(horizontal_sq_m2_s4), params.gravity_m_s2) if horizontal_sq_m2_s4 > 0.0 else 0.0


@njit(cache=True, nogil=True)
def unseen_variances_rad2(params: np.record, unaided: np.record, heading_measured: bool, field_ned_gauss: tuple) -> tuple:
    """(tilt, heading) variances, rad^2 per axis, of the down the followed excess, read as a horizontal
    acceleration beyond the tolerance, biases, or of the tilt the corrections absorbed (:func:`absorbed`), whichever
    is larger (two accounts of one error: the sustained acceleration and the transient); the heading's through the
    field's inclination (:func:`heading_through_dip_rad2`). The absorbed tilt's direction is known, but the
    per-axis variance is counted on both horizontal axes."""
    north, east = unaided.absorbed_rad[0], unaided.absorbed_rad[1]
    unseen_rad = _unseen_tilt_rad(params, unaided)
    tilt_rad2 = max(unseen_rad * unseen_rad, north * north + east * east)
    return tilt_rad2, heading_through_dip_rad2(tilt_rad2, heading_measured, field_ned_gauss)


@njit(cache=True, nogil=True)
def heading_through_dip_rad2(tilt_rad2: float, heading_measured: bool, field_ned_gauss: tuple) -> float:
    """Heading variance (rad^2) a tilt error of per-axis variance ``tilt_rad2`` makes through the magnetometer: a down
    wrong by ``d`` turns the field's horizontal projection by ``d tan(I) sin(a)`` (module docstring), ``tan(I)^2 / 2``
    times the tilt's variance over the axis (``I`` the reference field ``field_ned_gauss``'s inclination;
    ``heading_measured`` False: no magnetometer heading, none)."""
    if tilt_rad2 == 0.0 or not heading_measured:
        return 0.0
    north, east, down = field_ned_gauss
    field_horizontal_sq = north * north + east * east
    tan_sq = down * down / field_horizontal_sq if field_horizontal_sq > 0.0 else math.inf
    return min(0.5 * tilt_rad2 * tan_sq, math.pi * math.pi)
