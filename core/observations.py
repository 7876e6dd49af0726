"""Measurement likelihoods that are exactly Bingham densities in the attitude quaternion.

A unit vector ``b`` measured in the body frame of a known world vector ``r``
with Gaussian error, ``p(b | q) ~ exp(-|R(q) b - r|^2 / (2 sigma^2))``, is a
Bingham density in ``q``: for unit vectors ``|R b - r|^2 = 2 - 2 r.R(q)b``
and, writing vectors as pure quaternions, ``r.R(q)b = (r q).(q b) =
q^T R(b)^T L(r) q`` (``R(q)b`` is ``q b q*``, and right multiplication by a
unit ``q`` preserves the inner product). So the likelihood is
``exp(q^T K q / sigma^2)`` with ``K = sym(R(b)^T L(r))``, Davenport's
q-method matrix for one vector pair. ``K`` has eigenvalues +1, +1, -1, -1:
the measurement informs the two rotational degrees of freedom that move
``b`` off ``r`` and nothing about the rotation about ``r``
(``Z = (-2/sigma^2, -2/sigma^2, 0, 0)``). The update is therefore an exact
product of Binghams (unscented paper, sec. IV-B), verified against the
progressive update in the tests.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from core import quaternion as quat
from core.bingham import Bingham

__all__ = ["heading_exponent", "heading_likelihood", "vector_exponent", "vector_likelihood"]


def _kernel_array(v: ArrayLike) -> np.ndarray:
    """``v`` as the one array type the kernels are compiled for: C-contiguous float64 and writable (numba types a
    read-only array, such as a module's constant, apart, and would compile a kernel a second time for it)."""
    arr = np.ascontiguousarray(v, dtype=np.float64)
    return arr if arr.flags.writeable else arr.copy()


def _check_sigma(sigma: float) -> None:
    if not sigma > 0:
        raise ValueError("sigma must be positive")


def vector_exponent(b_body: ArrayLike, r_world: ArrayLike, sigma: float) -> np.ndarray:
    """Exponent ``K / sigma^2``, ``K = sym(R(b)^T L(r))``, of the vector likelihood (module docstring).

    Written out, ``K`` is Davenport's matrix for the profile ``B = r b^T``:
    ``[[tr B, (b x r)^T], [b x r, B + B^T - tr(B) I]]`` (checked against the
    quaternion-matrix form in the tests); compiled (:func:`_davenport`), a
    gravity reading's per-tick cost.
    """
    _check_sigma(sigma)
    b, r = _kernel_array(b_body), _kernel_array(r_world)
    k = _davenport(b, r, float(sigma)) if b.shape == r.shape == (3,) else None
    if k is None:
        raise ValueError("direction vectors must be finite and non-zero")
    return k


@njit(cache=True, nogil=True)
def _davenport(b: np.ndarray, r: np.ndarray, sigma: float):
    """Davenport's ``K / sigma^2`` for the unit directions of ``b`` and ``r`` (None if either is zero or not finite)."""
    nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    nr = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    if not (math.isfinite(nb) and math.isfinite(nr) and nb > 0.0 and nr > 0.0):
        return None
    bx, by, bz = b[0] / nb, b[1] / nb, b[2] / nb
    rx, ry, rz = r[0] / nr, r[1] / nr, r[2] / nr
    trace = rx * bx + ry * by + rz * bz
    cx, cy, cz = by * rz - bz * ry, bz * rx - bx * rz, bx * ry - by * rx
    s2 = sigma * sigma
    k = np.empty((4, 4))
    k[0, 0] = trace / s2
    k[0, 1] = cx / s2
    k[0, 2] = cy / s2
    k[0, 3] = cz / s2
    k[1, 1] = (2 * rx * bx - trace) / s2
    k[1, 2] = (rx * by + ry * bx) / s2
    k[1, 3] = (rx * bz + rz * bx) / s2
    k[2, 2] = (2 * ry * by - trace) / s2
    k[2, 3] = (ry * bz + rz * by) / s2
    k[3, 3] = (2 * rz * bz - trace) / s2
    for i in range(4):
        for j in range(i):
            k[i, j] = k[j, i]
    return k


def vector_likelihood(b_body: ArrayLike, r_world: ArrayLike, sigma: float) -> Bingham:
    """Likelihood of observing direction ``b_body`` of world direction ``r_world`` (sigma in radians)."""
    return Bingham.from_exponent(vector_exponent(b_body, r_world, sigma))


def heading_exponent(q_ref: ArrayLike, heading_error_rad: float, sigma: float) -> np.ndarray:
    """Exponent of a heading measurement that informs yaw only: rank one, ``-(2/sigma^2) v v^T``.

    The measurement is ``z = Rz(error) (x) q_ref`` (``q_ref`` turned about
    world down) with identity model ``z = x (x) v`` whose noise is
    concentrated only about ``a``, the body-frame direction of world down
    (unscented paper, sec. IV-B: zero entries in Z for axes a measurement
    does not inform). Its density ``exp(kappa ((x^-1 (x) z) . a)^2)`` is, with
    ``x^-1 (x) z = R(z) J x``, ``exp(kappa (v . x)^2)`` for ``v = J R(z)^T a``,
    ``kappa = -2/sigma^2`` (the vector part of a small rotation is half its
    angle): roll and pitch are untouched. With ``a = q_ref^* k q_ref`` (``k``
    the pure quaternion of down) and ``R(z)^T p = p z^*``, ``v = conj(a z^*) =
    -Rz(error) k q_ref``, which is computed directly.
    """
    _check_sigma(sigma)
    return _heading_exponent(np.ascontiguousarray(quat.as_quaternion(q_ref)), float(heading_error_rad), float(sigma))


@njit(cache=True, nogil=True)
def _heading_exponent(q: np.ndarray, heading_error_rad: float, sigma: float) -> np.ndarray:
    """:func:`heading_exponent`, compiled: ``v = (sin(e/2), 0, 0, -cos(e/2)) (x) q_ref``, ``-(2/sigma^2) v v^T``."""
    half = 0.5 * heading_error_rad
    s, c = math.sin(half), -math.cos(half)
    v = np.empty(4)  # not np.array([...]): one array constructor fewer to compile
    v[0] = s * q[0] - c * q[3]
    v[1] = s * q[1] - c * q[2]
    v[2] = s * q[2] + c * q[1]
    v[3] = s * q[3] + c * q[0]
    kappa = -2.0 / (sigma * sigma)
    out = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            out[i, j] = kappa * (v[i] * v[j])
    return out


def heading_likelihood(q_ref: ArrayLike, heading_error_rad: float, sigma: float) -> Bingham:
    """Likelihood of a yaw-only heading measurement (see :func:`heading_exponent`)."""
    return Bingham.from_exponent(heading_exponent(q_ref, heading_error_rad, sigma))
