"""Compiled 3-vector arithmetic for the tick: vectors as tuples of three floats, matrices as three rows.

An update handles a handful of 3-vectors and 3x3 rotations per tick; as
tuples they stay in registers inside the compiled tick (:mod:`fuser.model.fusion`),
where an array per value would be a heap allocation. :func:`load` and
:func:`store` move a vector between a tuple and a state record's field.
Rotation matrices come from :func:`core.quaternion_kernels.rotation_rows`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["ZERO", "angle_rad", "cross", "dot", "load", "mat_vec", "norm", "scaled", "store", "sub", "toward", "vec_mat", "wrapped_pi"]

ZERO = (0.0, 0.0, 0.0)


@njit(cache=True, nogil=True)
def load(a: np.ndarray) -> tuple:
    """The first three entries of ``a`` as a tuple."""
    return a[0], a[1], a[2]


@njit(cache=True, nogil=True)
def store(out: np.ndarray, v: tuple) -> None:
    """Write the tuple ``v`` into the first three entries of ``out``."""
    out[0], out[1], out[2] = v[0], v[1], v[2]


@njit(cache=True, nogil=True)
def dot(a: tuple, b: tuple) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True)
def cross(a: tuple, b: tuple) -> tuple:
    """``a x b``."""
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


@njit(cache=True, nogil=True)
def norm(a: tuple) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@njit(cache=True, nogil=True)
def sub(a: tuple, b: tuple) -> tuple:
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


@njit(cache=True, nogil=True)
def scaled(a: tuple, k: float) -> tuple:
    return a[0] * k, a[1] * k, a[2] * k


@njit(cache=True, nogil=True)
def mat_vec(m: tuple, v: tuple) -> tuple:
    """``m @ v`` for ``m`` three rows."""
    x, y, z = v
    r0, r1, r2 = m
    return r0[0] * x + r0[1] * y + r0[2] * z, r1[0] * x + r1[1] * y + r1[2] * z, r2[0] * x + r2[1] * y + r2[2] * z


@njit(cache=True, nogil=True)
def vec_mat(v: tuple, m: tuple) -> tuple:
    """``v @ m``, i.e. ``m^T v``."""
    x, y, z = v
    r0, r1, r2 = m
    return x * r0[0] + y * r1[0] + z * r2[0], x * r0[1] + y * r1[1] + z * r2[1], x * r0[2] + y * r1[2] + z * r2[2]


@njit(cache=True, nogil=True)
def toward(a: tuple, b: tuple, k: float) -> tuple:
    """``a + k (b - a)``: one step of a first-order low-pass from ``a`` towards ``b``."""
    return a[0] + k * (b[0] - a[0]), a[1] + k * (b[1] - a[1]), a[2] + k * (b[2] - a[2])


@njit(cache=True, nogil=True)
def angle_rad(cos: float) -> float:
    """``acos`` of a cosine, clipped to [-1, 1] (a product of unit vectors may round past them)."""
    return math.acos(max(-1.0, min(1.0, cos)))


@njit(cache=True, nogil=True)
def wrapped_pi(angle_rad: float) -> float:
    """``angle_rad`` wrapped into [-pi, pi]: ``math.remainder(angle, 2 pi)``, which numba does not compile (nor
    ``math.fmod``); the nearest multiple of ``2 pi`` taken off, halves to even as ``math.remainder`` does."""
    return angle_rad - 2.0 * math.pi * round(angle_rad / (2.0 * math.pi))
