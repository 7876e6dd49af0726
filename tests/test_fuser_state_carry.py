"""The updates that build their part of the state directly (for speed, instead of ``dataclasses.replace``) carry
every field they do not change: checked against ``dataclasses.replace`` of the input, on states whose every field
holds a value other than its default, and the field sets pinned, so that a field added to a state fails here until
the direct constructions carry it too (fuser/model/gravity.py, velocity.py, unaided.py, attitude.py)."""

import dataclasses
import math

import numpy as np
import pytest

from core import quaternion as quat
from drivers.samples import AttitudeSample, SourceId
from fuser.config import AccelSettings, AttitudeSettings, GnssSettings, UpdateSettings
from fuser.model.attitude import update_attitude
from fuser.model.gravity import turn_frame, update_gravity
from fuser.model.state import AttitudeState, GravityState, UnaidedState, VelocityState
from fuser.model.tick import TickContext
from fuser.model.unaided import absorbed, cleared, corrected, followed, learn_norm
from fuser.model.velocity import VelocityTrack, update_gravity_aided

G = AccelSettings().gravity_m_s2
TICK = TickContext(0.01, 1e-7, 1.0, 0.8)
TILT = quat.from_axis_angle([1.0, 0.0, 0.0], math.radians(2.0))

GRAVITY = GravityState(q_strapdown=quat.from_axis_angle([0.0, 0.0, 1.0], 0.3), accel_lp_m_s2=np.array([0.1, 0.0, -G]),
                       down_body=np.array([0.0, 0.6, 0.8]), converged=True, tilt_known=True, gated_s=0.25,
                       raw_mean_m_s2=np.array([0.2, 0.1, -G]), raw_s=0.5, measured_body=np.array([0.0, 0.8, 0.6]), gnss_checked=True,
                       measured_world=np.array([0.6, 0.0, 0.8]))
UNAIDED = UnaidedState(excess_m2_s4=3.0, norm_mean_m_s2=np.array([0.0, 0.0, -1.01 * G]), norm_mean_s=20.0, absorbed_rad=(0.02, -0.01))


def _same(a, b, names):
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        assert (np.array_equal(x, y) if isinstance(x, np.ndarray) or isinstance(y, np.ndarray) else x == y), name


def _names(cls):
    return [f.name for f in dataclasses.fields(cls)]


def test_the_field_sets_these_constructions_carry():
    assert _names(GravityState) == ["q_strapdown", "accel_lp_m_s2", "down_body", "converged", "tilt_known", "gated_s", "raw_mean_m_s2",
                                    "raw_s", "measured_body", "gnss_checked", "measured_world"]
    assert _names(UnaidedState) == ["excess_m2_s4", "norm_mean_m_s2", "norm_mean_s", "absorbed_rad"]
    assert _names(AttitudeState) == ["gated_s", "last_fused_ns"]
    for cls, state in ((GravityState, GRAVITY), (UnaidedState, UNAIDED)):  # every field off its default
        default = cls()
        for name in _names(cls):
            assert not np.array_equal(getattr(state, name), getattr(default, name)), name


def test_turn_frame_keeps_everything_but_what_a_gap_drops():
    _same(turn_frame(GRAVITY, None, 0.0), GRAVITY, _names(GravityState))
    dropped = dataclasses.replace(GRAVITY, accel_lp_m_s2=None, converged=False, raw_mean_m_s2=None, raw_s=0.0)
    _same(turn_frame(GRAVITY, None, 0.005), dropped, _names(GravityState))


def test_the_plain_update_keeps_the_strapdown_frame():
    reading = update_gravity(AccelSettings(), UpdateSettings(), GRAVITY, TICK, np.array([0.0, 0.0, -G]), 3.0, TILT, 0.01)
    assert reading.exponent is not None
    _same(reading.state, GRAVITY, ["q_strapdown"])
    assert reading.state.raw_mean_m_s2 is None and reading.state.raw_s == 0.0  # converged: the low-pass is in use


@pytest.mark.parametrize("fused", [False, True])
def test_the_aided_update_keeps_what_it_does_not_measure(fused):
    velocity = VelocityState(body_lp_m_s2=np.array([0.0, 0.0, G]), world_lp_m_s2=np.array([0.0, 0.0, G]), vertical=True)
    track = VelocityTrack(velocity, True, fused, 0.1, False, (), ())
    reading = update_gravity_aided(AccelSettings(), GnssSettings(), UpdateSettings(), GRAVITY, track, TICK, 3.0, TILT)
    changed = {"accel_lp_m_s2", "down_body", "raw_mean_m_s2", "raw_s", "measured_body", "measured_world"} | (
        {"converged", "tilt_known", "gated_s"} if fused else set())
    _same(reading.state, GRAVITY, [n for n in _names(GravityState) if n not in changed])
    assert reading.state.accel_lp_m_s2 is None and reading.state.raw_mean_m_s2 is None and reading.state.raw_s == 0.0
    np.testing.assert_allclose(reading.state.measured_world, [0.0, 0.0, 1.0], atol=1e-15)
    # a yaw-only strapdown frame leaves (0, 0, g) in S down in the body
    np.testing.assert_allclose(reading.state.measured_body, [0.0, 0.0, 1.0], atol=1e-15)


def test_the_unaided_steps_keep_the_learnt_norm():
    params = AccelSettings()
    _same(followed(params, UNAIDED, 4.0, 0.01, 3.0), UNAIDED, ["norm_mean_m_s2", "norm_mean_s", "absorbed_rad"])
    _same(cleared(params, UNAIDED), UNAIDED, ["norm_mean_m_s2", "norm_mean_s"])
    assert cleared(params, UNAIDED).absorbed_rad == (0.0, 0.0)
    _same(corrected(params, UNAIDED, 10.0, 5.0, math.pi), UNAIDED, ["norm_mean_m_s2", "norm_mean_s"])
    _same(absorbed(params, UNAIDED, 0.01, 3.0, None), UNAIDED, ["excess_m2_s4", "norm_mean_m_s2", "norm_mean_s"])
    learnt = learn_norm(params, UNAIDED, GRAVITY, np.array([0.0, 0.0, -G]), 0.01, False)
    assert learnt.excess_m2_s4 == UNAIDED.excess_m2_s4 and learnt.norm_mean_s == pytest.approx(20.01)
    assert learnt.absorbed_rad == UNAIDED.absorbed_rad
    broken = learn_norm(params, UNAIDED, GRAVITY, np.array([0.0, 0.0, -G]), 0.01, True)
    _same(broken, UNAIDED, ["excess_m2_s4", "norm_mean_s", "absorbed_rad"])
    # the mean kept along the last measured down, its norm the learnt one: -|mean| (0, 0.6, 0.8) turned into S
    expected = quat.to_matrix(GRAVITY.q_strapdown) @ (-1.01 * G * np.array([0.0, 0.6, 0.8]))
    np.testing.assert_allclose(broken.norm_mean_m_s2, expected, rtol=1e-12)


def test_the_attitude_update_keeps_when_it_last_fused():
    state = AttitudeState(gated_s=0.0, last_fused_ns=123)
    sample = AttitudeSample(0, tuple(TILT), SourceId("mavlink", 1, 1, 0))
    after = update_attitude(AttitudeSettings(), UpdateSettings(), state, [sample], TILT, None, TICK)
    assert len(after.exponents) == 1
    _same(after.state, state, ["gated_s", "last_fused_ns"])
