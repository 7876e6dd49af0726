"""core/quaternion_kernels.py: the compiled quaternion arithmetic on tuples against :mod:`core.quaternion` (the
same operations on arrays, written for the Python side) and scipy's ``Rotation`` (an independent implementation,
scalar-last); and :func:`fuser.model.vec3.wrapped_pi` against ``math.remainder``, which it replaces in the compiled
tick.

Inputs: random unit quaternions and rotation vectors over every angle, and the edge cases: zero and tiny angles
(the series branches of :func:`from_rotvec` and :func:`rotvec`, either side of their thresholds), half turns (the
sign of ``w`` flips there) and antipodal quaternions (``q`` and ``-q`` are one attitude).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core import quaternion as quat
from core import quaternion_kernels as qk
from fuser.model import vec3
from model_records import part

RNG = np.random.default_rng(23)
QUATERNIONS = [tuple(quat.normalize(RNG.standard_normal(4)).tolist()) for _ in range(200)]
ROTVECS = [tuple((quat.normalize(np.append(0.0, RNG.standard_normal(3)))[1:] * RNG.uniform(0.0, 0.999 * math.pi)).tolist())
           for _ in range(200)]
"""Rotation vectors of random axes and angles below a half turn (:func:`rotvec` gives the same vector back)."""
AXES = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), tuple((np.array([1.0, -2.0, 2.0]) / 3.0).tolist())]
SMALL_ANGLES_RAD = [0.0, 1e-300, 1e-12, 1e-9, 1e-8, 0.99e-4, 1e-4, 1.01e-4, 1e-3]
"""Zero, tiny, and either side of :func:`from_rotvec`'s series threshold (1e-4 rad)."""


def rotation(q: tuple) -> Rotation:
    """scipy's rotation of ``q`` (w, x, y, z)."""
    return Rotation.from_quat(np.roll(np.asarray(q, dtype=float), -1))


def wxyz(r: Rotation) -> np.ndarray:
    """The quaternion (w, x, y, z) of scipy's rotation ``r``."""
    return np.roll(r.as_quat(), 1)


def same_attitude(p: tuple, q: np.ndarray, atol: float) -> None:
    """``p`` and ``q`` are the same unit quaternion up to sign, to ``atol``."""
    q = np.asarray(q, dtype=float)
    np.testing.assert_allclose(np.asarray(p) * (1.0 if np.dot(p, q) >= 0.0 else -1.0), q, rtol=0, atol=atol)


def test_identity_and_from_array():
    assert qk.IDENTITY == tuple(quat.IDENTITY.tolist())
    for q in QUATERNIONS[:20]:
        assert qk.multiply(qk.IDENTITY, q) == q and qk.multiply(q, qk.IDENTITY) == q
    assert qk.from_array(np.array([0.5, -0.5, 0.25, 1.0, 7.0])) == (0.5, -0.5, 0.25, 1.0)  # the first four entries
    gravity = part("gravity")  # a state record's field: the strapdown attitude, the identity at the start
    assert qk.from_array(gravity.q_strapdown) == qk.IDENTITY
    assert all(isinstance(x, float) for x in qk.from_array(np.array([1, 0, 0, 0], dtype=float)))


@pytest.mark.parametrize("i", range(0, 200, 10))
def test_multiply_and_conjugate_are_the_hamilton_product(i):
    p, q = QUATERNIONS[i], QUATERNIONS[i + 1]
    assert qk.multiply(p, q) == tuple(quat.multiply(np.array(p), np.array(q)).tolist())  # the same arithmetic, exactly
    same_attitude(qk.multiply(p, q), wxyz(rotation(p) * rotation(q)), 1e-15)  # apply q first, then p
    assert qk.conjugate(p) == tuple(quat.conjugate(np.array(p)).tolist())
    same_attitude(qk.conjugate(p), wxyz(rotation(p).inv()), 1e-15)
    np.testing.assert_allclose(qk.multiply(p, qk.conjugate(p)), qk.IDENTITY, atol=1e-15)


def test_normalize_scales_to_unit_length():
    for q in QUATERNIONS[:50]:
        for scale in (1e-100, 1e-3, 1.0, 7.5, 1e100):
            raw = tuple(scale * x for x in q)
            out = qk.normalize(raw)
            np.testing.assert_allclose(out, quat.normalize(np.array(raw)), rtol=0, atol=2e-16)
            assert math.fsum(x * x for x in out) == pytest.approx(1.0, abs=1e-15)
    assert qk.normalize((-2.0, 0.0, 0.0, 0.0)) == (-1.0, 0.0, 0.0, 0.0)  # the sign is kept


@pytest.mark.parametrize("r", ROTVECS[:40])
def test_from_rotvec_and_rotvec_are_the_exponential_and_its_inverse(r):
    q = qk.from_rotvec(*r)
    np.testing.assert_allclose(q, quat.from_rotvec(np.array(r)), rtol=0, atol=2e-16)
    same_attitude(q, wxyz(Rotation.from_rotvec(r)), 1e-15)
    back = qk.rotvec(q)
    np.testing.assert_allclose(back, quat.to_rotvec(np.array(q)), rtol=0, atol=1e-15)
    np.testing.assert_allclose(back, Rotation.from_rotvec(r).as_rotvec(), rtol=0, atol=2e-15)
    np.testing.assert_allclose(back, r, rtol=0, atol=2e-15)  # angles below pi: the same vector back


@pytest.mark.parametrize("angle", SMALL_ANGLES_RAD)
@pytest.mark.parametrize("axis", AXES)
def test_tiny_angles_keep_full_relative_precision(angle, axis):
    """The series branches: ``sin(a/2)/a`` near zero and ``2/w`` for a tiny vector part; a gyro increment of
    1e-12 rad comes back to 1e-15 relative, where ``2 acos(w)`` would be all rounding."""
    r = tuple(angle * a for a in axis)
    q = qk.from_rotvec(*r)
    sinc = 0.5 - angle * angle / 48.0 if angle < 1e-3 else math.sin(0.5 * angle) / angle
    assert q[0] == pytest.approx(math.cos(0.5 * angle), rel=1e-16)
    np.testing.assert_allclose(q[1:], np.array(r) * sinc, rtol=1e-15, atol=0)
    same_attitude(q, wxyz(Rotation.from_rotvec(r)), 1e-16)
    np.testing.assert_allclose(qk.rotvec(q), r, rtol=2e-15, atol=0)
    np.testing.assert_allclose(qk.rotvec(q), Rotation.from_quat(np.roll(q, -1)).as_rotvec(), rtol=2e-15, atol=0)
    for scale in (0.5, 3.0):  # either branch is the rotation of the quaternion's direction, whatever its length
        np.testing.assert_allclose(qk.rotvec(tuple(scale * x for x in q)), qk.rotvec(q), rtol=2e-15, atol=0)


def test_from_rotvec_is_continuous_at_its_series_threshold():
    below, at = qk.from_rotvec(math.nextafter(1e-4, 0.0), 0.0, 0.0), qk.from_rotvec(1e-4, 0.0, 0.0)
    assert abs(below[1] - at[1]) < 1e-19 and below[0] == pytest.approx(at[0], abs=1e-16)


@pytest.mark.parametrize("axis", AXES)
@pytest.mark.parametrize("offset_rad", [-1e-6, -1e-12, 0.0, 1e-12, 1e-6, 0.5])
def test_half_turns(axis, offset_rad):
    """Around pi ``w`` changes sign: :func:`rotvec` keeps the angle in [0, pi] (past a half turn, the short way
    about the opposite axis) and the rotation is the same as scipy's."""
    angle = math.pi + offset_rad
    r = tuple(angle * a for a in axis)
    q = qk.from_rotvec(*r)
    same_attitude(q, wxyz(Rotation.from_rotvec(r)), 1e-15)
    back = qk.rotvec(q)
    assert vec3.norm(back) <= math.pi + 1e-15
    assert vec3.norm(back) == pytest.approx(math.pi - abs(offset_rad), abs=1e-14)
    assert (Rotation.from_rotvec(back).inv() * Rotation.from_rotvec(r)).magnitude() < 1e-14
    np.testing.assert_allclose(back, quat.to_rotvec(np.array(q)), rtol=0, atol=1e-15)


@pytest.mark.parametrize("q", QUATERNIONS[:40])
def test_antipodal_quaternions_are_one_attitude(q):
    minus = tuple(-x for x in q)
    assert qk.rotvec(minus) == qk.rotvec(q)
    assert qk.rotation_rows(minus) == qk.rotation_rows(q)
    for other in (q, minus):  # zero but for the product's rounding, as core.quaternion's
        d = qk.angular_distance(q, other)
        assert d <= 1e-16 and d == pytest.approx(float(quat.angular_distance(np.array(q), np.array(other))), rel=1e-15)
    p = QUATERNIONS[-1]
    assert qk.angular_distance(p, minus) == pytest.approx(qk.angular_distance(p, q), abs=1e-15)
    np.testing.assert_allclose(qk.rotvec_between_world(q, minus), (0.0, 0.0, 0.0), atol=1e-15)
    np.testing.assert_allclose(qk.rotvec_between_body(minus, q), (0.0, 0.0, 0.0), atol=1e-15)
    same_attitude(qk.turned_by(minus, 0.1, -0.2, 0.3), qk.turned_by(q, 0.1, -0.2, 0.3), 1e-15)


def test_a_pure_half_turn_is_one_rotation_from_either_sign():
    """``w`` exactly 0 (a half turn): ``q`` and ``-q`` give opposite vectors of length pi, the same rotation (as
    :func:`core.quaternion.to_rotvec`)."""
    for axis in AXES:
        q = (0.0, *axis)
        minus = (-0.0, *(-a for a in axis))
        for candidate in (q, minus):
            back = qk.rotvec(candidate)
            assert vec3.norm(back) == pytest.approx(math.pi, rel=1e-15)
            np.testing.assert_array_equal(back, quat.to_rotvec(np.array(candidate)))
            assert (Rotation.from_rotvec(back).inv() * rotation(q)).magnitude() < 1e-15


@pytest.mark.parametrize("i", range(0, 100, 5))
def test_turned_by_is_the_body_frame_turn(i):
    q, r = QUATERNIONS[i], ROTVECS[i]
    assert qk.turned_by(q, *r) == tuple(quat.multiply(q, quat.from_rotvec(r)).tolist())  # the same arithmetic, exactly
    same_attitude(qk.turned_by(q, *r), wxyz(rotation(q) * Rotation.from_rotvec(r)), 2e-15)
    assert qk.turned_by(q, 0.0, 0.0, 0.0) == q


@pytest.mark.parametrize("i", range(0, 100, 5))
def test_rotvec_between_recovers_the_turn_in_either_frame(i):
    q_from, r = QUATERNIONS[i], ROTVECS[i]
    in_body = qk.turned_by(q_from, *r)  # q_to = q_from (x) exp(r)
    in_world = qk.multiply(qk.from_rotvec(*r), q_from)  # q_to = exp(r) (x) q_from
    np.testing.assert_allclose(qk.rotvec_between_body(q_from, in_body), r, rtol=0, atol=1e-14)
    np.testing.assert_allclose(qk.rotvec_between_world(q_from, in_world), r, rtol=0, atol=1e-14)
    q_to = QUATERNIONS[i + 1]
    np.testing.assert_allclose(qk.rotvec_between_world(q_from, q_to), quat.to_rotvec(quat.multiply(q_to, quat.conjugate(q_from))),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(qk.rotvec_between_body(q_from, q_to), quat.to_rotvec(quat.multiply(quat.conjugate(q_from), q_to)),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(qk.rotvec_between_world(q_from, q_to), (rotation(q_to) * rotation(q_from).inv()).as_rotvec(), atol=1e-14)
    np.testing.assert_allclose(qk.rotvec_between_body(q_from, q_to), (rotation(q_from).inv() * rotation(q_to)).as_rotvec(), atol=1e-14)


@pytest.mark.parametrize("i", range(0, 100, 5))
def test_angular_distance(i):
    p, q = QUATERNIONS[i], QUATERNIONS[i + 1]
    d = qk.angular_distance(p, q)
    assert 0.0 <= d <= math.pi
    assert d == pytest.approx(float(quat.angular_distance(np.array(p), np.array(q))), abs=1e-15)
    assert d == pytest.approx((rotation(p).inv() * rotation(q)).magnitude(), abs=1e-14)
    assert qk.angular_distance(q, p) == pytest.approx(d, abs=1e-15)


@pytest.mark.parametrize("angle", [1e-12, 1e-9, 1e-4, 0.5, math.pi - 1e-9, math.pi])
def test_angular_distance_at_small_and_half_turn_angles(angle):
    """By ``atan2``: a nanoradian is resolved (``2 acos`` would give 0 or 2e-8) and a half turn is pi."""
    p = QUATERNIONS[0]
    q = qk.turned_by(p, 0.0, angle, 0.0)
    assert qk.angular_distance(p, q) == pytest.approx(angle, rel=1e-6, abs=1e-15)
    assert qk.angular_distance(p, q) == pytest.approx(float(quat.angular_distance(np.array(p), np.array(q))), abs=1e-15)


@pytest.mark.parametrize("q", QUATERNIONS[:40])
def test_rotation_rows_are_the_body_to_world_matrix(q):
    rows = qk.rotation_rows(q)
    assert np.array_equal(np.array(rows), quat.to_matrix(np.array(q)))  # the same entries, written alike
    np.testing.assert_allclose(np.array(rows), rotation(q).as_matrix(), rtol=0, atol=1e-15)
    v = tuple(RNG.standard_normal(3).tolist())
    np.testing.assert_allclose(vec3.mat_vec(rows, v), rotation(q).apply(v), rtol=0, atol=1e-14)  # q v q*: body -> world


@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.3, -1.2, math.pi, -math.pi, 2.5 * math.pi])
def test_yaw_turn_is_a_rotation_about_world_down(angle):
    q = qk.yaw_turn(angle)
    np.testing.assert_allclose(q, quat.from_axis_angle([0.0, 0.0, 1.0], angle), rtol=0, atol=1e-16)
    same_attitude(q, wxyz(Rotation.from_euler("z", angle)), 1e-15)
    np.testing.assert_allclose(vec3.mat_vec(qk.rotation_rows(q), (0.0, 0.0, 1.0)), (0.0, 0.0, 1.0), atol=1e-15)  # down stays
    heading = qk.multiply(q, QUATERNIONS[0])  # a world-frame turn: every attitude's yaw changes by the angle
    assert qk.angular_distance(heading, QUATERNIONS[0]) == pytest.approx(abs(vec3.wrapped_pi(angle)), abs=1e-12)


TWO_PI = 2.0 * math.pi


def test_wrapped_pi_is_math_remainder_over_a_few_turns():
    """Random angles over four turns either way, an angle difference's span: equal to ``math.remainder(x, 2 pi)``
    to the last bit of pi (measured: exactly), in [-pi, pi]."""
    rng = np.random.default_rng(5)
    for x in [*rng.uniform(-4 * TWO_PI, 4 * TWO_PI, 20_000).tolist(), 0.0, -0.0, 1e-300, -1e-300, 1.0, -3.0, 3.0, 6.3, -6.3]:
        wrapped = vec3.wrapped_pi(x)
        assert abs(wrapped - math.remainder(x, TWO_PI)) <= math.ulp(math.pi), x
        assert -math.pi <= wrapped <= math.pi, x
    assert vec3.wrapped_pi(0.25) == 0.25 and vec3.wrapped_pi(0.25 + TWO_PI) == pytest.approx(0.25, abs=1e-15)


ODD_PI = [k * math.pi for k in (-7, -5, -3, -1, 1, 3, 5, 7)]
NEAR_PI = [math.nextafter(x, 0.0) for x in ODD_PI] + [math.nextafter(x, 2 * x) for x in ODD_PI]


def test_wrapped_pi_is_math_remainder_at_half_turns():
    """The docstring's claim at the boundary: ``math.remainder(x, 2 pi)`` exactly, in [-pi, pi]."""
    differing = [(x, vec3.wrapped_pi(x), math.remainder(x, TWO_PI)) for x in ODD_PI + NEAR_PI
                 if vec3.wrapped_pi(x) != math.remainder(x, TWO_PI) or not -math.pi <= vec3.wrapped_pi(x) <= math.pi]
    assert not differing, differing
