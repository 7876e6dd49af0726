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
from core.filters import identity_likelihood

__all__ = ["heading_likelihood", "vector_likelihood"]


def _pure(v: ArrayLike) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm == 0.0:
        raise ValueError("direction vectors must be finite and non-zero")
    return np.concatenate([[0.0], v / norm])


def vector_likelihood(b_body: ArrayLike, r_world: ArrayLike, sigma: float) -> Bingham:
    """Likelihood of observing direction ``b_body`` of world direction ``r_world`` (sigma in radians)."""
    if not sigma > 0:
        raise ValueError("sigma must be positive")
    k = quat.right_matrix(_pure(b_body)).T @ quat.left_matrix(_pure(r_world))
    evals, evecs = np.linalg.eigh((k + k.T) / (2.0 * sigma * sigma))
    return Bingham._trusted(evecs, evals)


def heading_likelihood(q_ref: ArrayLike, heading_error_rad: float, sigma: float) -> Bingham:
    """Likelihood of a heading measurement that informs yaw only.

    The measurement is ``q_ref`` turned about the world down axis by
    ``heading_error_rad``; its noise (identity model ``z = x (x) v``) is
    concentrated only about the body-frame direction of world down, so roll
    and pitch are untouched (unscented paper, sec. IV-B: zero entries in Z for
    axes a measurement does not inform).
    """
    if not sigma > 0:
        raise ValueError("sigma must be positive")
    q_ref = quat.as_quaternion(q_ref)
    down_body = quat.rotate(quat.conjugate(q_ref), [0.0, 0.0, 1.0])
    basis = np.linalg.svd(down_body[None, :])[2]  # rows: down_body, then two orthogonal axes
    M = np.zeros((4, 4))
    M[1:, :3] = basis.T
    M[0, 3] = 1.0
    noise = Bingham._trusted(M, np.array([-2.0 / sigma**2, 0.0, 0.0, 0.0]))
    z = quat.multiply(quat.from_rotvec([0.0, 0.0, heading_error_rad]), q_ref)
    return identity_likelihood(z, noise)
