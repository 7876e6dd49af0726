"""Accurate Bingham normalizer and moments by one-dimensional quadrature.

For ``n = 4`` write ``x = (sqrt(1-s) cos a, sqrt(1-s) sin a, sqrt(s) cos b,
sqrt(s) sin b)`` (Hopf coordinates), with surface element ``ds da db / 2``.
The two circle integrals are Bessel functions,
``int_0^{2 pi} exp(A cos^2 a + B sin^2 a) da = 2 pi exp((A+B)/2) I0((A-B)/2)``,
and with the weights ``cos^2 a``, ``cos^4 a``, ... they become combinations of
``I0``, ``I1``, ``I2``. What is left is an integral over ``s in [0, 1]`` whose
only sharp features sit at the ends, on the scale ``1/|z|``. It is done with
Gauss-Legendre panels graded geometrically towards both ends (down to
``2**-50``), using exponentially scaled Bessel functions and factoring out
``exp(max z)``, so nothing overflows or underflows for ``|z|`` up to 1e12.
``n = 3`` (``x3 = t``, a circle in ``x1, x2``) and ``n = 2`` (closed form) use
the same building blocks.

This is the independent reference (``method="exact"``) for the saddlepoint
approximation; the test suite checks it against a brute-force integral over
the sphere in hyperspherical coordinates.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.special import ive

_LOG_2PI = math.log(2.0 * math.pi)
_GRADING_DEPTH = 50
_NODES_PER_PANEL = 16


@lru_cache(maxsize=1)
def _graded_rule() -> tuple[NDArray, NDArray, NDArray]:
    """Nodes ``s``, ``1 - s`` (both exact) and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(_NODES_PER_PANEL)
    x = 0.5 * (x + 1.0)
    w = 0.5 * w
    edges = np.array([0.0] + [2.0**-k for k in range(_GRADING_DEPTH, 0, -1)])
    lo, hi = edges[:-1, None], edges[1:, None]
    near = (lo + (hi - lo) * x).ravel()  # distance of a node from the nearer end
    weights = ((hi - lo) * w).ravel()
    s = np.concatenate([near, 1.0 - near])
    v = np.concatenate([1.0 - near, near])
    return s, v, np.concatenate([weights, weights])


def _circle_ratios(k: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """``ive0(|k|)``, ``I1(k)/I0(k)``, ``I2(k)/I0(k)`` for the circle integrals."""
    a = np.abs(k)
    i0 = ive(0, a)
    return i0, np.sign(k) * ive(1, a) / i0, ive(2, a) / i0


def _quadrature4(z: NDArray, fourth: bool) -> tuple[float, NDArray, NDArray | None]:
    order = np.argsort(z, kind="stable")
    z1, z2, z3, z4 = z[order]
    s, v, w = _graded_rule()
    k1 = 0.5 * (z1 - z2) * v
    k2 = 0.5 * (z3 - z4) * s
    i0a, r1a, r2a = _circle_ratios(k1)
    i0b, r1b, r2b = _circle_ratios(k2)
    weight = w * np.exp(-(z4 - z2) * v) * i0a * i0b
    total = weight.sum()
    log_n = math.log(2.0 * math.pi**2) + z4 + math.log(total)
    p = weight / total
    c2 = np.stack([v * (1 + r1a) / 2, v * (1 - r1a) / 2, s * (1 + r1b) / 2, s * (1 - r1b) / 2])
    second = c2 @ p
    fourth_m = None
    if fourth:
        vv, ss, sv = v * v, s * s, s * v
        q = np.empty((4, 4, s.size))
        q[0, 0] = vv * (3 + 4 * r1a + r2a) / 8
        q[1, 1] = vv * (3 - 4 * r1a + r2a) / 8
        q[0, 1] = q[1, 0] = vv * (1 - r2a) / 8
        q[2, 2] = ss * (3 + 4 * r1b + r2b) / 8
        q[3, 3] = ss * (3 - 4 * r1b + r2b) / 8
        q[2, 3] = q[3, 2] = ss * (1 - r2b) / 8
        for i, sa in ((0, 1.0), (1, -1.0)):
            for j, sb in ((2, 1.0), (3, -1.0)):
                q[i, j] = q[j, i] = sv * (1 + sa * r1a) * (1 + sb * r1b) / 4
        fourth_m = np.empty((4, 4))
        fourth_m[np.ix_(order, order)] = q @ p
    moments = np.empty(4)
    moments[order] = second
    return log_n, moments, fourth_m


def _quadrature3(z: NDArray) -> tuple[float, NDArray]:
    order = np.argsort(z, kind="stable")
    z1, z2, z3 = z[order]
    s, v, w = _graded_rule()  # t = s, 1 - t = v
    one_minus_t2 = v * (1.0 + s)
    i0, r1, _ = _circle_ratios(0.5 * (z1 - z2) * one_minus_t2)
    weight = w * np.exp(-(z3 - z2) * one_minus_t2) * i0
    total = weight.sum()
    log_n = math.log(4.0 * math.pi) + z3 + math.log(total)
    p = weight / total
    second = np.stack([one_minus_t2 * (1 + r1) / 2, one_minus_t2 * (1 - r1) / 2, s * s]) @ p
    moments = np.empty(3)
    moments[order] = second
    return log_n, moments


def _closed_form2(z: NDArray) -> tuple[float, NDArray]:
    k = 0.5 * (z[0] - z[1])
    i0, r1, _ = _circle_ratios(np.array([k]))
    log_n = _LOG_2PI + max(z[0], z[1]) + math.log(i0[0])
    return log_n, np.array([(1 + r1[0]) / 2, (1 - r1[0]) / 2])


def log_normalizer_and_moments(z: NDArray) -> tuple[float, NDArray]:
    """``log N(Z)`` and ``E[x_i^2]`` for ``n`` in 2, 3, 4."""
    n = z.shape[0]
    if n == 4:
        log_n, m, _ = _quadrature4(z, fourth=False)
        return log_n, m
    if n == 3:
        return _quadrature3(z)
    if n == 2:
        return _closed_form2(z)
    raise ValueError(f'method="exact" is implemented for n = 2, 3, 4, not n = {n}; use method="saddlepoint"')


def moments_and_fourth(z: NDArray) -> tuple[float, NDArray, NDArray]:
    """``log N``, ``E[x_i^2]`` and ``E[x_i^2 x_j^2]`` for ``n = 4``.

    The fourth moments give the exact Jacobian of the moments,
    ``d E[x_i^2] / d z_j = E[x_i^2 x_j^2] - E[x_i^2] E[x_j^2]``.
    """
    if z.shape[0] != 4:
        raise ValueError(f'exact fourth moments are implemented for n = 4, not n = {z.shape[0]}')
    log_n, m, q = _quadrature4(z, fourth=True)
    return log_n, m, q
