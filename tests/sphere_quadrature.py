"""Independent references for the tests: brute-force integrals over spheres.

Tensor-product Gauss-Legendre in hyperspherical coordinates, with no use of
the project's Bessel reduction or saddlepoint code.
"""

from __future__ import annotations

import math

import numpy as np


def sphere_grid(n_dim: int, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (n_dim, K) and weights (K,) of a quadrature over S^(n_dim - 1)."""
    g, gw = np.polynomial.legendre.leggauss(nodes)
    polar = (g + 1.0) * np.pi / 2.0
    polar_w = gw * np.pi / 2.0
    azim = (g + 1.0) * np.pi
    azim_w = gw * np.pi
    angles = np.meshgrid(*([polar] * (n_dim - 2) + [azim]), indexing="ij")
    weights = np.ones_like(angles[0])
    for k, w1 in enumerate([polar_w] * (n_dim - 2) + [azim_w]):
        shape = [1] * (n_dim - 1)
        shape[k] = -1
        weights = weights * w1.reshape(shape)
    x = []
    sin_prod = np.ones_like(angles[0])
    for k in range(n_dim - 1):
        x.append(sin_prod * np.cos(angles[k]))
        if k < n_dim - 2:
            weights = weights * np.sin(angles[k]) ** (n_dim - 2 - k)
        sin_prod = sin_prod * np.sin(angles[k])
    x.append(sin_prod)
    return np.stack([c.ravel() for c in x]), weights.ravel()


def brute_force(z: np.ndarray, nodes: int = 120) -> tuple[float, np.ndarray]:
    """``log N(diag(z))`` and ``E[x_i^2]`` by direct integration over the sphere."""
    z = np.asarray(z, dtype=float)
    x, w = sphere_grid(z.shape[0], nodes)
    expo = z @ (x * x)
    f = w * np.exp(expo - z.max())
    total = f.sum()
    return z.max() + math.log(total), (x * x) @ f / total


def sphere_area(n_dim: int) -> float:
    """``|S^(n-1)| = 2 pi^(n/2) / Gamma(n/2)``."""
    return 2.0 * math.pi ** (n_dim / 2) / math.gamma(n_dim / 2)


def importance_moments(z: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Monte Carlo ``E[x_i^2]`` and its standard error by weighting uniform points."""
    x = rng.standard_normal((n, len(z)))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    w = np.exp((x * x) @ z - np.max(z))
    w /= w.sum()
    mean = (x * x).T @ w
    var = ((x * x - mean) ** 2).T @ (w * w)
    return mean, np.sqrt(var)
