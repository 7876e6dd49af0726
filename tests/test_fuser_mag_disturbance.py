"""Magnetic disturbances as VQF handles them: the heading held on the gyro while the field is disturbed, a new
field accepted once it has been steady long enough, the reference following the undisturbed field."""

import math

import numpy as np
import pytest

from core import quaternion as quat
from fuser.config import FuserConfig, MagSettings
from fuser.model import FusionModel
from motion_inputs import fly, turning
from fusion_inputs import FIELD

MAGNET_GAUSS = np.array([0.15, 0.1, 0.35])
"""A magnet near the sensor: a body-fixed field about as strong as the earth's, which turns the horizontal field by
up to 35 deg and raises the norm by more than half at every heading (a weaker one can match the earth's norm and
dip at some headings, and is then as trustworthy as the earth's field for all norm and dip can tell)."""


def yawing(t: float) -> np.ndarray:
    """Turning about down at 0.6 rad/s with a small wobble: fast enough for a new field to count (0.35 rad/s)."""
    return np.array([0.15 * math.sin(2.0 * t), 0.1 * math.cos(1.3 * t), 0.6])


@pytest.fixture(scope="module")
def turn():
    return turning(yawing, 12.0, q0=quat.from_rotvec([0.05, -0.03, 0.2]))


def _heading(results, t_from, t_to):
    return [(t, r, next(d for d in r.diagnostics if d.update == "heading")) for t, r in results if t_from <= t < t_to]


def _error_deg(motion, t, r):
    i = int(round(t * 200.0)) - 1  # the tick's end is a sample time: 200 Hz samples, 10-ms ticks
    assert abs(motion.t_s[i] - t) < 1e-9
    return math.degrees(quat.angular_distance(r.q_wxyz, motion.q_true[i])) if r.ahead_ns == 0 else None


def test_a_magnet_holds_the_heading_on_the_gyro_and_the_uncertainty_grows(turn):
    config = FuserConfig().replace(extrapolation={"to": "tick", "imu_delay_ms": 0.0})
    model = FusionModel(config)
    results = fly(model, turn, field_extra=lambda t, q: MAGNET_GAUSS if 4.0 <= t < 8.0 else 0.0)
    during = _heading(results, 4.02, 8.0)
    assert all(d.outcome == "gated" and d.reason in ("norm", "dip") for _, _, d in during)  # kept out throughout
    after = _heading(results, 8.02, 12.0)
    back = next(t for t, _, d in after if d.outcome == "fused")
    # the field matches again after the low-pass (50 ms) and must stay so for 0.5 s before it is trusted
    assert 8.5 <= back < 8.65 and all(d.outcome == "gated" for t, _, d in after if t < back)
    assert sum(d.reason == "disturbed" for t, _, d in after if t < back) >= 40
    assert max(_error_deg(turn, t, r) for t, r, _ in during) < 0.5  # the gyro held it: the magnet pulled nothing
    unc = [r.uncertainty_deg for _, r, _ in during][::50]  # every half second
    assert all(b > a for a, b in zip(unc, unc[1:])), unc  # growing while on the gyro
    assert next(r.uncertainty_deg for t, r, _ in after if t > back + 1.0) < unc[-1]


def test_a_new_field_that_stays_steady_while_turning_is_accepted():
    """At 3 s the sensor is in a stronger, steeper field (the same declination): disturbed at first, accepted
    once it has stayed steady for ``new_field_s`` of turning, then fused again."""
    new_field = np.array([0.25, 0.0, 0.62])  # norm +41 %, dip 68 deg against 64
    motion = turning(yawing, 9.0, q0=quat.from_rotvec([0.05, -0.03, 0.2]))
    config = FuserConfig().replace(mag={"new_field_s": 2.0}, extrapolation={"to": "tick", "imu_delay_ms": 0.0})
    model = FusionModel(config)
    results = fly(model, motion, field_extra=lambda t, q: quat.rotate(quat.conjugate(q), new_field - FIELD) if t >= 3.0 else 0.0)
    after = _heading(results, 3.02, 9.0)
    accepted = next(t for t, _, d in after if d.outcome == "fused")
    assert 5.0 <= accepted < 5.2  # 2 s of turning at 0.6 rad/s after the change (and its 50-ms low-pass)
    assert all(d.outcome == "gated" for t, _, d in after if t < accepted)
    assert sum(d.outcome == "fused" for t, _, d in after if t >= accepted) > 0.95 * sum(t >= accepted for t, _, _ in after)
    field = model.state.heading.disturbance
    assert field.reference_norm_gauss == pytest.approx(np.linalg.norm(new_field), rel=0.02)
    assert math.degrees(field.reference_dip_rad) == pytest.approx(math.degrees(math.asin(0.62 / np.linalg.norm(new_field))), abs=0.5)
    assert max(_error_deg(motion, t, r) for t, r, _ in after) < 1.0


def test_a_disturbance_longer_than_the_rejection_time_is_fused_with_a_wider_sigma(turn):
    config = FuserConfig().replace(mag={"max_rejection_s": 1.0}, extrapolation={"to": "tick", "imu_delay_ms": 0.0})
    model = FusionModel(config)
    weak = np.array([0.0, 0.0, 0.08])  # along body z (near down): the norm 15 % off, the horizontal field unchanged
    results = fly(model, turn, field_extra=lambda t, q: weak if t >= 4.0 else 0.0)
    before = [d for _, _, d in _heading(results, 3.5, 4.0)]
    later = [(t, d) for t, _, d in _heading(results, 4.1, 12.0)]  # after the 50-ms low-pass of the norm
    first = next(t for t, d in later if d.outcome != "gated")
    assert 5.0 <= first < 5.15  # held for max_rejection_s, then fused again
    ratio = next(d for t, d in later if t >= first and d.outcome == "fused").sigma_deg / before[-1].sigma_deg
    assert ratio == pytest.approx(MagSettings().rejection_factor, rel=0.1)


def test_the_reference_follows_an_undisturbed_field_slowly(turn):
    """Configured 6 % weaker than the field measured: inside the gate, so undisturbed; its reference moves to the
    measured norm as a first-order low-pass over ``reference_s``."""
    config = FuserConfig().replace(mag={"field_ned_gauss": tuple(FIELD / 1.06)}, extrapolation={"to": "tick", "imu_delay_ms": 0.0})
    model = FusionModel(config)
    fly(model, turn)
    field = model.state.heading.disturbance
    configured, measured = np.linalg.norm(FIELD) / 1.06, np.linalg.norm(FIELD)
    # readings from the first tilt on (t ~ 0.01 s), 10 ms apart, gain 0.01 / 20 each
    expected = measured + (configured - measured) * (1.0 - 0.01 / 20.0) ** (len(turn.t_s) // 2 - 1)
    assert not field.disturbed
    assert field.reference_norm_gauss == pytest.approx(expected, abs=0.002 * measured)
    assert field.reference_norm_gauss > configured + 0.2 * (measured - configured)


def test_without_rejection_each_reading_is_judged_on_its_own(turn):
    config = FuserConfig().replace(mag={"disturbance_rejection": False}, extrapolation={"to": "tick", "imu_delay_ms": 0.0})
    results = fly(FusionModel(config), turn, field_extra=lambda t, q: MAGNET_GAUSS if 4.0 <= t < 8.0 else 0.0)
    assert next(t for t, _, d in _heading(results, 8.0, 12.0) if d.outcome == "fused") < 8.02  # trusted at once
