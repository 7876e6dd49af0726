"""Gaussian noise, quaternion composition and the Kalman correction shared by the baselines.

The baselines treat a quaternion as a vector in R^4 with Gaussian
uncertainty, as the filters the papers compare against do (unscented paper,
sec. V-A; saddlepoint paper, sec. IV-B; QBF paper, sec. 6). This module holds
what they share: the Gaussian counterpart of a Bingham noise (saddlepoint
paper, sec. IV-B), composition ``x (x) w`` or ``w (x) x`` with its Jacobians,
the antipodal measurement fix and the Kalman gain step.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core import quaternion as quat
from core.bingham import Bingham

__all__ = [
    "Gaussian",
    "Side",
    "SystemFunction",
    "as_gaussian",
    "canonical",
    "compose",
    "compose_jacobians",
    "draw_unit",
    "gaussian_from_bingham",
    "homogeneous",
    "kalman_correct",
    "normalization_jacobian",
]

Side = Literal["right", "left"]
SystemFunction = Callable[[NDArray[np.float64]], NDArray[np.float64]]

DEFAULT_SAMPLES = 10_000


@dataclass(frozen=True)
class Gaussian:
    """Gaussian in R^4 over quaternions (w, x, y, z): ``mean`` (4,) and ``cov`` (4, 4)."""

    mean: NDArray[np.float64]
    cov: NDArray[np.float64]

    def __post_init__(self) -> None:
        mean = np.array(self.mean, dtype=float)
        cov = np.array(self.cov, dtype=float)
        if mean.shape != (4,) or cov.shape != (4, 4):
            raise ValueError(f"mean must have shape (4,) and cov (4, 4), got {mean.shape} and {cov.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError("mean and cov must be finite")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", 0.5 * (cov + cov.T))


@lru_cache(maxsize=64)
def _moments_of_samples(M: bytes, Z: bytes, n: int, seed: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    b = Bingham(np.frombuffer(M).reshape(4, 4), np.frombuffer(Z))
    x = b.sample(n, seed)
    x = np.where((x @ b.mode)[:, None] < 0, -x, x)
    mean = x.mean(axis=0)
    d = x - mean
    return mean, d.T @ d / n


def gaussian_from_bingham(noise: Bingham, n: int = DEFAULT_SAMPLES, seed: int = 0) -> Gaussian:
    """Gaussian parameters of a Bingham by random sampling (saddlepoint paper, sec. IV-B).

    "Parameters for corresponding Gaussian distributions were obtained by
    random sampling from the Bingham distributions involved and computing the
    respective means and covariances." ``n`` exact draws (seeded) are moved
    to the hemisphere of the mode first: the Bingham is antipodally
    symmetric, so without that the mean would be zero. The QBF paper (sec. 6)
    maps its noises the same way ("empirically matching second moments").
    Deterministic for a given ``seed``, hence cached.
    """
    if n < 2:
        raise ValueError(f"need at least 2 samples, got {n}")
    mean, cov = _moments_of_samples(noise.M.tobytes(), noise.Z.tobytes(), int(n), int(seed))
    return Gaussian(mean, cov)


def as_gaussian(noise: Bingham | Gaussian) -> Gaussian:
    """``noise`` itself if Gaussian, else its sampled Gaussian counterpart (:func:`gaussian_from_bingham`)."""
    return noise if isinstance(noise, Gaussian) else gaussian_from_bingham(noise)


def draw_unit(noise: Bingham | Gaussian, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``n`` unit-quaternion draws: exact Bingham draws, or ``w / ||w||`` for ``w ~ N`` (unscented paper, sec. V-A)."""
    if isinstance(noise, Bingham):
        return noise.sample(n, rng)
    return quat.normalize(rng.multivariate_normal(noise.mean, noise.cov, size=n, method="eigh"))


def compose(x: ArrayLike, w: ArrayLike, side: Side = "right") -> NDArray[np.float64]:
    """``x (x) w`` (unscented paper, sec. IV: noise on the right) or ``w (x) x`` (QBF paper, sec. 3: on the left)."""
    if side == "right":
        return quat.multiply(x, w)
    if side == "left":
        return quat.multiply(w, x)
    raise ValueError(f"side must be 'right' or 'left', got {side!r}")


def compose_jacobians(x: NDArray, w: NDArray, side: Side = "right") -> tuple[NDArray, NDArray, NDArray]:
    """``compose(x, w, side)`` and its (bilinear, hence exact) Jacobians in ``x`` and in ``w``."""
    if side == "right":
        return quat.multiply(x, w), quat.right_matrix(w), quat.left_matrix(x)
    if side == "left":
        return quat.multiply(w, x), quat.left_matrix(w), quat.right_matrix(x)
    raise ValueError(f"side must be 'right' or 'left', got {side!r}")


def homogeneous(g: SystemFunction) -> SystemFunction:
    """``x -> ||x|| g(x / ||x||)``: the system function on all of R^4 \\ {0}.

    A Gaussian filter evaluates ``g`` at points off the unit sphere (sigma
    points, finite differences); the papers' ``g`` is defined on S^3 only.
    This extension is exact for the linear ``g(x) = L(u) x`` of the QBF
    paper's first-order process and keeps ``g(-x) = -g(x)``.
    """

    def extended(x: NDArray[np.float64]) -> NDArray[np.float64]:
        norm = np.linalg.norm(x, axis=-1, keepdims=True)
        return norm * np.asarray(g(x / norm), dtype=float)

    return extended


def canonical(q: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion of ``q`` with ``w >= 0`` (``q`` and ``-q`` are one orientation; unscented paper, eq. 4)."""
    q = quat.normalize(q)
    return -q if q[0] < 0 else q


def normalization_jacobian(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Jacobian of ``x / ||x||``: ``(I - n n^T) / ||x||`` (LaViola's normalizing measurement, QBF paper sec. 6)."""
    norm = np.linalg.norm(x)
    n = x / norm
    return (np.eye(4) - np.outer(n, n)) / norm


def kalman_correct(
    mean: NDArray, cov: NDArray, z: ArrayLike, z_pred: NDArray, S: NDArray, cross: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Kalman correction with the unscented paper's antipodal fix (sec. V-A).

    The measurement is "multiplied by -1 to ensure ||z - x^p|| < ||-z - x^p||"
    before the update; here ``z`` is compared with the predicted measurement
    ``z_pred`` (which is ``x^p`` up to scale for zero-mean noise). ``S`` is
    the innovation covariance and ``cross`` the state-measurement
    cross-covariance; returns the corrected mean (not yet renormalized) and
    covariance ``P - K S K^T``.
    """
    z = quat.as_quaternion(z)
    if z @ z_pred < 0:
        z = -z
    gain = np.linalg.solve(S, cross.T).T
    new_cov = cov - gain @ S @ gain.T
    return mean + gain @ (z - z_pred), 0.5 * (new_cov + new_cov.T)
