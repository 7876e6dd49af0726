"""Unit quaternions in MAVLink order (w, x, y, z), Hamilton convention.

Every function is vectorised over leading axes: a quaternion argument has
shape ``(..., 4)`` and a 3-vector ``(..., 3)``. A quaternion ``q`` maps body
vectors to world vectors, ``v_world = q v_body q*``, as MAVLink's
ATTITUDE_QUATERNION does (body FRD to world NED).

The power ``q**c`` and the antipodal-aware angular distance follow
Gilitschenski et al., "Unscented Orientation Estimation Based on the Bingham
Distribution" (unscented paper), sec. II and eq. (4).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "IDENTITY",
    "angular_distance",
    "as_quaternion",
    "conjugate",
    "from_axis_angle",
    "from_matrix",
    "from_rotvec",
    "inverse",
    "left_matrix",
    "multiply",
    "normalize",
    "power",
    "right_matrix",
    "rotate",
    "to_axis_angle",
    "to_matrix",
    "to_rotvec",
]

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])

_UNIT_TOL = 1e-6

_CONJUGATE_SIGN = np.array([1.0, -1.0, -1.0, -1.0])
_CONJUGATE_SIGN.setflags(write=False)


def as_quaternion(q: ArrayLike, *, unit: bool = True) -> NDArray[np.float64]:
    """Return ``q`` as a float array of shape (..., 4), validated.

    Raises ``ValueError`` for a wrong shape, NaN/inf, or (with ``unit``) a
    norm further than 1e-6 from one.
    """
    arr = np.asarray(q, dtype=float)
    if arr.shape == (4,):  # one quaternion, the common case in a filter loop: its squared norm in plain floats checks it all
        w, x, y, z = arr.tolist()
        norm2 = w * w + x * x + y * y + z * z
        if math.isfinite(norm2) and (not unit or abs(norm2 - 1.0) <= _UNIT_TOL):
            return arr
    elif arr.shape[-1:] != (4,):
        raise ValueError(f"a quaternion needs 4 components (w, x, y, z), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("quaternion has NaN or infinite components")
    if unit:
        norm = np.linalg.norm(arr, axis=-1)
        if np.any(np.abs(norm - 1.0) > _UNIT_TOL):
            worst = float(norm.flat[np.argmax(np.abs(norm - 1.0))])
            raise ValueError(f"quaternion is not unit length (norm {worst:.9g}); normalize() it first")
    return arr


def normalize(q: ArrayLike) -> NDArray[np.float64]:
    """Scale ``q`` to unit length; raises ``ValueError`` for zero or non-finite input."""
    arr = as_quaternion(q, unit=False)
    if arr.ndim == 1:  # in plain floats: numpy's dot product (BLAS) rounds by the CPU it runs on, and an import must not
        w, x, y, z = arr.tolist()
        scale = math.sqrt(w * w + x * x + y * y + z * z)
        if scale == 0.0:
            raise ValueError("cannot normalize a zero quaternion")
        return arr / scale
    norm = np.linalg.norm(arr, axis=-1, keepdims=True)
    if np.any(norm == 0.0):
        raise ValueError("cannot normalize a zero quaternion")
    return arr / norm


def multiply(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``p q`` (apply ``q`` first, then ``p``)."""
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    if q.shape == (4,) and p.shape == (4,):  # one pair, as in a filter loop: plain floats
        return np.array(_multiply_one(p.tolist(), q.tolist()))
    # element-wise, not a matrix product: numpy's matmul may fuse multiply-adds by the CPU it runs on, and an
    # import or a replay must round alike on every machine
    return np.stack(_multiply_one(np.moveaxis(p, -1, 0), np.moveaxis(q, -1, 0)), axis=-1)  # type: ignore[arg-type]


def _multiply_one(p: Sequence[float], q: Sequence[float]) -> tuple[float, float, float, float]:
    """:func:`multiply` of one pair in plain floats."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def conjugate(q: ArrayLike) -> NDArray[np.float64]:
    """Quaternion conjugate (w, -x, -y, -z)."""
    return np.asarray(q, dtype=float) * _CONJUGATE_SIGN


def inverse(q: ArrayLike) -> NDArray[np.float64]:
    """Multiplicative inverse; equals the conjugate for unit quaternions."""
    arr = np.asarray(q, dtype=float)
    return conjugate(arr) / np.sum(arr * arr, axis=-1, keepdims=True)


# L(q)[i, j] = sign * q[index]: built by one gather, for any leading shape.
_LEFT_INDEX = np.array([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_LEFT_SIGN = np.array([[1.0, -1, -1, -1], [1, 1, -1, 1], [1, 1, 1, -1], [1, -1, 1, 1]])
_RIGHT_SIGN = np.array([[1.0, -1, -1, -1], [1, 1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1]])


def left_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Matrix ``L(q)`` with ``L(q) p == multiply(q, p)``."""
    return np.asarray(q, dtype=float)[..., _LEFT_INDEX] * _LEFT_SIGN


def right_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Matrix ``R(q)`` with ``R(q) p == multiply(p, q)``."""
    return np.asarray(q, dtype=float)[..., _LEFT_INDEX] * _RIGHT_SIGN


def rotate(q: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
    """Rotate 3-vectors: ``q v q*`` (body to world for an attitude quaternion)."""
    v = np.asarray(v, dtype=float)
    R = to_matrix(q)
    x, y, z = np.moveaxis(v, -1, 0)  # element-wise, as :func:`multiply`: the same rounding on every CPU
    return np.stack([R[..., i, 0] * x + R[..., i, 1] * y + R[..., i, 2] * z for i in range(3)], axis=-1)


def to_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix ``R`` with ``R @ v == rotate(q, v)``: the vector block of ``L(q) R(q)^T``."""
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):  # one quaternion: the same entries written out, in plain floats (a flat list builds faster)
        w, x, y, z = q.tolist()
        return np.array(
            [
                w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y),
                2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x),
                2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z,
            ]
        ).reshape(3, 3)
    w, x, y, z = np.moveaxis(q, -1, 0)  # the same entries element-wise (no matrix product: CPU-independent rounding)
    rows = [[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (w >= 0) of a rotation matrix.

    Uses the largest-diagonal branch (Shepperd's method) so that it is accurate
    for every rotation, including those near 180 degrees.
    """
    R = np.asarray(R, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"a rotation matrix must be 3x3, got shape {R.shape}")
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    cand = np.stack(
        [
            np.stack([1 + m00 + m11 + m22, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1),
            np.stack([R[..., 2, 1] - R[..., 1, 2], 1 + m00 - m11 - m22, R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0]], -1),
            np.stack([R[..., 0, 2] - R[..., 2, 0], R[..., 0, 1] + R[..., 1, 0], 1 - m00 + m11 - m22, R[..., 1, 2] + R[..., 2, 1]], -1),
            np.stack([R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1], 1 - m00 - m11 + m22], -1),
        ],
        axis=-2,
    )
    best = np.argmax(np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1), axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def from_axis_angle(axis: ArrayLike, angle: ArrayLike) -> NDArray[np.float64]:
    """Quaternion rotating by ``angle`` radians about the unit ``axis``."""
    axis = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    if np.any(norm == 0.0):
        raise ValueError("rotation axis must be non-zero")
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis / norm], axis=-1)


def to_axis_angle(q: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Axis (unit 3-vector) and angle in [0, pi] of the rotation ``q``.

    The axis of the identity rotation is returned as (1, 0, 0).
    """
    rotvec = to_rotvec(q)
    angle = np.linalg.norm(rotvec, axis=-1)
    safe = np.where(angle[..., None] > 0, rotvec / np.where(angle > 0, angle, 1.0)[..., None], [1.0, 0.0, 0.0])
    return safe, angle


def from_rotvec(rotvec: ArrayLike) -> NDArray[np.float64]:
    """Quaternion of a rotation vector (axis times angle in radians).

    Uses sin(a/2)/a with its Taylor series near zero, so tiny gyro
    increments keep full precision.
    """
    rotvec = np.asarray(rotvec, dtype=float)
    if rotvec.shape == (3,):  # one rotation: plain floats
        return np.array(_from_rotvec_one(*rotvec.tolist()))
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < 1e-4
    sinc = np.where(small, 0.5 - angle * angle / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(half), sinc * rotvec], axis=-1)


def _from_rotvec_one(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """:func:`from_rotvec` of one rotation vector in plain floats."""
    angle = math.sqrt(x * x + y * y + z * z)
    sinc = 0.5 - angle * angle / 48.0 if angle < 1e-4 else math.sin(0.5 * angle) / angle
    return math.cos(0.5 * angle), sinc * x, sinc * y, sinc * z


def to_rotvec(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation vector (angle in [0, pi] times axis) of ``q``; ``q`` and ``-q`` agree."""
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):  # one rotation: plain floats
        return np.array(_rotvec_one(*q.tolist()))
    q = np.where(q[..., :1] < 0, -q, q)
    vec_norm = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(vec_norm, q[..., :1])
    small = vec_norm < 1e-8
    scale = np.where(small, 2.0 / np.where(small, q[..., :1], 1.0), angle / np.where(small, 1.0, vec_norm))
    return scale * q[..., 1:]


def _rotvec_one(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """:func:`to_rotvec` of one quaternion in plain floats."""
    if not w >= 0:
        w, x, y, z = -w, -x, -y, -z
    vec_norm = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 / w if vec_norm < 1e-8 else 2.0 * math.atan2(vec_norm, w) / vec_norm
    return scale * x, scale * y, scale * z


def power(q: ArrayLike, c: ArrayLike) -> NDArray[np.float64]:
    """``q**c``: the rotation about the same axis by ``c`` times the angle (unscented paper, sec. II)."""
    return from_rotvec(np.asarray(c, dtype=float)[..., None] * to_rotvec(q))


def angular_distance(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Rotation angle in radians between the orientations ``p`` and ``q``.

    Antipodal-aware (unscented paper, eq. 4): ``q`` and ``-q`` are the same
    orientation, so the result is ``2 acos(|<p, q>|)`` in [0, pi]. Computed
    with ``atan2`` for accuracy at small angles.
    """
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    d = multiply(conjugate(p), q)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))
