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
from numpy.typing import ArrayLike

from core import quaternion as quat
from core.bingham import Bingham

__all__ = ["heading_exponent", "heading_likelihood", "vector_exponent", "vector_likelihood"]


def _unit(v: ArrayLike) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    norm = float(np.sqrt(v @ v))
    if not np.isfinite(norm) or norm == 0.0:
        raise ValueError("direction vectors must be finite and non-zero")
    return v / norm


def _check_sigma(sigma: float) -> None:
    if not sigma > 0:
        raise ValueError("sigma must be positive")


def vector_exponent(b_body: ArrayLike, r_world: ArrayLike, sigma: float) -> np.ndarray:
    """Exponent ``K / sigma^2``, ``K = sym(R(b)^T L(r))``, of the vector likelihood (module docstring).

    Written out, ``K`` is Davenport's matrix for the profile ``B = r b^T``:
    ``[[tr B, (b x r)^T], [b x r, B + B^T - tr(B) I]]`` (checked against the
    quaternion-matrix form in the tests).
    """
    _check_sigma(sigma)
    bx, by, bz = _unit(b_body).tolist()
    rx, ry, rz = _unit(r_world).tolist()
    trace = rx * bx + ry * by + rz * bz
    cross = (by * rz - bz * ry, bz * rx - bx * rz, bx * ry - by * rx)
    k = np.array(
        [
            [trace, *cross],
            [cross[0], 2 * rx * bx - trace, rx * by + ry * bx, rx * bz + rz * bx],
            [cross[1], rx * by + ry * bx, 2 * ry * by - trace, ry * bz + rz * by],
            [cross[2], rx * bz + rz * bx, ry * bz + rz * by, 2 * rz * bz - trace],
        ]
    )
    return k / (sigma * sigma)


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
    q_ref = quat.as_quaternion(q_ref)
    half = 0.5 * heading_error_rad
    v = quat.multiply(np.array([math.sin(half), 0.0, 0.0, -math.cos(half)]), q_ref)
    return (-2.0 / (sigma * sigma)) * np.outer(v, v)


def heading_likelihood(q_ref: ArrayLike, heading_error_rad: float, sigma: float) -> Bingham:
    """Likelihood of a yaw-only heading measurement (see :func:`heading_exponent`)."""
    return Bingham.from_exponent(heading_exponent(q_ref, heading_error_rad, sigma))
