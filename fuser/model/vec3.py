"""Plain-float 3-vector arithmetic for the per-tick updates.

An update handles a handful of 3-vectors and 3x3 rotations per tick; numpy
costs about a microsecond per call on them (an array made, a dispatch), many
times the arithmetic on three numbers, and that overhead was most of the
gravity, velocity and heading updates' cost. Here a vector is a tuple of
three floats and a matrix a sequence of three rows (:func:`rotation_rows`);
the updates convert at their edges (:func:`floats` in, ``np.array`` for the
state they keep out). Element-wise operations round exactly as numpy's do; a
dot product or a matrix-vector product may differ from numpy's (BLAS, fused
multiply-adds) in the last bit.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from drivers.samples import Vec3

__all__ = ["Rows", "angle_rad", "dot", "floats", "mat_vec", "norm", "rotation_rows", "sub", "toward", "vec_mat"]

Rows = Sequence[Sequence[float]]
"""A 3x3 matrix as three rows of three floats."""


def floats(v: ArrayLike) -> Vec3:
    """A 3-vector (array, tuple, list) as a tuple of three floats."""
    x, y, z = np.asarray(v, dtype=float).tolist()
    return x, y, z


def rotation_rows(q: ArrayLike) -> Rows:
    """The rotation matrix of the unit quaternion ``q`` (w, x, y, z) as rows of floats: the entries of
    :func:`core.quaternion.to_matrix`, written out alike (so rounded alike), without its arrays."""
    w, x, y, z = np.asarray(q, dtype=float).tolist()
    return ((w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z))


def dot(a: Vec3, b: Vec3) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(a: Vec3) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def mat_vec(m: Rows, v: Vec3) -> Vec3:
    """``m @ v``."""
    x, y, z = v
    r0, r1, r2 = m
    return r0[0] * x + r0[1] * y + r0[2] * z, r1[0] * x + r1[1] * y + r1[2] * z, r2[0] * x + r2[1] * y + r2[2] * z


def vec_mat(v: Vec3, m: Rows) -> Vec3:
    """``v @ m``, i.e. ``m^T v``."""
    x, y, z = v
    r0, r1, r2 = m
    return x * r0[0] + y * r1[0] + z * r2[0], x * r0[1] + y * r1[1] + z * r2[1], x * r0[2] + y * r1[2] + z * r2[2]


def sub(a: Vec3, b: Vec3) -> Vec3:
    """``a - b``."""
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


def toward(a: Vec3, b: Vec3, k: float) -> Vec3:
    """``a + k (b - a)``: one step of a first-order low-pass from ``a`` towards ``b``."""
    return a[0] + k * (b[0] - a[0]), a[1] + k * (b[1] - a[1]), a[2] + k * (b[2] - a[2])


def angle_rad(cos: float) -> float:
    """``acos`` of a cosine, clipped to [-1, 1] (a product of unit vectors may round past them)."""
    return math.acos(max(-1.0, min(1.0, cos)))
