"""Compiled quaternion arithmetic on single quaternions held as tuples ``(w, x, y, z)``, for the compiled tick.

The same operations as :mod:`core.quaternion` (Hamilton product, ``w`` first,
``v_world = q v_body q*``), written for one quaternion at a time in numba:
the fusion model's tick (:mod:`fuser.model.fusion`) turns a handful of
quaternions and 3-vectors per tick, where an array per value would cost more
than the arithmetic. A tuple of floats lives in registers, not on the heap.
``tests/test_quaternion_kernels.py`` checks each against :mod:`core.quaternion`
and scipy's ``Rotation``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["angular_distance", "conjugate", "from_array", "from_rotvec", "multiply", "normalize", "rotation_rows", "rotvec",
           "rotvec_between_body", "rotvec_between_world", "turned_by", "yaw_turn"]

IDENTITY = (1.0, 0.0, 0.0, 0.0)


@njit(cache=True, nogil=True)
def from_array(q: np.ndarray) -> tuple:
    """The first four entries of ``q`` as a tuple."""
    return q[0], q[1], q[2], q[3]


@njit(cache=True, nogil=True)
def multiply(p: tuple, q: tuple) -> tuple:
    """Hamilton product ``p q`` (apply ``q`` first, then ``p``)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


@njit(cache=True, nogil=True)
def conjugate(q: tuple) -> tuple:
    return q[0], -q[1], -q[2], -q[3]


@njit(cache=True, nogil=True)
def normalize(q: tuple) -> tuple:
    """``q`` scaled to unit length (``q`` non-zero)."""
    w, x, y, z = q
    scale = math.sqrt(w * w + x * x + y * y + z * z)
    return w / scale, x / scale, y / scale, z / scale


@njit(cache=True, nogil=True)
def from_rotvec(x: float, y: float, z: float) -> tuple:
    """The quaternion of a rotation vector (axis times angle, rad), ``sin(a/2)/a`` by its Taylor series near zero."""
    angle = math.sqrt(x * x + y * y + z * z)
    sinc = 0.5 - angle * angle / 48.0 if angle < 1e-4 else math.sin(0.5 * angle) / angle
    return math.cos(0.5 * angle), sinc * x, sinc * y, sinc * z


@njit(cache=True, nogil=True)
def rotvec(q: tuple) -> tuple:
    """The rotation vector (angle in [0, pi] times axis) of ``q``; ``q`` and ``-q`` agree."""
    w, x, y, z = q
    if not w >= 0:
        w, x, y, z = -w, -x, -y, -z
    vec_norm = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 / w if vec_norm < 1e-8 else 2.0 * math.atan2(vec_norm, w) / vec_norm
    return scale * x, scale * y, scale * z


@njit(cache=True, nogil=True)
def turned_by(q: tuple, x: float, y: float, z: float) -> tuple:
    """``q (x) exp(r)`` for a body-frame rotation vector ``r = (x, y, z)``."""
    return multiply(q, from_rotvec(x, y, z))


@njit(cache=True, nogil=True)
def rotvec_between_world(q_from: tuple, q_to: tuple) -> tuple:
    """The world-frame rotation vector ``r`` with ``q_to = exp(r) (x) q_from``: a filter's correction seen in the world."""
    return rotvec(multiply(q_to, conjugate(q_from)))


@njit(cache=True, nogil=True)
def rotvec_between_body(q_from: tuple, q_to: tuple) -> tuple:
    """The body-frame rotation vector ``r`` with ``q_to = q_from (x) exp(r)``."""
    return rotvec(multiply(conjugate(q_from), q_to))


@njit(cache=True, nogil=True)
def angular_distance(p: tuple, q: tuple) -> float:
    """Rotation angle (rad, in [0, pi]) between the orientations ``p`` and ``q`` (antipodal-aware; unscented paper, eq. 4)."""
    w, x, y, z = multiply(conjugate(p), q)
    return 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))


@njit(cache=True, nogil=True)
def rotation_rows(q: tuple) -> tuple:
    """The rotation matrix of the unit quaternion ``q`` (body -> world) as three rows of three floats."""
    w, x, y, z = q
    return ((w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z))


@njit(cache=True, nogil=True)
def yaw_turn(angle_rad: float) -> tuple:
    """The rotation by ``angle_rad`` about world down (NED ``z``)."""
    return math.cos(0.5 * angle_rad), 0.0, 0.0, math.sin(0.5 * angle_rad)
