"""The tilt error an unaided accelerometer cannot see, against the closed form of a coordinated turn.

In a level coordinated turn banked ``phi`` the specific force is ``g / cos(phi)`` along the body's down axis, so the
low-passed down is ``phi`` off the true one: with no tolerance the unseen angle must be exactly ``phi``; within the
tolerance (the accelerometer's own scale error) nothing; a vertical acceleration that comes and goes averages out of
the followed (signed) excess while a turn's stays; the heading's share follows the field's inclination (``tan I / sqrt 2`` in RMS over the tilt's axis)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fuser.config import AccelSettings
from fuser.model.unaided import excess_norm_sq_m2_s4, followed, unseen_variances_rad2

G = 9.80665


def _turn_specific_force(bank_deg: float) -> np.ndarray:
    """Specific force in a level coordinated turn (inertial frame, NED): centripetal acceleration east, gravity up."""
    return np.array([0.0, G * math.tan(math.radians(bank_deg)), -G])


def _unseen_tilt_deg(params: AccelSettings, f: np.ndarray, field=None) -> float:
    return math.degrees(math.sqrt(unseen_variances_rad2(params, excess_norm_sq_m2_s4(params, f), field)[0]))


@pytest.mark.parametrize("bank_deg", [5.0, 20.0, 30.0, 45.0, 60.0])
def test_without_tolerance_the_unseen_angle_is_the_bank(bank_deg):
    params = AccelSettings(unaided_norm_tolerance_fraction=0.0)
    f = _turn_specific_force(bank_deg)
    assert np.linalg.norm(f) == pytest.approx(G / math.cos(math.radians(bank_deg)))
    assert _unseen_tilt_deg(params, f) == pytest.approx(bank_deg, abs=1e-9)


def test_the_tolerance_hides_shallow_turns_and_trims_steep_ones():
    params = AccelSettings()  # 3 %: turns banked less than acos(1 / 1.03) = 13.9 deg stay unseen
    assert math.degrees(math.acos(1 / 1.03)) == pytest.approx(13.86, abs=0.01)
    assert _unseen_tilt_deg(params, _turn_specific_force(13.0)) == 0.0
    # at 30 deg: |a|^2 = g^2 (1/cos^2 30 - 1.03^2) = g^2 (4/3 - 1.0609)
    expected = math.degrees(math.atan(math.sqrt(4 / 3 - 1.0609)))
    assert _unseen_tilt_deg(params, _turn_specific_force(30.0)) == pytest.approx(expected, abs=1e-9)
    assert 27.0 < expected < 30.0
    # gravity alone (hover), a low-pass not started yet, and less than g (free fall) are no turn
    assert _unseen_tilt_deg(params, np.array([0.0, 0.0, -G])) == 0.0
    assert excess_norm_sq_m2_s4(params, None) == 0.0
    assert _unseen_tilt_deg(params, np.array([0.0, 0.0, -0.5 * G])) == 0.0


def test_a_vertical_acceleration_that_comes_and_goes_averages_out_and_a_turn_stays():
    params, tau, dt = AccelSettings(), 3.0, 0.01
    bobbing = turning = 0.0
    for k in range(3000):  # 30 s: +-1.5 m/s^2 up and down at 0.5 Hz, against a steady 30 deg turn
        a_up = 1.5 * math.sin(2 * math.pi * 0.5 * k * dt)
        bobbing = followed(params, bobbing, excess_norm_sq_m2_s4(params, np.array([0.0, 0.0, -G - a_up])), dt, tau)
        turning = followed(params, turning, excess_norm_sq_m2_s4(params, _turn_specific_force(30.0)), dt, tau)
    assert unseen_variances_rad2(params, bobbing, None) == (0.0, 0.0)
    assert math.degrees(math.sqrt(unseen_variances_rad2(params, turning, None)[0])) > 27.0
    # the instantaneous excess of the bobbing alone would have claimed a turn
    assert _unseen_tilt_deg(params, np.array([0.0, 0.0, -G - 1.5])) > 20.0


def test_the_excess_is_followed_with_a_first_order_lag_and_a_floor():
    params, tau, dt, target = AccelSettings(), 3.0, 0.01, 25.0
    v = 0.0
    for _ in range(300):
        v = followed(params, v, target, dt, tau)
    assert v == pytest.approx(target * (1 - (1 - dt / tau) ** 300), rel=1e-12)
    assert followed(params, v, target, 10.0, tau) == target  # an interval longer than tau lands on the target
    # a norm persistently low sits at minus the tolerance's excess, not below: a turn after it shows within ~tau
    allowed = (1.03**2 - 1.0) * G * G
    low = followed(params, 0.0, -50.0, 10.0, tau)
    assert low == pytest.approx(-allowed)


def test_the_heading_share_follows_the_inclination():
    params = AccelSettings(unaided_norm_tolerance_fraction=0.0)
    excess = (G * math.tan(math.radians(10.0))) ** 2  # a 10 deg turn
    tilt = math.radians(10.0) ** 2
    assert unseen_variances_rad2(params, excess, (0.2, 0.0, 0.4)) == pytest.approx((tilt, 2.0 * tilt))  # tan I = 2: 4 / 2
    assert unseen_variances_rad2(params, excess, (0.15, 0.15, 0.0)) == pytest.approx((tilt, 0.0))  # horizontal field
    assert unseen_variances_rad2(params, excess, None) == pytest.approx((tilt, 0.0))  # no magnetometer heading
    assert unseen_variances_rad2(params, excess, (0.0, 0.0, 0.5))[1] == pytest.approx(math.pi**2)  # at the pole
