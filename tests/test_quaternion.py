"""Quaternion algebra, checked against scipy's Rotation and algebraic identities."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from core import quaternion as quat

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
raw_quat = arrays(np.float64, 4, elements=finite).filter(lambda v: np.linalg.norm(v) > 1e-3)
vec3 = arrays(np.float64, 3, elements=finite)


def unit(v):
    return quat.normalize(v)


def scipy_rot(q):
    return Rotation.from_quat(np.asarray(q)[..., [1, 2, 3, 0]])  # scipy is scalar-last


def same_rotation(p, q, atol=1e-9):
    return np.allclose(p, q, atol=atol) or np.allclose(p, -np.asarray(q), atol=atol)


@given(raw_quat, raw_quat)
def test_product_matches_scipy_composition(a, b):
    p, q = unit(a), unit(b)
    expected = (scipy_rot(p) * scipy_rot(q)).as_quat()[[3, 0, 1, 2]]
    assert same_rotation(quat.multiply(p, q), expected)


@given(raw_quat, vec3)
def test_rotate_and_matrix_match_scipy(a, v):
    q = unit(a)
    expected = scipy_rot(q).apply(v)
    np.testing.assert_allclose(quat.rotate(q, v), expected, atol=1e-9 * (1 + np.abs(v).max()))
    np.testing.assert_allclose(quat.to_matrix(q), scipy_rot(q).as_matrix(), atol=1e-12)


@given(raw_quat, raw_quat, raw_quat)
def test_product_is_associative_and_norm_preserving(a, b, c):
    p, q, r = unit(a), unit(b), unit(c)
    np.testing.assert_allclose(quat.multiply(quat.multiply(p, q), r), quat.multiply(p, quat.multiply(q, r)), atol=1e-12)
    assert abs(np.linalg.norm(quat.multiply(p, q)) - 1) < 1e-12


@given(raw_quat)
def test_inverse_and_conjugate(a):
    q = unit(a)
    np.testing.assert_allclose(quat.multiply(q, quat.inverse(q)), quat.IDENTITY, atol=1e-12)
    np.testing.assert_allclose(quat.inverse(a), quat.conjugate(a) / np.dot(a, a), rtol=1e-12)


@given(raw_quat, raw_quat)
def test_left_right_matrices(a, b):
    p, q = unit(a), unit(b)
    np.testing.assert_allclose(quat.left_matrix(p) @ q, quat.multiply(p, q), atol=1e-12)
    np.testing.assert_allclose(quat.right_matrix(q) @ p, quat.multiply(p, q), atol=1e-12)


@given(raw_quat)
def test_matrix_roundtrip(a):
    q = unit(a)
    assert same_rotation(quat.from_matrix(quat.to_matrix(q)), q, atol=1e-9)


@given(raw_quat)
def test_rotvec_and_axis_angle_match_scipy(a):
    q = unit(a)
    rotvec = quat.to_rotvec(q)
    assert abs(np.linalg.norm(rotvec) - scipy_rot(q).magnitude()) < 1e-9
    assert same_rotation(Rotation.from_rotvec(rotvec).as_quat()[[3, 0, 1, 2]], q)
    assert same_rotation(quat.from_rotvec(quat.to_rotvec(q)), q)
    axis, angle = quat.to_axis_angle(q)
    assert same_rotation(quat.from_axis_angle(axis, angle), q)


def test_small_rotvec_keeps_precision():
    v = np.array([1e-12, -2e-12, 3e-12])
    np.testing.assert_allclose(quat.to_rotvec(quat.from_rotvec(v)), v, rtol=1e-9)


@given(raw_quat, st.floats(-3, 3), st.floats(-3, 3))
def test_power_laws(a, s, t):
    q = unit(a)
    assert same_rotation(quat.power(q, 1.0), q)
    assert same_rotation(quat.power(q, 0.0), quat.IDENTITY)
    # same axis: q^s q^t = q^(s+t) (angles add modulo 2 pi)
    assert same_rotation(quat.multiply(quat.power(q, s), quat.power(q, t)), quat.power(q, s + t), atol=1e-8)


@given(raw_quat, raw_quat, raw_quat)
def test_angular_distance_is_a_metric_on_rotations(a, b, c):
    p, q, r = unit(a), unit(b), unit(c)
    d = quat.angular_distance
    assert d(p, -p) < 1e-7
    assert abs(d(p, q) - d(q, p)) < 1e-12
    assert d(p, r) <= d(p, q) + d(q, r) + 1e-9
    assert abs(d(p, q) - (scipy_rot(p).inv() * scipy_rot(q)).magnitude()) < 1e-7


def test_vectorised_over_leading_axes():
    rng = np.random.default_rng(0)
    q = quat.normalize(rng.normal(size=(5, 3, 4)))
    p = quat.normalize(rng.normal(size=(5, 3, 4)))
    out = quat.multiply(p, q)
    assert out.shape == (5, 3, 4)
    np.testing.assert_allclose(out[2, 1], quat.multiply(p[2, 1], q[2, 1]))
    assert quat.to_matrix(q).shape == (5, 3, 3, 3)
    # one quaternion takes a plain-float path: it must agree with the batched one
    np.testing.assert_allclose(quat.to_matrix(q)[2, 1], quat.to_matrix(q[2, 1]), atol=1e-15)
    v = rng.normal(size=(4, 3)) * [[1.0], [1e-5], [3.0], [0.0]]
    np.testing.assert_allclose(quat.from_rotvec(v), [quat.from_rotvec(row) for row in v], atol=1e-16)
    r = quat.from_rotvec(v) * [[1.0], [-1.0], [1.0], [-1.0]]  # both signs of each rotation
    np.testing.assert_allclose(quat.to_rotvec(r), [quat.to_rotvec(row) for row in r], atol=1e-15)


@pytest.mark.parametrize("bad", [[1, 0, 0], [np.nan, 0, 0, 1], [np.inf, 0, 0, 0], [2.0, 0, 0, 0]])
def test_bad_quaternions_raise(bad):
    with pytest.raises(ValueError):
        quat.as_quaternion(bad)


def test_normalize_rejects_zero():
    with pytest.raises(ValueError, match="zero"):
        quat.normalize([0, 0, 0, 0])
