"""fuser/model/vec3.py: the compiled 3-vector arithmetic on tuples against numpy on random vectors and rotations.

The rotations' rows come from :func:`core.quaternion_kernels.rotation_rows` (they were ``vec3.rotation_rows``), a
vector is a tuple of three floats (``vec3.floats`` is gone: ``tuple(a.tolist())``, or :func:`vec3.load` from an
array)."""

import math

import numpy as np
import pytest

from core import quaternion as quat
from core.quaternion_kernels import from_array, rotation_rows
from fuser.model import vec3

RNG = np.random.default_rng(17)
CASES = [(quat.normalize(RNG.standard_normal(4)), RNG.standard_normal(3) * 10.0, RNG.standard_normal(3)) for _ in range(200)]


def floats(a: np.ndarray) -> tuple[float, ...]:
    """An array as a tuple of floats (what the compiled helpers take)."""
    return tuple(np.asarray(a, dtype=float).tolist())


@pytest.mark.parametrize("q, a, b", CASES[:50])
def test_rotation_rows_are_the_quaternions_matrix_exactly(q, a, b):
    assert np.array_equal(np.array(rotation_rows(floats(q))), quat.to_matrix(q))
    assert rotation_rows(floats(q)) == rotation_rows(from_array(q))  # an array's entries too


def test_products_agree_with_numpy_to_rounding():
    for q, a, b in CASES:
        m = quat.to_matrix(q)
        rows, fa, fb = rotation_rows(floats(q)), floats(a), floats(b)
        np.testing.assert_allclose(vec3.mat_vec(rows, fa), m @ a, rtol=0, atol=1e-13)
        np.testing.assert_allclose(vec3.vec_mat(fa, rows), a @ m, rtol=0, atol=1e-13)
        assert vec3.dot(fa, fb) == pytest.approx(float(a @ b), abs=1e-13)
        assert vec3.norm(fa) == pytest.approx(float(np.linalg.norm(a)), rel=1e-15)
        np.testing.assert_allclose(vec3.cross(fa, fb), np.cross(a, b), rtol=0, atol=1e-13)


def test_low_pass_step_and_difference_round_as_numpy_does():
    for _, a, b in CASES:
        k = float(RNG.uniform())
        assert np.array_equal(np.array(vec3.toward(floats(a), floats(b), k)), a + k * (b - a))
        assert np.array_equal(np.array(vec3.sub(floats(a), floats(b))), a - b)
        assert np.array_equal(np.array(vec3.scaled(floats(a), k)), a * k)


def test_load_and_store_move_a_vector_between_a_tuple_and_an_array_field():
    """``load`` reads the first three entries, ``store`` writes them in place (a state record's field: through it)."""
    record = np.zeros(1, np.dtype([("v", "f8", (3,)), ("after", "f8")]))[0]
    vec3.store(record["v"], (1.5, -2.0, 3.25))
    assert record["after"] == 0.0 and record["v"].tolist() == [1.5, -2.0, 3.25]
    assert vec3.load(record["v"]) == (1.5, -2.0, 3.25)
    assert vec3.load(np.array([1.0, 2.0, 3.0, 4.0])) == (1.0, 2.0, 3.0)


def test_hand_worked_values():
    rows = rotation_rows(floats(quat.from_axis_angle([0.0, 0.0, 1.0], math.pi / 2)))  # 90 deg about z: x -> y
    np.testing.assert_allclose(vec3.mat_vec(rows, (1.0, 0.0, 0.0)), (0.0, 1.0, 0.0), atol=1e-15)
    np.testing.assert_allclose(vec3.vec_mat((0.0, 1.0, 0.0), rows), (1.0, 0.0, 0.0), atol=1e-15)  # the transpose back
    assert vec3.norm((3.0, 4.0, 12.0)) == 13.0
    assert vec3.dot((1.0, 2.0, 3.0), (4.0, -5.0, 6.0)) == 12.0
    assert vec3.toward((0.0, 0.0, 0.0), (2.0, 4.0, -8.0), 0.25) == (0.5, 1.0, -2.0)
    assert vec3.sub((1.0, 2.0, 3.0), (4.0, -5.0, 6.5)) == (-3.0, 7.0, -3.5)
    assert vec3.scaled((1.0, -2.0, 0.5), 4.0) == (4.0, -8.0, 2.0)
    assert vec3.cross((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)) == (0.0, 0.0, 1.0)  # x cross y = z
    assert vec3.angle_rad(1.0 + 1e-15) == 0.0 and vec3.angle_rad(-1.0 - 1e-15) == math.pi
    assert vec3.ZERO == (0.0, 0.0, 0.0)
