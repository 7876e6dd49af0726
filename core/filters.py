"""Recursive Bingham filters for attitude (state: a :class:`~core.bingham.Bingham`).

Papers: Gilitschenski et al., "Unscented Orientation Estimation Based on the
Bingham Distribution" (unscented paper), sec. IV; Li et al., "Progressive
Bingham Filter" (progressive paper), Alg. 1 and 2; the saddlepoint paper for
the normalization constant behind every moment match.
"""

from __future__ import annotations

import math
from typing import Callable, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core import quaternion as quat
from core.bingham import Bingham, composition_inertia
from core.bingham_kernels import rms_angle_deg as moments_rms_angle_deg
from core.normalization import Method
from core.rss import rss_samples

__all__ = ["BinghamFilter", "Sampler", "deterministic_samples", "identity_likelihood", "rms_angle_deg"]

Sampler = Literal["unscented", "rss"]
_CONJUGATE = np.diag([1.0, -1.0, -1.0, -1.0])


def deterministic_samples(
    state: Bingham, sampler: Sampler = "unscented", m: int = 100, lam: float = 0.5, method: Method = "saddlepoint"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points and weights with the inertia of ``state``.

    ``"unscented"``: the 7 points around one mode (unscented paper, sec. III;
    the mirrored 7 add nothing to a quadratic statistic). ``"rss"``: ``m``
    equally weighted Riemannian spherical samples (:mod:`core.rss`).
    """
    if sampler == "unscented":
        return state.unscented_samples(lam, antipodal=False, method=method)
    if sampler == "rss":
        return rss_samples(state, m, method)
    raise ValueError(f"sampler must be 'unscented' or 'rss', got {sampler!r}")


def identity_likelihood(z: ArrayLike, noise: Bingham) -> Bingham:
    """The likelihood ``f_v(x^-1 (x) z)`` of ``z = x (x) v`` as a Bingham in ``x``.

    ``x^-1 (x) z = R(z) J x`` (``J`` conjugates), so the exponent is
    ``x^T (J R(z)^T M_v) Z_v (J R(z)^T M_v)^T x`` (unscented paper, sec. IV-B).
    """
    zq = quat.as_quaternion(z)
    return Bingham._trusted(_CONJUGATE @ quat.right_matrix(zq).T @ noise.M, noise.Z)


class BinghamFilter:
    """Quaternion Bingham filter; the state is always a :class:`Bingham`.

    ``method`` chooses the normalization constant used by every moment match
    (``"saddlepoint"`` fast, ``"exact"`` accurate).
    """

    def __init__(self, initial: Bingham, method: Method = "saddlepoint") -> None:
        self.state = initial
        self.method: Method = method

    # -- prediction -----------------------------------------------------------
    def predict(self, noise: Bingham, u: ArrayLike | None = None) -> Bingham:
        """``x_k = x_(k-1) (x) u (x) w`` in closed form (progressive paper, Alg. 1).

        Rotates ``M`` by ``u`` on the right (eq. 6), then composes with the
        noise ``w ~ noise`` by moment matching (QBF paper, A.9).
        """
        state = self.state if u is None else self.state.rotate_right(u)
        self.state = state.compose(noise, self.method)
        return self.state

    def predict_nonlinear(
        self,
        g: Callable[[NDArray[np.float64]], NDArray[np.float64]],
        noise: Bingham,
        sampler: Sampler = "unscented",
        m: int = 100,
        lam: float = 0.5,
    ) -> Bingham:
        """``x_k = g(x_(k-1)) (x) w`` for any ``g`` with ``g(-x) = -g(x)`` (unscented paper, sec. IV-A).

        Deterministic samples are propagated through ``g`` (vectorised over
        rows), their weighted inertia is composed with the noise in closed
        form and a Bingham is fitted to the result.
        """
        points, weights = deterministic_samples(self.state, sampler, m, lam, self.method)
        moved = quat.normalize(g(points))
        inertia = (moved * weights[:, None]).T @ moved
        self.state = Bingham.fit(composition_inertia(inertia, noise.inertia(self.method)), self.method)
        return self.state

    # -- updates --------------------------------------------------------------
    def update(self, z: ArrayLike, noise: Bingham) -> Bingham:
        """Identity measurement ``z = x (x) v``: exact product of densities (unscented paper, sec. IV-B).

        Zero entries in ``noise.Z`` beyond the last make measurements that
        inform only one or two axes.
        """
        self.state = self.state.product(identity_likelihood(z, noise))
        return self.state

    def update_likelihood(
        self,
        loglik: Callable[[NDArray[np.float64]], NDArray[np.float64]],
        tau: float = 0.1,
        sampler: Sampler = "unscented",
        m: int = 100,
        lam: float = 0.5,
        max_steps: int = 200,
    ) -> Bingham:
        """Progressive update with any measurement model (progressive paper, Alg. 2, eqs. 14-16).

        ``loglik`` maps quaternions (rows) to log-likelihoods. Each progression
        step reweights deterministic samples by ``likelihood**lam_i`` with
        ``lam_i`` chosen so that the weights differ by at most ``1/tau``
        (eq. 16), computed in log space so that very peaked likelihoods do
        not underflow; after ``max_steps`` the remaining exponent is applied
        at once.
        """
        if not 0.0 < tau < 1.0:
            raise ValueError(f"tau must lie in (0, 1), got {tau}")
        remaining = 1.0
        for step in range(max_steps):
            points, weights = deterministic_samples(self.state, sampler, m, lam, self.method)
            ll = np.asarray(loglik(points), dtype=float)
            if ll.shape != weights.shape or np.any(np.isnan(ll)) or np.any(ll == np.inf):
                raise ValueError("loglik must return one finite or -inf value per sample")
            top = ll.max()
            if top == -np.inf:
                return self.state  # line 9-10 of Alg. 2: the likelihood vanishes on every sample
            spread = top - ll.min()
            lam_i = remaining if step == max_steps - 1 or spread == 0.0 else min(remaining, math.log(1.0 / tau) / spread)
            weights = weights * np.exp(lam_i * (ll - top))
            self.state = Bingham.from_samples(points, weights, self.method)
            remaining -= lam_i
            if remaining <= 1e-12:
                break
        return self.state

    # -- summaries ------------------------------------------------------------
    @property
    def estimate(self) -> NDArray[np.float64]:
        """Mode of the state (w, x, y, z), w >= 0."""
        return self.state.mode

    @property
    def uncertainty_deg(self) -> float:
        """Root-mean-square angular deviation from the mode, in degrees.

        ``sin^2(theta/2) = 1 - (mode . x)^2`` exactly for the rotation angle
        ``theta`` between ``x`` and the mode, so ``E[sin^2(theta/2)] = 1 -
        omega_4``; this returns ``2 asin(sqrt(1 - omega_4))``, which equals
        the RMS angle to first order and is exact given the moments.
        """
        return rms_angle_deg(self.state, self.method)


def rms_angle_deg(state: Bingham, method: Method = "saddlepoint") -> float:
    """``2 asin(sqrt(E[sin^2(theta/2)]))`` in degrees for ``theta`` the angle to the mode
    (:func:`core.bingham_kernels.rms_angle_deg` of the state's moments)."""
    return float(moments_rms_angle_deg(np.ascontiguousarray(state.moments(method), dtype=np.float64)))
