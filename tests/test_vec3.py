"""fuser/model/vec3.py: the plain-float 3-vector arithmetic against numpy on random vectors and rotations."""

import math

import numpy as np
import pytest

from core import quaternion as quat
from fuser.model import vec3

RNG = np.random.default_rng(17)
CASES = [(quat.normalize(RNG.standard_normal(4)), RNG.standard_normal(3) * 10.0, RNG.standard_normal(3)) for _ in range(200)]


@pytest.mark.parametrize("q, a, b", CASES[:50])
def test_rotation_rows_are_the_quaternions_matrix_exactly(q, a, b):
    assert np.array_equal(np.array(vec3.rotation_rows(q)), quat.to_matrix(q))
    assert vec3.rotation_rows(q) == vec3.rotation_rows(q.tolist())  # a list too


def test_products_agree_with_numpy_to_rounding():
    for q, a, b in CASES:
        m = quat.to_matrix(q)
        rows, fa, fb = vec3.rotation_rows(q), vec3.floats(a), vec3.floats(b)
        np.testing.assert_allclose(vec3.mat_vec(rows, fa), m @ a, rtol=0, atol=1e-13)
        np.testing.assert_allclose(vec3.vec_mat(fa, rows), a @ m, rtol=0, atol=1e-13)
        assert vec3.dot(fa, fb) == pytest.approx(float(a @ b), abs=1e-13)
        assert vec3.norm(fa) == pytest.approx(float(np.linalg.norm(a)), rel=1e-15)


def test_low_pass_step_and_difference_round_as_numpy_does():
    for _, a, b in CASES:
        k = float(RNG.uniform())
        assert np.array_equal(np.array(vec3.toward(vec3.floats(a), vec3.floats(b), k)), a + k * (b - a))
        assert np.array_equal(np.array(vec3.sub(vec3.floats(a), vec3.floats(b))), a - b)


def test_hand_worked_values():
    rows = vec3.rotation_rows(quat.from_axis_angle([0.0, 0.0, 1.0], math.pi / 2))  # 90 deg about z: x -> y
    np.testing.assert_allclose(vec3.mat_vec(rows, (1.0, 0.0, 0.0)), (0.0, 1.0, 0.0), atol=1e-15)
    np.testing.assert_allclose(vec3.vec_mat((0.0, 1.0, 0.0), rows), (1.0, 0.0, 0.0), atol=1e-15)  # the transpose back
    assert vec3.norm((3.0, 4.0, 12.0)) == 13.0
    assert vec3.dot((1.0, 2.0, 3.0), (4.0, -5.0, 6.0)) == 12.0
    assert vec3.toward((0.0, 0.0, 0.0), (2.0, 4.0, -8.0), 0.25) == (0.5, 1.0, -2.0)
    assert vec3.sub((1.0, 2.0, 3.0), (4.0, -5.0, 6.5)) == (-3.0, 7.0, -3.5)
    assert vec3.angle_rad(1.0 + 1e-15) == 0.0 and vec3.angle_rad(-1.0 - 1e-15) == math.pi
    assert vec3.floats(np.array([1, 2, 3])) == (1.0, 2.0, 3.0) and vec3.floats([1, 2, 3]) == (1.0, 2.0, 3.0)
