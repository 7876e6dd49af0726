"""Kume-Wood third-order saddlepoint approximation of the Bingham normalizer.

Compiled with numba (``cache=True``); every quantity is kept in log space.

References: Gilitschenski, Kurz, Julier, Hanebeck, "Efficient Bingham
Filtering Based on Saddlepoint Approximations" (saddlepoint paper), sec.
III-A and Corollary 2; Kume & Wood, Biometrika 92(2), 2005 (its ref. [25]).

What the printed formulas get wrong, established numerically (see
``tests/test_normalization.py``, which checks against a direct integral):

* ``K^(j)`` is the cumulant generating function of ``sum_i x_i**2`` with
  ``x_i ~ N(0, 1/(2 lam_i))`` and ``lam_i = -z_i``, i.e.
  ``K(t) = -1/2 sum_i log(1 - t/lam_i)`` and
  ``K^(j)(t) = sum_i (j-1)!/2 / (lam_i - t)**j``. The paper prints
  ``sqrt(-z_i) - t``: with the square root, ``N(0)`` comes out wrong and the
  error grows without bound with concentration. The same applies to the
  product ``prod_i (lam_i - t)**(-1/2)`` and to the bound ``z*``.
* ``rho_j = K^(j) / (K^(2))**(j/2)``, so ``rho_3 = K3 / K2**1.5`` and
  ``rho_4 = K4 / K2**2``, and the correction is
  ``T = rho_4/8 - 5 rho_3**2 / 24`` (``rho_3`` squared). The printed
  ``rho_j = K^(j)/K^(2)`` and ``5 rho_3/24`` are not scale-free and give
  errors of tens of percent.
* Newton must start at the right end ``t = lam_min - 1/2`` of the interval
  ``(lam_min - n/2, lam_min - 1/2)``: ``K'`` is increasing and convex
  (Proposition 1), so from the right every Newton iterate stays at or right
  of the root and left of the pole at ``lam_min``; from the left end the
  first step can jump past the pole.

The approximation depends only on ``lam_i - t``, so it is exactly invariant
under ``Z -> Z + cI`` up to the factor ``exp(c)`` of eq. (3). We solve for
``u = lam_min - t`` in ``(1/2, n/2]`` with ``delta_i = lam_i - lam_min >= 0``;
this is what keeps it accurate for ``|z|`` from 0 to well beyond 1e6.

Derivatives use the dimension-raising identity (Corollary 2 and its general
form, eq. 4): a derivative of order ``k_i`` in ``z_i`` equals
``a(k) N`` of a Bingham normalizer in which ``z_i`` appears ``2 k_i + 1``
times. Here an entry's repetition is passed as a multiplicity, so raising the
dimension costs nothing.

Compiled as :mod:`core.bingham_kernels` says (one signature per kernel,
single-use helpers inlined, ``np.empty`` only): the cold compile is a fresh
install's first start.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

LOG_2PI = math.log(2.0 * math.pi)
_LOG_SQRT2 = 0.5 * math.log(2.0)
_LOG_PI = math.log(math.pi)
# a(k) of eq. (4) for |k| = 1 and |k| = 2, in log space.
_LOG_A1 = -LOG_2PI  # k_i = 1: Gamma(3/2) / (pi Gamma(1/2)) = 1/(2 pi)
_LOG_A11 = -2.0 * LOG_2PI  # k_i = k_j = 1: 1/(4 pi^2)
_LOG_A2 = math.log(0.75) - 2.0 * _LOG_PI  # k_i = 2: Gamma(5/2)/(pi^2 Gamma(1/2)) = 3/(4 pi^2)


@njit(cache=True, nogil=True, inline="always")
def _solve_u(delta: np.ndarray, mult: np.ndarray) -> float:
    """Root ``u`` of ``sum_i m_i / (2 (delta_i + u)) = 1``, i.e. ``K'(t) = 1``.

    ``delta >= 0`` with at least one zero. Newton from a point left of the root
    in ``u`` (right of it in ``t``) converges monotonically (Proposition 1).
    The start is the best of the lower bounds ``sum_{S} m_i / 2 - max_S delta``
    over the sets ``S`` of the smallest deltas.
    """
    n = delta.shape[0]
    u = 0.5
    for k in range(n):  # S = entries with delta <= delta[k]; n is small, so O(n^2) is fine
        acc = 0.0
        for i in range(n):
            if delta[i] <= delta[k]:
                acc += mult[i]
        cand = 0.5 * acc - delta[k]
        if cand > u:
            u = cand
    for _ in range(100):
        h = -1.0
        dh = 0.0
        for i in range(n):
            r = 1.0 / (delta[i] + u)
            h += 0.5 * mult[i] * r
            dh -= 0.5 * mult[i] * r * r
        step = h / dh
        u -= step
        if -step <= 1e-15 * u:
            break
    return u


@njit(cache=True, nogil=True)
def log_c3(z: np.ndarray, mult: np.ndarray) -> float:
    """Third-order saddlepoint ``log N(Z)`` for entries ``z`` repeated ``mult`` times.

    Kume-Wood's ``C_3 = C_1 exp(T)`` (saddlepoint paper, sec. III-A, with the
    corrections in the module docstring), with the surface measure so that
    ``N(0) = |S^(p-1)|`` up to the approximation error, ``p = sum(mult)``.
    """
    n = z.shape[0]
    zmax = z[0]
    for i in range(1, n):
        if z[i] > zmax:
            zmax = z[i]
    delta = np.empty(n)
    p = 0.0
    for i in range(n):
        delta[i] = zmax - z[i]
        p += mult[i]
    u = _solve_u(delta, mult)
    k2 = 0.0
    k3 = 0.0
    k4 = 0.0
    log_prod = 0.0
    for i in range(n):
        d = delta[i] + u
        r = 1.0 / d
        r2 = r * r
        k2 += 0.5 * mult[i] * r2
        k3 += mult[i] * r2 * r
        k4 += 3.0 * mult[i] * r2 * r2
        log_prod += mult[i] * math.log(d)
    rho3_sq = k3 * k3 / (k2 * k2 * k2)
    rho4 = k4 / (k2 * k2)
    t_corr = rho4 / 8.0 - 5.0 * rho3_sq / 24.0
    return (
        _LOG_SQRT2
        + 0.5 * (p - 1.0) * _LOG_PI
        - 0.5 * math.log(k2)
        - 0.5 * log_prod
        + u
        + zmax
        + t_corr
    )


@njit(cache=True, nogil=True, inline="always")
def _ones(n: int) -> np.ndarray:
    """``np.ones(n)`` as a filled ``np.empty(n)``, the one array constructor the kernels use (each other is one more
    numba overload to compile)."""
    out = np.empty(n)
    for i in range(n):
        out[i] = 1.0
    return out


@njit(cache=True, nogil=True, inline="always")
def _gradient(z: np.ndarray) -> tuple:
    """``log N`` and ``g_i = (dN/dz_i)/N``: each derivative a scaled normalizer of a raised dimension
    (saddlepoint paper, Corollary 2 and eq. 4)."""
    n = z.shape[0]
    mult = _ones(n)
    log_n = log_c3(z, mult)
    grad = np.empty(n)
    for i in range(n):
        mult[i] += 2.0
        grad[i] = math.exp(_LOG_A1 + log_c3(z, mult) - log_n)
        mult[i] -= 2.0
    return log_n, grad


@njit(cache=True, nogil=True, inline="always")
def _hessian(z: np.ndarray, log_n: float) -> np.ndarray:
    """``H_ij = (d2N/dz_i dz_j)/N`` for ``log_n = log N(z)`` (eq. 4, ``|k| = 2``)."""
    n = z.shape[0]
    hess = np.empty((n, n))  # every entry is written
    mult = _ones(n)
    for i in range(n):
        mult[i] += 2.0
        for j in range(i, n):
            if j == i:
                mult[i] += 2.0
                hess[i, i] = math.exp(_LOG_A2 + log_c3(z, mult) - log_n)
                mult[i] -= 2.0
            else:
                mult[j] += 2.0
                v = math.exp(_LOG_A11 + log_c3(z, mult) - log_n)
                mult[j] -= 2.0
                hess[i, j] = v
                hess[j, i] = v
        mult[i] -= 2.0
    return hess


@njit(cache=True, nogil=True)
def derivatives(z: np.ndarray, order: int) -> tuple:
    """``log N``, ``g_i = (dN/dz_i)/N`` and, if ``order == 2``, ``H_ij = (d2N/dz_i dz_j)/N`` (zeros otherwise).

    Each derivative is a scaled normalizer of a raised dimension (saddlepoint
    paper, Corollary 2 and eq. 4). The per-tick kernels call :func:`_gradient`
    and :func:`_hessian` themselves: an ``order`` that is a constant in one
    caller and a variable in another would compile this twice.
    """
    log_n, grad = _gradient(z)
    hess = _hessian(z, log_n) if order == 2 else np.zeros((z.shape[0], z.shape[0]))
    return log_n, grad, hess


@njit(cache=True, nogil=True)
def _log_moment_residual(z: np.ndarray, log_target: np.ndarray, with_jacobian: bool) -> tuple:
    """Residual ``log m(z) - log target`` over ``z_1..z_(n-1)``, the moments ``m(z)`` and, if asked, the Jacobian.

    ``m_i = N_i / sum_k N_k`` are the moments of :func:`derivatives`; the
    Jacobian comes from the second derivatives (eq. 4):
    ``d log m_i / dz_j = (H_ij - g_i g_j) / g_i - sum_k (H_kj - g_k g_j) / G``.
    """
    n = z.shape[0]
    log_n, g = _gradient(z)
    total = 0.0
    for i in range(n):
        total += g[i]
    m = np.empty(n)
    for i in range(n):
        m[i] = g[i] / total
    res = np.empty(n - 1)
    for i in range(n - 1):
        res[i] = math.log(m[i]) - log_target[i]
    jac = np.empty((n - 1, n - 1))
    if with_jacobian:
        h = _hessian(z, log_n)
        for j in range(n - 1):
            col = 0.0
            for k in range(n):
                col += h[k, j] - g[k] * g[j]
            for i in range(n - 1):
                jac[i, j] = (h[i, j] - g[i] * g[j]) / g[i] - col / total
    return res, m, jac


@njit(cache=True, nogil=True, inline="always")
def _sum_squares(v: np.ndarray) -> float:
    s = 0.0
    for x in v:
        s += x * x
    return s


@njit(cache=True, nogil=True, inline="always")
def _gauss_newton_step(jac: np.ndarray, res: np.ndarray) -> np.ndarray:
    """``-(J^T J + mu I)^-1 J^T r`` by Cholesky; ``mu`` is 1e-12 of the trace.

    The paper's pseudo-inverse step, damped just enough to stay defined if
    ``J`` is singular; written out because the system is at most a few
    unknowns and LAPACK's numba bindings cost seconds of compilation.
    """
    k = res.shape[0]
    a = np.empty((k, k))
    b = np.empty(k)
    for i in range(k):
        for j in range(k):
            s = 0.0
            for r in range(k):
                s += jac[r, i] * jac[r, j]
            a[i, j] = s
        s = 0.0
        for r in range(k):
            s -= jac[r, i] * res[r]
        b[i] = s
    trace = 0.0
    for i in range(k):
        trace += a[i, i]
    for i in range(k):
        a[i, i] += 1e-12 * trace + 1e-300
    for j in range(k):  # in-place Cholesky, lower triangle
        s = a[j, j]
        for p in range(j):
            s -= a[j, p] * a[j, p]
        a[j, j] = math.sqrt(max(s, 1e-300))
        for i in range(j + 1, k):
            s = a[i, j]
            for p in range(j):
                s -= a[i, p] * a[j, p]
            a[i, j] = s / a[j, j]
    for i in range(k):  # forward then backward substitution
        s = b[i]
        for p in range(i):
            s -= a[i, p] * b[p]
        b[i] = s / a[i, i]
    for i in range(k - 1, -1, -1):
        s = b[i]
        for p in range(i + 1, k):
            s -= a[p, i] * b[p]
        b[i] = s / a[i, i]
    return b


@njit(cache=True, nogil=True, inline="always")
def fit_log_moments(z0: np.ndarray, log_target: np.ndarray, tol: float, max_iter: int) -> tuple:
    """Gauss-Newton for ``log m(z) = log target`` with ``z_n = 0`` fixed (saddlepoint paper, sec. III-B).

    Derivatives of the raised-dimension approximations are not the exact
    derivatives of the approximated moments, so the iteration converges
    linearly (about 16x per step, measured) whatever the Jacobian's
    freshness; the Jacobian is therefore refreshed only while the residual
    is large (a chord method), which halves the cost. Steps that would
    increase the residual are halved; ``z`` stays <= 0. Returns ``z`` and
    the approximated moments at ``z``.
    """
    n = z0.shape[0]
    z = z0.copy()
    # the Jacobian if a step may follow: a flag computed, not the constant True, so that this call and the
    # loop's share one compiled specialization (a literal argument compiles one of its own)
    res, m, jac = _log_moment_residual(z, log_target, max_iter > 0)
    cost = _sum_squares(res)
    trial = z.copy()
    for _ in range(max_iter):
        if cost < tol:
            break
        step = _gauss_newton_step(jac, res)
        scale = 1.0
        while True:
            for i in range(n - 1):
                trial[i] = min(z[i] + scale * step[i], 0.0)
            fresh = cost > 1e-8
            res_new, m_new, jac_new = _log_moment_residual(trial, log_target, fresh)
            cost_new = _sum_squares(res_new)
            if cost_new <= cost or scale < 1e-4:
                break
            scale *= 0.5
        for i in range(n):  # a loop: ``z[:] = trial`` compiles a shape check whose message formatting costs 2.4 s
            z[i] = trial[i]
        res = res_new
        m = m_new
        cost = cost_new
        if fresh:
            jac = jac_new
    return z, m


@njit(cache=True, nogil=True)
def moments(z: np.ndarray) -> np.ndarray:
    """``E[x_i^2] = (dN/dz_i) / sum_k dN/dz_k`` (:func:`core.normalization.moments`), in one call."""
    grad = _gradient(z.copy())[1]  # a writable copy: log_c3 then compiles once, for the fit's arrays too
    total = 0.0
    for g in grad:
        total += g
    for i in range(grad.shape[0]):  # loops, not array expressions: a tenth of the compile time
        grad[i] /= total
    return grad


@njit(cache=True, nogil=True, inline="always")
def _sort_alongside(keys: np.ndarray, values: np.ndarray) -> None:
    """Sort ``keys`` ascending in place, equal keys in their order, and ``values`` alike (insertion sort: a few entries)."""
    for i in range(1, keys.shape[0]):
        j = i
        while j > 0 and keys[j - 1] > keys[j]:
            keys[j - 1], keys[j] = keys[j], keys[j - 1]
            values[j - 1], values[j] = values[j], values[j - 1]
            j -= 1


@njit(cache=True, nogil=True)
def fit_moments(target: np.ndarray, start: np.ndarray, min_moment: float, tol: float, max_iter: int) -> tuple:
    """``z`` (ascending, last 0) with saddlepoint moments ``target`` and those moments, sorted alike
    (:func:`core.normalization.fit_dispersion_trusted`, saddlepoint method, in one call).

    ``target`` entries below ``min_moment`` are raised to it and the whole
    renormalised; Gauss-Newton (:func:`fit_log_moments`) starts from ``start``,
    or, if ``start`` is empty, from ``z_i = 1/(2 t_n) - 1/(2 t_i)``.
    """
    n = target.shape[0]
    t = np.empty(n)
    total = 0.0
    for i in range(n):
        t[i] = max(target[i], min_moment)
        total += t[i]
    log_t = np.empty(n)
    for i in range(n):
        t[i] /= total
        log_t[i] = math.log(t[i])
    z0 = np.empty(n)
    for i in range(n):
        z0[i] = 0.5 / t[n - 1] - 0.5 / t[i] if start.shape[0] == 0 else start[i]
    z, m = fit_log_moments(z0, log_t, tol, max_iter)
    _sort_alongside(z, m)
    return z, m
