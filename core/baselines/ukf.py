"""Quaternion UKF: the Gaussian baseline of the unscented paper (sec. V-A) and the saddlepoint paper (sec. IV-B).

The state is a quaternion treated as a vector in R^4 with a Gaussian
``N(mean, cov)``. Noise enters multiplicatively (``x (x) w``), so both steps
use the augmented unscented transform (Julier and Uhlmann): sigma points of
the joint Gaussian of state and noise go through the exact nonlinear model.
The unscented paper's two fixes are applied in the update: the measurement
is flipped to the hemisphere of the prediction, and the estimate is projected
to the unit sphere at the end of the update.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import block_diag

from core import quaternion as quat
from core.baselines.gaussian import (
    Gaussian,
    Side,
    SystemFunction,
    as_gaussian,
    canonical,
    compose,
    homogeneous,
    kalman_correct,
)
from core.bingham import Bingham

__all__ = ["QuaternionUKF", "sigma_points"]


def sigma_points(mean: NDArray, cov: NDArray, kappa: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The ``2n + 1`` symmetric sigma points and weights of ``N(mean, cov)`` (Julier and Uhlmann's UT).

    Points ``mean`` and ``mean +- sqrt(n + kappa) a_i`` with ``a_i`` the
    columns of a square root of ``cov`` (from ``eigh``, so a singular
    covariance is fine); weights ``kappa / (n + kappa)`` and
    ``1 / (2 (n + kappa))``. ``kappa >= 0`` keeps every weight non-negative.
    """
    n = mean.size
    if kappa < 0:
        raise ValueError(f"kappa must be >= 0, got {kappa}")
    evals, evecs = np.linalg.eigh(cov)
    spread = np.sqrt(n + kappa) * (evecs * np.sqrt(np.clip(evals, 0.0, None))).T
    points = np.concatenate([mean[None], mean + spread, mean - spread])
    weights = np.full(2 * n + 1, 0.5 / (n + kappa))
    weights[0] = kappa / (n + kappa)
    return points, weights


def _weighted_moments(points: NDArray, weights: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    mean = weights @ points
    d = points - mean
    return mean, (d * weights[:, None]).T @ d


class QuaternionUKF:
    """Quaternion UKF in R^4 as compared against in the unscented paper (sec. V-A).

    ``QuaternionUKF(initial, kappa=1.0)``: ``initial`` is a :class:`Gaussian`
    or a :class:`Bingham` (converted by sampling, saddlepoint paper sec.
    IV-B). Attributes ``mean`` (4,) and ``cov`` (4, 4); ``estimate`` is the
    unit quaternion (w, x, y, z), ``w >= 0``. Noise arguments are a
    :class:`Bingham` (converted the same way, seeded and cached) or a
    :class:`Gaussian` used as is; ``side="left"`` switches to the QBF
    paper's ``w (x) x`` models.
    """

    def __init__(self, initial: Bingham | Gaussian, kappa: float = 1.0) -> None:
        start = as_gaussian(initial)
        self.mean: NDArray[np.float64] = start.mean.copy()
        self.cov: NDArray[np.float64] = start.cov.copy()
        self.kappa = float(kappa)

    def _augmented(self, noise: Bingham | Gaussian) -> tuple[NDArray, NDArray]:
        g = as_gaussian(noise)
        return sigma_points(np.concatenate([self.mean, g.mean]), block_diag(self.cov, g.cov), self.kappa)

    def predict(self, g: SystemFunction, noise: Bingham | Gaussian, side: Side = "right") -> None:
        """``x_(k+1) = g(x_k) (x) w_k`` (unscented paper, sec. IV-A model; UT prediction).

        Sigma points of ``(x, w)`` are mapped to ``g(x) (x) w`` with ``g``
        extended off the sphere by :func:`homogeneous`; mean and covariance
        are their weighted moments.
        """
        points, weights = self._augmented(noise)
        moved = compose(homogeneous(g)(points[:, :4]), points[:, 4:], side)
        self.mean, self.cov = _weighted_moments(moved, weights)

    def update(self, z: ArrayLike, noise: Bingham | Gaussian, side: Side = "right") -> None:
        """``z = x (x) v`` (unscented paper, sec. IV-B model; UT update with the sec. V-A fixes).

        Predicted measurements ``x_i / ||x_i|| (x) v_i`` of the augmented
        sigma points give the innovation covariance and cross-covariance;
        ``z`` is flipped to the predicted hemisphere and the corrected mean
        is projected to the unit sphere.
        """
        points, weights = self._augmented(noise)
        states = points[:, :4]
        predicted = compose(quat.normalize(states), points[:, 4:], side)
        z_pred, S = _weighted_moments(predicted, weights)
        cross = ((states - self.mean) * weights[:, None]).T @ (predicted - z_pred)
        mean, self.cov = kalman_correct(self.mean, self.cov, z, z_pred, S, cross)
        self.mean = quat.normalize(mean)

    @property
    def estimate(self) -> NDArray[np.float64]:
        """Unit quaternion (w, x, y, z) of the mean, ``w >= 0``."""
        return canonical(self.mean)
