"""Each update changes its own part of the state and nothing else.

The updates once built their part of the state directly (for speed, instead of ``dataclasses.replace``) and had to
carry every field they did not change; this file checked that against ``dataclasses.replace`` of the input. The state
is one numpy record now (:mod:`fuser.model.state`) and each module's functions write their own part of it in place
(fuser/model/gravity.py, velocity.py, unaided.py, attitude.py, heading.py, rest.py, bias.py, fuser/model_error.py).
The equivalent invariant, checked here: on a state whose every field of every part holds a random value (the part the
call reads set to what it is about), a call changes the fields of its own part it must, may change the ones it
computes, and leaves every other byte of the record (padding aside) as it was: the other parts, the parts it only
reads, and the fields of its own part it does not update. The field sets are pinned, so that a field added to a part
fails here until the checks below say whether each call changes it.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Collection

import numpy as np
import pytest

from core import quaternion as quat
from fuser.config import AccelSettings, FuserConfig
from fuser.model import bias, heading, rest, unaided
from fuser.model.attitude import update_attitude
from fuser.model.bias import HeadingEvidence, TiltEvidence
from fuser.model.diagnostics import DIAGNOSTIC, FUSED, GRAVITY as GRAVITY_UPDATE, HEADING as HEADING_UPDATE, NO_REASON, NOT_AIDED, of
from fuser.model.gravity import turn_frame, update_gravity
from fuser.model.state import ATTITUDE_SOURCE, BIAS, GRAVITY as GRAVITY_FIELDS, HEADING, MODEL_ERROR, REST, STATE, UNAIDED as UNAIDED_FIELDS
from fuser.model.state import FilterState, initial_state
from fuser.model.tick import GravityReading, HeadingReading, TickContext, VelocityTrack
from fuser.model.velocity import update_gravity_aided
from fuser.model_error import observe_rate
from fusion_inputs import FIELD
from model_records import field_bytes, params, set_fields

G = AccelSettings().gravity_m_s2
P = params()
TICK = TickContext(0.01, 1e-7, 1.0, 0.8)
TILT = tuple(quat.from_axis_angle([1.0, 0.0, 0.0], math.radians(2.0)))
YAW = tuple(quat.from_axis_angle([0.0, 0.0, 1.0], math.radians(2.0)))
IDENTITY = (1.0, 0.0, 0.0, 0.0)
ZERO = (0.0, 0.0, 0.0)

GRAVITY = dict(q_strapdown=quat.from_axis_angle([0.0, 0.0, 1.0], 0.3), accel_lp_m_s2=np.array([0.1, 0.0, -G]),
               down_body=np.array([0.0, 0.6, 0.8]), converged=True, tilt_known=True, gated_s=0.25, disputed_rad=0.1,
               raw_mean_m_s2=np.array([0.2, 0.1, -G]), raw_s=0.5, measured_body=np.array([0.0, 0.8, 0.6]), gnss_checked=True,
               measured_world=np.array([0.6, 0.0, 0.8]))
UNAIDED = dict(excess_m2_s4=3.0, norm_mean_m_s2=np.array([0.0, 0.0, -1.01 * G]), norm_mean_s=20.0, absorbed_rad=(0.02, -0.01))
BIAS_STATE = dict(estimate_rad_s=np.array([0.001, 0.002, 0.003]), covariance_rad2_s2=1e-4 * np.eye(3),
                  rotation_lp=np.stack([np.eye(3)] * 3), rotated_lp_rad_s=np.full((3, 3), 0.001), tilt_aided=True, tilt_settled_s=7.0)
REST_STATE = dict(gyro_lp_rad_s=np.array([0.001, 0.0, 0.0]), accel_lp_m_s2=np.array([0.0, 0.0, -9.8]), still_s=1.0, at_rest=True)
"""What the calls below read, every field off its default (the start's)."""


def _randomized(values: np.ndarray, rng: np.random.Generator) -> None:
    """Every leaf field of the structured array ``values`` set to a random value of its type."""
    for name in values.dtype.names:
        field = values[name]
        if field.dtype.names:
            _randomized(field, rng)
        elif field.dtype == np.bool_:
            field[...] = rng.integers(0, 2, field.shape).astype(bool)
        elif field.dtype.kind in "iu":
            field[...] = rng.integers(0, 2 if field.dtype == np.uint8 else 10**15, field.shape)
        else:
            field[...] = rng.normal(0.0, 3.0, field.shape)


def _state(seed: int = 0, **parts: dict[str, Any]) -> FilterState:
    """A state whose every number is random, then the fields of ``parts`` (``gravity=GRAVITY``) set: what the call
    under test reads."""
    state = initial_state(FuserConfig())
    rng = np.random.default_rng(seed)
    _randomized(state.record, rng)
    for name, fields in parts.items():
        set_fields(getattr(state, name), **fields)
    return state


def _changes(state: FilterState, call: Callable[[], Any], part: str, changed: Collection[str] = (), free: Collection[str] = ()) -> Any:
    """Run ``call``; the fields ``changed`` of ``state``'s ``part`` must have changed, its fields ``free`` may have,
    and every other byte of the record (its other parts' fields and its own others) must be as it was. Returns what
    ``call`` returned."""
    names = STATE[part].names
    assert set(changed) <= set(names) and set(free) <= set(names), (changed, free)
    before = field_bytes(state.record)
    knots = state.knots_ns.tobytes(), state.knots.tobytes()
    result = call()
    after = field_bytes(state.record)
    assert after.keys() == before.keys() and (state.knots_ns.tobytes(), state.knots.tobytes()) == knots
    for key in before:
        where, _, field = key.partition(".")
        if where == part and field.partition(".")[0] in changed:
            assert after[key] != before[key], f"{key} did not change"
        elif not (where == part and field.partition(".")[0] in free):
            assert after[key] == before[key], f"{key} changed"
    return result


def test_the_field_sets_these_checks_cover():
    assert STATE.names == ("attitude", "bias", "gyro", "rest", "gravity", "heading", "attitude_source", "imu_check", "model_error",
                           "velocity", "unaided")
    assert GRAVITY_FIELDS.names == ("q_strapdown", "has_accel_lp", "accel_lp_m_s2", "down_body", "converged", "tilt_known", "gated_s", "disputed_rad",
                                    "has_raw_mean", "raw_mean_m_s2", "raw_s", "measured_body", "gnss_checked", "measured_world")
    assert UNAIDED_FIELDS.names == ("excess_m2_s4", "has_norm_mean", "norm_mean_m_s2", "norm_mean_s", "absorbed_rad")
    assert ATTITUDE_SOURCE.names == ("gated_s", "has_last_fused_ns", "last_fused_ns")
    assert HEADING.names == ("gated_s", "has_last_reading_ns", "last_reading_ns", "has_last_fused_ns", "last_fused_ns", "vector_until_ns")
    assert REST.names == ("has_lp", "gyro_lp_rad_s", "accel_lp_m_s2", "still_s", "at_rest")
    assert BIAS.names == ("estimate_rad_s", "covariance_rad2_s2", "has_lp", "rotation_lp", "rotated_lp_rad_s", "tilt_aided", "tilt_settled_s")
    assert MODEL_ERROR.names == ("rate_sq",)
    start = initial_state(FuserConfig())
    for name, fields in (("gravity", GRAVITY), ("unaided", UNAIDED), ("bias", BIAS_STATE), ("rest", REST_STATE)):  # every field off its default
        record = _state(**{name: fields})
        given = field_bytes(getattr(record, name))
        default = field_bytes(getattr(start, name))
        for field in given:
            assert given[field] != default[field], (name, field)
    first, second = field_bytes(_state(0).record), field_bytes(_state(1).record)  # the premise: every number random (a bool a coin)
    assert all(first[key] != second[key] for key in first if len(first[key]) > 1)


def test_turn_frame_keeps_everything_but_what_a_gap_drops():
    state = _state(gravity=GRAVITY)
    _changes(state, lambda: turn_frame(state.gravity, False, IDENTITY, 0.0), "gravity")
    dropped = {"has_accel_lp", "accel_lp_m_s2", "converged", "has_raw_mean", "raw_mean_m_s2", "raw_s"}
    _changes(state, lambda: turn_frame(state.gravity, False, IDENTITY, 0.005), "gravity", changed=dropped)
    g = state.gravity
    assert not g.has_accel_lp and not g.converged and not g.has_raw_mean and g.raw_s == 0.0
    assert np.all(g.accel_lp_m_s2 == 0.0) and np.all(g.raw_mean_m_s2 == 0.0)
    turned = _state(gravity=GRAVITY)
    rotation = quat.from_rotvec([0.01, -0.02, 0.03])
    _changes(turned, lambda: turn_frame(turned.gravity, True, tuple(rotation), 0.0), "gravity", changed={"q_strapdown"})
    np.testing.assert_allclose(turned.gravity.q_strapdown, quat.normalize(quat.multiply(GRAVITY["q_strapdown"], rotation)), rtol=1e-12,
                               atol=1e-15)


def test_the_plain_update_keeps_the_strapdown_frame():
    state = _state(gravity=GRAVITY)
    reading = _changes(state, lambda: update_gravity(P.accel, P.updates, state.gravity, TICK, (0.0, 0.0, -G), 3.0, TILT, 0.01, True, False,
                                                     ZERO, 0.0),
                       "gravity", changed={"has_raw_mean", "raw_mean_m_s2", "raw_s"},
                       free=set(GRAVITY_FIELDS.names) - {"q_strapdown"})
    assert reading.fused
    np.testing.assert_array_equal(state.gravity.q_strapdown, GRAVITY["q_strapdown"])
    assert not state.gravity.has_raw_mean and state.gravity.raw_s == 0.0  # converged: the low-pass is in use


@pytest.mark.parametrize("fused", [False, True])
def test_the_aided_update_keeps_what_it_does_not_measure(fused):
    velocity = dict(body_lp_m_s2=np.array([0.0, 0.0, G]), world_lp_m_s2=np.array([0.0, 0.0, G]), vertical=True, noise_var_m2_s4=0.0)
    state = _state(gravity=GRAVITY, velocity=velocity)
    track = VelocityTrack(True, fused, 0.1, False, False)
    changed = {"has_accel_lp", "accel_lp_m_s2", "down_body", "has_raw_mean", "raw_mean_m_s2", "raw_s", "measured_body", "measured_world"}
    _changes(state, lambda: update_gravity_aided(P.accel, P.updates, state.gravity, state.velocity, track, TICK, 3.0, TILT),
             "gravity", changed=changed, free={"converged", "tilt_known", "gated_s", "disputed_rad"} if fused else set())
    g = state.gravity
    assert not g.has_accel_lp and not g.has_raw_mean and g.raw_s == 0.0
    np.testing.assert_allclose(g.measured_world, [0.0, 0.0, 1.0], atol=1e-15)
    # a yaw-only strapdown frame leaves (0, 0, g) in S down in the body
    np.testing.assert_allclose(g.measured_body, [0.0, 0.0, 1.0], atol=1e-15)


def test_the_unaided_steps_keep_the_learnt_norm():
    accel = P.accel
    norm = {"has_norm_mean", "norm_mean_m_s2", "norm_mean_s"}  # what every step but learn_norm keeps
    state = _state(unaided=UNAIDED, gravity=GRAVITY)
    _changes(state, lambda: unaided.followed(accel, state.unaided, 4.0, 0.01, 3.0), "unaided", changed={"excess_m2_s4"})
    state = _state(unaided=UNAIDED, gravity=GRAVITY)
    _changes(state, lambda: unaided.cleared(accel, state.unaided), "unaided", changed={"absorbed_rad"}, free={"excess_m2_s4"})
    assert tuple(state.unaided.absorbed_rad) == (0.0, 0.0)
    state = _state(unaided=UNAIDED, gravity=GRAVITY)
    _changes(state, lambda: unaided.corrected(accel, state.unaided, 10.0, math.radians(5.0), math.pi), "unaided",
             free=set(UNAIDED_FIELDS.names) - norm)
    state = _state(unaided=UNAIDED, gravity=GRAVITY)
    _changes(state, lambda: unaided.absorbed(accel, state.unaided, 0.01, 3.0, False, IDENTITY, IDENTITY), "unaided", changed={"absorbed_rad"})
    state = _state(unaided=UNAIDED, gravity=GRAVITY)  # the gravity part is read, not written
    _changes(state, lambda: unaided.learn_norm(accel, state.unaided, state.gravity, (0.0, 0.0, -G), 0.01, False), "unaided",
             changed={"norm_mean_m_s2", "norm_mean_s"})
    assert state.unaided.excess_m2_s4 == UNAIDED["excess_m2_s4"] and state.unaided.norm_mean_s == pytest.approx(20.01)
    assert tuple(state.unaided.absorbed_rad) == UNAIDED["absorbed_rad"]
    state = _state(unaided=UNAIDED, gravity=GRAVITY)
    _changes(state, lambda: unaided.learn_norm(accel, state.unaided, state.gravity, (0.0, 0.0, -G), 0.01, True), "unaided",
             changed={"norm_mean_m_s2"})
    # the mean kept along the last measured down, its norm the learnt one: -|mean| (0, 0.6, 0.8) turned into S
    expected = quat.to_matrix(GRAVITY["q_strapdown"]) @ (-1.01 * G * np.array([0.0, 0.6, 0.8]))
    np.testing.assert_allclose(state.unaided.norm_mean_m_s2, expected, rtol=1e-12)


def _attitude(state: FilterState, q_wxyz: np.ndarray) -> tuple[int, int, np.ndarray]:
    """One autopilot attitude sample through :func:`update_attitude` against the estimate ``TILT``: (diagnostics
    written, samples fused, the exponents' sum)."""
    exponent, diagnostics = np.zeros((4, 4)), np.zeros(4, DIAGNOSTIC)
    n, fused = update_attitude(P.attitude, P.updates, state.attitude_source, np.array([q_wxyz], float), TILT, False, (0.0, 0.0, 1.0), TICK,
                               exponent, diagnostics, 0)
    return n, fused, exponent


def test_the_attitude_update_keeps_when_it_last_fused():
    state = _state(attitude_source=dict(gated_s=0.0, last_fused_ns=123))
    n, fused, exponent = _changes(state, lambda: _attitude(state, np.array(TILT)), "attitude_source")
    assert n == 1 and fused == 1 and np.any(exponent != 0.0)
    # a jump: kept out, for one tick more, when it last fused still as it was
    n, fused, exponent = _changes(state, lambda: _attitude(state, quat.from_rotvec([0.0, 0.0, 1.5])), "attitude_source", changed={"gated_s"})
    assert n == 1 and fused == 0 and np.all(exponent == 0.0)
    assert state.attitude_source.gated_s == TICK.dt_s and state.attitude_source.last_fused_ns == 123


@pytest.mark.parametrize("yaw_rad, gated", [(0.0, False), (math.pi / 2, True)])
def test_the_heading_update_changes_only_its_gate(yaw_rad, gated):
    """The magnetometer's reading against an estimate right (fused) or a quarter turn off (gated by innovation): only
    the heading's seconds of gating change; when it last read is the tick's to note, and the gravity part it reads
    (the measured down, for the dip gate) stays."""
    level = dict(GRAVITY, measured_body=np.array([0.0, 0.0, 1.0]), measured_world=np.array([0.0, 0.0, 1.0]))
    state = _state(heading=dict(gated_s=0.25), gravity=level)
    current = tuple(quat.from_rotvec([0.0, 0.0, yaw_rad]))
    reading = _changes(state, lambda: heading.update_heading(P.mag, P.updates, FIELD.copy(), state.heading, state.gravity, TICK,
                                                             tuple(FIELD), current, math.radians(2.0), 6.0),
                       "heading", changed={"gated_s"})
    assert reading.fused != gated
    assert state.heading.gated_s == (pytest.approx(0.25 + TICK.dt_s) if gated else 0.0)


def test_the_rest_steps_change_only_the_detector_and_the_bias_it_measures():
    state = _state(rest=REST_STATE)
    _changes(state, lambda: rest.detect_rest(P.rest, state.rest, ZERO, (0.0, 0.0, -9.81), 0.01), "rest",
             changed={"gyro_lp_rad_s", "accel_lp_m_s2", "still_s"}, free={"at_rest"})
    state = _state(rest=REST_STATE)
    _changes(state, lambda: rest.reset(state.rest), "rest", changed=set(REST.names))
    assert not state.rest.has_lp and not state.rest.at_rest and state.rest.still_s == 0.0
    state = _state(rest=REST_STATE, bias=BIAS_STATE)  # the rest part is read, not written
    _changes(state, lambda: rest.measure_bias(P.rest, state.rest, state.bias, 0.01), "bias", changed={"estimate_rad_s", "covariance_rad2_s2"})


def _tilt_reading() -> GravityReading:
    """A fused, trusted plain gravity reading of sigma 1 deg."""
    return GravityReading(True, np.zeros((4, 4)), False, True, of(GRAVITY_UPDATE, FUSED, NO_REASON, 0.001, math.radians(1.0), 0.01, NOT_AIDED),
                          False, 0.0, False)


def _heading_reading() -> HeadingReading:
    return HeadingReading(True, np.zeros((4, 4)), of(HEADING_UPDATE, FUSED, NO_REASON, 0.001, math.radians(3.0), 0.01, NOT_AIDED))


def _learn_from_tick(state: FilterState, aided: bool, restarted: bool) -> None:
    """One tick of learning in motion from a tilt correction (GNSS-aided's or the plain one's) and a heading
    correction, slowly turning (``restarted``: the frame broke)."""
    turned = tuple(quat.multiply(np.array(TILT), quat.from_rotvec([1e-4, -1e-4, 2e-4])))
    bias.learn_from_tick(P, state.bias, TILT, turned, TICK, 3.0, 0.01, VelocityTrack(aided, aided, 0.1, False, False), True,
                         _tilt_reading(), True, _heading_reading(), 0.01, state.unaided, False, False, 0.1, restarted)


STAGES = {"rotation_lp", "rotated_lp_rad_s"}
"""The state's stages follow the GNSS-aided tilt correction (``tilt_aided``): ``low_pass`` continues them with the
aided one, and starts them again with the plain one (which then waits for them to settle, and learns from the heading alone)."""
BIAS_STEPS = {
    "propagate": (lambda s: bias.propagate(P.bias, s.bias, 0.01), {"covariance_rad2_s2"}),
    "low_pass": (lambda s: bias.low_pass(s.bias, TILT, 3.0, 0.01, True, True, 0.5, True, 0.5), STAGES | {"tilt_settled_s"}),
    "learn_in_motion": (lambda s: bias.learn_in_motion(P.bias, s.bias, IDENTITY, TILT, 3.0, True, TiltEvidence(0.003, 0.01, 1e-4), True,
                                                       HeadingEvidence(0.002, 0.01, 0.02, 10.0), 0.0, 0.0),
                        {"estimate_rad_s", "covariance_rad2_s2"}),
    "integral_feedback": (lambda s: bias.integral_feedback(P.bias, s.bias, IDENTITY, TILT, 0.01), {"estimate_rad_s", "covariance_rad2_s2"}),
    "heading_feedback": (lambda s: bias.heading_feedback(P.bias, s.bias, IDENTITY, YAW, 40.0), {"estimate_rad_s"}),
    "learn_from_tick aided": (lambda s: _learn_from_tick(s, True, False), STAGES | {"tilt_settled_s", "estimate_rad_s", "covariance_rad2_s2"}),
    "learn_from_tick plain": (lambda s: _learn_from_tick(s, False, False),
                              STAGES | {"tilt_aided", "tilt_settled_s", "estimate_rad_s", "covariance_rad2_s2"}),
    "learn_from_tick restarted": (lambda s: _learn_from_tick(s, False, True), STAGES | {"has_lp"}),
}


@pytest.mark.parametrize("step", BIAS_STEPS)
def test_the_bias_steps_change_only_the_bias(step):
    """The bias's steps write its part alone; learning from a tick reads the unaided accelerometer's (the tilt's noise)."""
    call, changed = BIAS_STEPS[step]
    state = _state(bias=BIAS_STATE, unaided=UNAIDED)
    _changes(state, lambda: call(state), "bias", changed=changed)


def test_the_model_error_observes_only_its_rate():
    state = _state(model_error=dict(rate_sq=0.5))
    _changes(state, lambda: observe_rate(state.model_error, 5.0, 0.01, 3.0), "model_error", changed={"rate_sq"})
    assert state.model_error.rate_sq == pytest.approx(0.5 + 0.01 / 3.0 * (25.0 - 0.5), rel=1e-12)
