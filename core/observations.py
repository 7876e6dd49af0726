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

import numpy as np
from numpy.typing import ArrayLike

from core import quaternion as quat
from core.bingham import Bingham

__all__ = ["heading_exponent", "heading_likelihood", "vector_exponent", "vector_likelihood"]

_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])


def _pure(v: ArrayLike) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm == 0.0:
        raise ValueError("direction vectors must be finite and non-zero")
    return np.concatenate([[0.0], v / norm])


def _check_sigma(sigma: float) -> None:
    if not sigma > 0:
        raise ValueError("sigma must be positive")


def vector_exponent(b_body: ArrayLike, r_world: ArrayLike, sigma: float) -> np.ndarray:
    """Exponent ``K / sigma^2``, ``K = sym(R(b)^T L(r))``, of the vector likelihood (module docstring)."""
    _check_sigma(sigma)
    k = quat.right_matrix(_pure(b_body)).T @ quat.left_matrix(_pure(r_world))
    return (k + k.T) / (2.0 * sigma * sigma)


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
    angle): roll and pitch are untouched.
    """
    _check_sigma(sigma)
    q_ref = quat.as_quaternion(q_ref)
    down_body = quat.rotate(quat.conjugate(q_ref), [0.0, 0.0, 1.0])
    z = quat.multiply(quat.from_rotvec([0.0, 0.0, heading_error_rad]), q_ref)
    v = _CONJUGATE * (quat.right_matrix(z).T @ np.concatenate([[0.0], down_body]))
    return (-2.0 / (sigma * sigma)) * np.outer(v, v)


def heading_likelihood(q_ref: ArrayLike, heading_error_rad: float, sigma: float) -> Bingham:
    """Likelihood of a yaw-only heading measurement (see :func:`heading_exponent`)."""
    return Bingham.from_exponent(heading_exponent(q_ref, heading_error_rad, sigma))
