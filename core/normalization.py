"""Normalization constant of the Bingham distribution, its derivatives, and moment matching.

``N(Z) = int_{S^(n-1)} exp(x^T Z x) dx`` with the surface measure, so
``N(0) = |S^(n-1)|`` (``2 pi^2`` for ``n = 4``). Two methods:

``"saddlepoint"`` (default)
    Kume-Wood third-order saddlepoint approximation (saddlepoint paper,
    sec. III-A; corrections to the printed formulas in
    :mod:`core.saddlepoint`), derivatives by the dimension-raising identity
    (Corollary 2, eq. 4). Any ``n >= 2``, a few microseconds per call.
    Measured error against ``"exact"`` (README, "Accuracy"): up to 6.4% in
    ``N`` and 5.1% in the dispersion moments near ``z ~ -(5, 5, 3, 0)``,
    about 1.3% when extremely concentrated, 0.03% at ``Z = 0``.
``"exact"``
    One-dimensional Gauss-Legendre quadrature in Hopf coordinates
    (:mod:`core.hopf_quadrature`), about 1e-13 relative; ``n`` in 2, 3, 4;
    about 1 ms per call.

Every function works in log space and accepts any finite ``z`` (entries may
be positive, repeated, or of magnitude 1e6 and beyond), using
``N(Z + cI) = N(Z) exp(c)`` (saddlepoint paper, eq. 3).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scipy import optimize

from core import hopf_quadrature, saddlepoint

__all__ = ["Method", "fit_dispersion", "fit_dispersion_trusted", "log_normalizer", "moments", "moments_jacobian", "moments_trusted", "METHODS"]

Method = Literal["saddlepoint", "exact"]
METHODS: tuple[str, ...] = ("saddlepoint", "exact")

#: Smallest dispersion moment ``E[x_i^2]`` a fit accepts; smaller ones (a
#: degenerate inertia, e.g. from one sample) are raised to it, which caps the
#: concentration at about ``|z| = 1 / (2 MIN_MOMENT) = 5e9``.
MIN_MOMENT = 1e-10

# Squared log-moment residual at which Gauss-Newton stops (1e-10 relative per moment).
_CONVERGED = 1e-20
_NO_START = np.empty(0)  # saddlepoint.fit_moments: start from _initial_z


def _as_z(z: ArrayLike) -> NDArray[np.float64]:
    arr = np.ascontiguousarray(z, dtype=np.float64)
    if arr.ndim != 1 or arr.shape[0] < 2:
        raise ValueError(f"z must be a 1-D array of at least 2 entries, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("z has NaN or infinite entries")
    return arr


def _check_method(method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")


def log_normalizer(z: ArrayLike, method: Method = "saddlepoint") -> float:
    """Natural log of the Bingham normalization constant ``N(diag(z))``."""
    arr = _as_z(z)
    _check_method(method)
    if method == "exact":
        return hopf_quadrature.log_normalizer_and_moments(arr)[0]
    return float(saddlepoint.log_c3(arr, np.ones(arr.shape[0])))


def moments(z: ArrayLike, method: Method = "saddlepoint") -> NDArray[np.float64]:
    """``E[x_i^2]`` under ``Bingham(I, diag(z))``; the entries sum to 1.

    With ``"saddlepoint"`` this is ``(dN/dz_i) / sum_k dN/dz_k``, each
    derivative by Corollary 2. The exact derivatives satisfy
    ``sum_k dN/dz_k = N`` (from eq. 3); dividing by the sum of the
    approximated derivatives instead of the approximated ``N`` keeps the
    moments on the simplex, as the moments of unit vectors must be.
    """
    return moments_trusted(_as_z(z), method)


def moments_trusted(z: NDArray[np.float64], method: Method) -> NDArray[np.float64]:
    """:func:`moments` without checking ``z``, for one already checked (a :class:`~core.bingham.Bingham`'s)."""
    if method == "saddlepoint":
        return saddlepoint.moments(z)
    _check_method(method)
    return hopf_quadrature.log_normalizer_and_moments(z)[1]


def moments_jacobian(z: ArrayLike, method: Method = "saddlepoint") -> tuple[NDArray, NDArray]:
    """Moments ``m = moments(z)`` and their Jacobian ``dm_i / dz_j``.

    ``"saddlepoint"``: from the second derivatives ``d2N/dz_i dz_j`` by the
    general dimension-raising identity (saddlepoint paper, eq. 4). Those
    approximations do not satisfy ``sum_j d2N/dz_i dz_j = dN/dz_i`` exactly,
    so the last column is set from the shift identity (eq. 3: the moments do
    not change when every ``z_j`` moves together); rows and columns then sum
    to zero like the exact Jacobian's.
    ``"exact"`` (n = 4): ``E[x_i^2 x_j^2] - E[x_i^2] E[x_j^2]`` by quadrature.
    """
    arr = _as_z(z)
    _check_method(method)
    if method == "exact":
        _, m, fourth = hopf_quadrature.moments_and_fourth(arr)
        return m, fourth - np.outer(m, m)
    _, g, h = saddlepoint.derivatives(arr, 2)
    dg = h - np.outer(g, g)  # d(N_i/N)/dz_j
    total = g.sum()
    jac = dg / total - np.outer(g, dg.sum(axis=0)) / total**2
    jac[:, -1] = -jac[:, :-1].sum(axis=1)
    return g / total, jac


def _initial_z(target: NDArray) -> NDArray:
    """Start for Gauss-Newton: ``z_i = 1/(2 m_n) - 1/(2 m_i)``.

    Exact at ``Z = 0`` and asymptotically exact for high concentration,
    where ``E[x_i^2] -> 1 / (2 |z_i|)``.
    """
    return 0.5 / target[-1] - 0.5 / target


def _exact_fit(z0: NDArray, log_target: NDArray) -> NDArray:
    """Solve the exact moment equations with MINPACK's Levenberg-Marquardt (scipy)."""

    def residual(free: NDArray) -> tuple[NDArray, NDArray]:
        z = np.append(np.minimum(free, 0.0), 0.0)
        m, jac = moments_jacobian(z, "exact")
        return np.log(m[:-1]) - log_target[:-1], jac[:-1, :-1] / m[:-1, None]

    sol = optimize.root(residual, z0[:-1], jac=True, method="lm", options={"xtol": 1e-14})
    return np.append(np.minimum(sol.x, 0.0), 0.0)


def fit_dispersion(
    target: ArrayLike,
    method: Method = "saddlepoint",
    *,
    max_iter: int = 60,
) -> NDArray[np.float64]:
    """Solve ``moments(z) = target`` for ``z`` (ascending, last entry 0).

    ``"saddlepoint"``: Gauss-Newton as in the saddlepoint paper, sec. III-B
    (eqs. 5-6; :func:`core.saddlepoint.fit_log_moments`), with two changes
    that make it converge from uniform to |z| = 1e9: the residual is taken in
    log space (``log m_i - log e_i``, nearly linear in ``z`` when
    concentrated), and ``z_n`` is held at 0 instead of re-shifting each
    iteration (eq. 3 makes one entry free, and the moments' sum-to-one makes
    one equation redundant). ``"exact"``: the same equations with exact
    moments and Jacobian, solved by scipy's Levenberg-Marquardt.

    ``target`` are the eigenvalues of an inertia matrix in ascending order,
    summing to 1; entries below ``MIN_MOMENT`` are raised to it.
    """
    _check_method(method)
    t = np.asarray(target, dtype=np.float64)
    if t.ndim != 1 or t.shape[0] < 2 or not np.all(np.isfinite(t)):
        raise ValueError("target moments must be a finite 1-D array of at least 2 entries")
    if np.any(np.diff(t) < -1e-12):
        raise ValueError("target moments must be in ascending order")
    if abs(t.sum() - 1.0) > 1e-6:
        raise ValueError(f"target moments must sum to 1, got {t.sum():.9g}")
    return fit_dispersion_trusted(np.sort(t), method, max_iter=max_iter)[0]


def fit_dispersion_trusted(
    target: NDArray[np.float64], method: Method, start: NDArray[np.float64] | None = None, max_iter: int = 60
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """:func:`fit_dispersion` without validation, for the sorted eigenvalues of an inertia
    this package computed itself; also returns the saddlepoint moments at the solution
    (``None`` for ``"exact"``, whose moments equal the target to 1e-14).

    ``start`` (ascending, ``<= 0``, last entry 0), e.g. the previous solution
    when a distribution changes slowly, replaces the first guess of the
    saddlepoint Gauss-Newton (same solution to the tolerance, in a step or
    two). The exact solver ignores it: Levenberg-Marquardt from a distant
    start can stall on the ``z <= 0`` bound.
    """
    if method == "saddlepoint":
        begin = _NO_START if start is None else np.ascontiguousarray(start, dtype=np.float64)
        return saddlepoint.fit_moments(np.ascontiguousarray(target, dtype=np.float64), begin, MIN_MOMENT, _CONVERGED, max_iter)
    t = np.maximum(target, MIN_MOMENT)
    t /= t.sum()
    return np.sort(_exact_fit(_initial_z(t), np.log(t))), None
