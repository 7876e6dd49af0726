"""Particle filter with importance resampling, the sampling baseline of the unscented paper (sec. V-A).

Particles are unit quaternions. The prediction pushes every particle through
the system function and composes it with its own noise draw; the update
weights particles by the measurement likelihood and resamples (systematic
resampling) "after each update step". With Gaussian noise the likelihood is
the paper's approximation ``p(z | x) ~ f_v(x^-1 (x) z)`` with the
measurement flipped to each particle's hemisphere; with Bingham noise it is
the exact (antipodally symmetric) Bingham density, which needs no flip.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core import quaternion as quat
from core.baselines.gaussian import Gaussian, Side, SystemFunction, canonical, compose, draw_unit
from core.bingham import Bingham

__all__ = ["ParticleFilter", "systematic_resample"]


def systematic_resample(weights: ArrayLike, rng: np.random.Generator) -> NDArray[np.intp]:
    """Indices drawn by systematic resampling (Kitagawa 1996; Douc et al. 2005).

    One uniform offset ``u ~ U[0, 1/N)`` and the ``N`` positions
    ``u + i/N`` are located in the cumulative weights, so particle ``j`` is
    copied ``floor(N w_j)`` or ``ceil(N w_j)`` times. ``weights`` must be
    non-negative with a positive sum (they are normalized here).
    """
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError("weights must be a finite, non-negative vector with a positive sum")
    n = w.size
    cumulative = np.cumsum(w / w.sum())
    cumulative[-1] = 1.0
    positions = (rng.random() + np.arange(n)) / n
    return np.searchsorted(cumulative, positions, side="right")


def _log_likelihood(particles: NDArray, z: NDArray, noise: Bingham | Gaussian, side: Side) -> NDArray[np.float64]:
    """``log f_v(residual)`` up to a constant, ``residual = x^-1 (x) z`` (right) or ``z (x) x^-1`` (left).

    Gaussian ``v``: the measurement is flipped per particle so that
    ``||z - x|| < ||-z - x||`` (unscented paper, sec. V-A).
    """
    if isinstance(noise, Bingham):
        return noise.log_pdf(quat.normalize(compose(quat.conjugate(particles), z, side)))
    flipped = np.where((particles @ z)[:, None] < 0, -z, z)
    d = compose(quat.conjugate(particles), flipped, side) - noise.mean
    return -0.5 * np.einsum("ij,ji->i", d, np.linalg.solve(noise.cov, d.T))


class ParticleFilter:
    """Particle filter on unit quaternions with systematic resampling after every update (unscented paper, sec. V-A).

    ``ParticleFilter(initial, n_particles=300, rng=None)``: ``initial`` is a
    :class:`Bingham` (exact draws) or a :class:`Gaussian` (draws normalized
    to unit length); ``rng`` a ``numpy.random.Generator`` or a seed. The
    paper runs 30, 300 and 10^4 particles. Attributes ``particles`` (N, 4)
    and ``weights`` (N,), summing to one. ``predict(g, noise, side="right")``,
    ``update(z, noise, side="right")``, ``estimate``.
    """

    def __init__(
        self, initial: Bingham | Gaussian, n_particles: int = 300, rng: np.random.Generator | int | None = None
    ) -> None:
        if n_particles < 1:
            raise ValueError(f"n_particles must be positive, got {n_particles}")
        self.rng = np.random.default_rng(rng)
        self.particles: NDArray[np.float64] = draw_unit(initial, n_particles, self.rng)
        self.weights: NDArray[np.float64] = np.full(n_particles, 1.0 / n_particles)

    def predict(self, g: SystemFunction, noise: Bingham | Gaussian, side: Side = "right") -> None:
        """``x_(k+1) = g(x_k) (x) w_k`` with one noise draw per particle (unscented paper, sec. V-A)."""
        noise_draws = draw_unit(noise, len(self.particles), self.rng)
        self.particles = quat.normalize(compose(np.asarray(g(self.particles), dtype=float), noise_draws, side))

    def update(self, z: ArrayLike, noise: Bingham | Gaussian, side: Side = "right") -> None:
        """Importance weighting by ``p(z | x)`` for ``z = x (x) v``, then systematic resampling (sec. V-A)."""
        z = quat.as_quaternion(z)
        log_w = np.log(self.weights) + _log_likelihood(self.particles, z, noise, side)
        w = np.exp(log_w - log_w.max())
        self.particles = self.particles[systematic_resample(w, self.rng)]
        self.weights = np.full(len(self.particles), 1.0 / len(self.particles))

    @property
    def estimate(self) -> NDArray[np.float64]:
        """Principal eigenvector of the weighted inertia ``sum w_i x_i x_i^T`` (the Bingham MLE mode), ``w >= 0``.

        Antipodally invariant, unlike a plain mean of the particles.
        """
        inertia = (self.particles * self.weights[:, None]).T @ self.particles
        return canonical(np.linalg.eigh(inertia)[1][:, -1])
