"""Riemannian spherical sampling (RSS) of a quaternion Bingham distribution.

"Riemannian Spherical Sampling" (RSS paper, ../shared/papers), sec. III
and Alg. 1: ``m`` equally weighted deterministic samples whose inertia
``E[x x^T]`` equals the Bingham's exactly, spread like the density rather
than along the principal axes only. Three stages, all in the eigenbasis
``M`` of the Bingham (mode ``e_4``, tangent plane at the mode spanned by
``e_1..e_3``):

1. Dirac mixture approximation (DMA) of the standard normal on the tangent
   plane by the localized cumulative distribution (sec. II-C, eqs. 4-6), with
   the Gaussian kernel integrated over ``b`` in closed form and ``b_max ->
   inf`` (:func:`_standard_normal_dma`). It depends only on ``m`` and is
   cached, so it costs nothing per filter step.
2. Per-axis scaling and gnomonic retraction ``R_m(t) = (t + m) / sqrt(1 +
   |t|^2)`` (eqs. 8, 12; Alg. 1, lines 7-8).
3. On-manifold moment correction (eq. 13) by Riemannian Gauss-Newton on the
   product of spheres (:func:`_moment_correction`).

Choices that differ from the paper, and why:

* Scaling (eqs. 10-11). The paper approximates the projected density
  ``exp(t^T Z_t t / (1 + |t|^2))`` by the Gaussian ``exp(t^T Z_t t)``, i.e.
  tangent standard deviations ``sqrt(-1 / (2 z_i))``; these are infinite
  for ``z_i = 0`` (uniform directions) and ignore the ``1 + |t|^2`` factor.
  Here the per-axis scales ``s_i`` are chosen so that the retracted points'
  ratios ``E[y_i^2] / E[y_4^2]`` equal the Bingham's ``omega_i / omega_4``
  (two fixed-point sweeps; more change neither the result nor the
  correction's iteration count). For a concentrated Bingham ``omega_i /
  omega_4 -> -1 / (2 z_i)``, so this agrees with the paper where the paper's scale
  is valid, and it is finite for every ``Z``. (Alg. 1, line 7 prints
  ``Z_t^-1`` where the Gaussian's square root ``(-2 Z_t)^(-1/2)`` is meant;
  either way only the standard-normal DMA needs caching.)
* Optimizer. The paper runs Riemannian steepest descent (Manopt) from the
  retracted points, preferring it because small steps keep the points close
  to the DMA. Gauss-Newton with the minimum-norm (Moore-Penrose) step does
  that by construction -- of all tangent displacements that fix the
  linearized moment error it takes the smallest -- and converges
  quadratically: 2-4 iterations to a residual of 1e-16, each a 9x9 solve,
  where steepest descent converges linearly (the paper's Figs. 2-5 stop at
  E ~ 1e-10-1e-13). The problem is tiny (9
  moment equations), so a library (pymanopt, not installed) would add a
  dependency and per-iteration overhead for no gain.
* The samples lie on the mode's hemisphere (``y_4 > 0``). Mirroring them
  (the paper's remedy for the first moment) gives ``2m`` points with the same
  inertia; callers that need a zero mean can stack ``points`` and
  ``-points``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy import optimize
from scipy.stats import norm, qmc

from core.bingham import Bingham
from core.normalization import Method

__all__ = ["rss_samples"]

_DIM = 3  # tangent plane of S^3
_EULER_GAMMA = 0.5772156649015329
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(48)
_UNIT_NODES = 0.5 * (_GL_NODES + 1.0)  # Gauss-Legendre on [0, 1]
_UNIT_WEIGHTS = 0.5 * _GL_WEIGHTS
_SCALE_SWEEPS = 2
_GN_MAX_ITER = 60
_GN_TOL = 1e-15
_EXACT_TOL = 1e-10
# Upper-triangle entries of the 4x4 inertia, without (4, 4): fixed by trace 1.
_ROWS, _COLS = (idx[:-1] for idx in np.triu_indices(4))


def _gram_second_moment_map() -> NDArray[np.float64]:
    """Linear map from the inertia ``P`` (flattened) to ``sum_j J_kj . J_lj / m``.

    With ``J_k = y_c e_a + y_a e_c`` for entry ``k = (a, c)``:
    ``J_k . J_l = y_c y_d [a=b] + y_c y_b [a=d] + y_a y_d [c=b] + y_a y_b [c=d]``
    for ``l = (b, d)``.
    """
    out = np.zeros((9, 9, 4, 4))
    for k, (a, c) in enumerate(zip(_ROWS, _COLS)):
        for l, (b, d) in enumerate(zip(_ROWS, _COLS)):
            for same, i, j in ((a == b, c, d), (a == d, c, b), (c == b, a, d), (c == d, a, b)):
                out[k, l, i, j] += same
    return out.reshape(81, 16)


_GRAM_SECOND = _gram_second_moment_map()


def _gaussian_lcd_term(r2: NDArray) -> tuple[NDArray, NDArray]:
    """Dirac-to-Gaussian part ``g(r^2)`` of the LCD distance and ``dg/d(r^2)``.

    For a Dirac at ``x`` (``|x|^2 = r2``) and ``N(0, I)`` in ``n = 3``
    dimensions, with the Gaussian kernel of width ``b`` and weight
    ``b^(1-n)`` (RSS paper, eqs. 5-6):
    ``int F_gauss F_dirac dr = (2 pi b^4 / (1 + 2 b^2))^(n/2)
    exp(-r2 / (2 (1 + 2 b^2)))``. Divided by ``pi^(n/2)`` the integrand in
    ``b`` is ``h(b) = 2^(n/2) b^(n+1) (1 + 2 b^2)^(-n/2) exp(...)``, which
    grows like ``b - k / b`` with ``k = (n + r2) / 4``. The divergent part is
    dropped (it is the same for every Dirac mixture with zero mean,
    see :func:`_dma_objective`), leaving ``int_0^1 h + int_1^inf (h - b + k /
    b) - 1/2``. Both integrals by 48-point Gauss-Legendre, the tail in ``s =
    1 / b``.
    """
    r2 = r2[:, None]
    b = _UNIT_NODES
    one2b = 1.0 + 2.0 * b * b
    h = 2.0 ** (_DIM / 2) * b ** (_DIM + 1) * one2b ** (-_DIM / 2) * np.exp(-0.5 * r2 / one2b)
    dh = -0.5 * h / one2b
    # Tail in s = 1/b: h = phi(s) / s with log phi = a, so that
    # (h - b + k/b) db = (expm1(a) + k s^2) / s^3 ds, free of cancellation.
    s = _UNIT_NODES
    log_half = np.log1p(0.5 * s * s)
    a = -(_DIM / 2) * log_half - 0.5 * r2 * s * s / (2.0 + s * s)
    tail = (np.expm1(a) + 0.25 * (_DIM + r2) * s * s) / s**3
    dtail = -np.expm1(a - log_half) / (4.0 * s)
    g = (h + tail) @ _UNIT_WEIGHTS - 0.5
    dg = (dh + dtail) @ _UNIT_WEIGHTS
    return g, dg


def _dma_objective(flat: NDArray, m: int) -> tuple[float, NDArray]:
    """Modified Cramer-von Mises distance (RSS paper, eq. 6) to ``N(0, I)``, and its gradient.

    Equal weights ``1/m``; the points are centred first, which makes the
    ``b_max -> inf`` limit finite: the Dirac-Dirac part ``int_0^B b exp(-c /
    b^2) db = (B^2 e^(-c/B^2) - c E1(c/B^2)) / 2`` (``c = |x_i - x_j|^2 / 4``)
    tends to ``B^2/2 + c (ln c + gamma - 1) / 2 - c ln B``, and the ``ln B``
    terms of all parts cancel up to ``|mean|^2 ln B``.
    """
    y = flat.reshape(m, _DIM)
    x = y - y.mean(axis=0)
    diff = x[:, None, :] - x[None, :, :]
    c = 0.25 * np.einsum("ijk,ijk->ij", diff, diff)
    np.fill_diagonal(c, 1.0)  # c ln c = 0 there either way
    log_c = np.log(c)
    np.fill_diagonal(c, 0.0)
    dirac = 0.5 * np.sum(c * (log_c + _EULER_GAMMA - 1.0))
    dp = 0.5 * (log_c + _EULER_GAMMA)
    np.fill_diagonal(dp, 0.0)
    g, dg = _gaussian_lcd_term(np.sum(x * x, axis=1))
    value = dirac / m**2 - 2.0 * g.sum() / m
    grad = (np.sum(dp[:, :, None] * diff, axis=1)) / m**2 - 4.0 * dg[:, None] * x / m
    return float(value), (grad - grad.mean(axis=0)).ravel()


@lru_cache(maxsize=64)
def _standard_normal_dma(m: int) -> NDArray[np.float64]:
    """``m`` equally weighted points approximating ``N(0, I_3)`` (RSS paper, sec. II-C; Alg. 1, line 5).

    Minimizes the LCD distance from an unscrambled Halton start mapped
    through the normal quantile (deterministic), then whitens so that the
    mean is 0 and the covariance is ``I`` exactly. Cached per ``m``; read-only.
    """
    start = norm.ppf(qmc.Halton(d=_DIM, scramble=False).random(m + 1)[1:])
    sol = optimize.minimize(
        _dma_objective, start.ravel(), args=(m,), jac=True, method="L-BFGS-B", options={"maxiter": 2000, "gtol": 1e-9}
    )
    x = sol.x.reshape(m, _DIM)
    x -= x.mean(axis=0)
    evals, evecs = np.linalg.eigh(x.T @ x / m)
    x = x @ (evecs / np.sqrt(evals)) @ evecs.T
    x.setflags(write=False)
    return x


def _retract(t: NDArray) -> NDArray:
    """Gnomonic retraction onto S^3 at the mode ``e_4`` (RSS paper, eqs. 8, 12)."""
    return np.column_stack([t, np.ones(len(t))]) / np.sqrt(1.0 + np.sum(t * t, axis=1))[:, None]


def _scaled_retraction(u: NDArray, omega: NDArray) -> NDArray:
    """Retract ``u diag(s)`` with per-axis scales ``s`` fitted to ``omega_i / omega_4`` (Alg. 1, lines 6-9)."""
    ratio = omega[:3] / omega[3]
    s = np.sqrt(ratio)
    for _ in range(_SCALE_SWEEPS):
        y = _retract(u * s)
        second = np.mean(y * y, axis=0)
        s = s * np.sqrt(ratio * second[3] / np.maximum(second[:3], 1e-300))
    return _retract(u * s)


def _residual(y: NDArray, omega: NDArray) -> NDArray:
    """``diag(omega) - (1/m) sum_j y_j y_j^T`` (the matrix inside eq. 13)."""
    return np.diag(omega) - y.T @ y / len(y)


def _moment_correction(y: NDArray, omega: NDArray) -> NDArray:
    """Solve eq. (13), ``(1/m) sum_j y_j y_j^T = diag(omega)`` on ``(S^3)^m``, by Riemannian Gauss-Newton.

    A tangent displacement ``v_j`` (``v_j . y_j = 0``) changes the inertia
    by ``(1/m) sum_j (v_j y_j^T + y_j v_j^T)``; on the 9 independent entries
    (upper triangle without ``(4, 4)``, fixed by the trace) this is ``J v``.
    The step is the minimum-norm solution ``v = J^T (J J^T)^-1 r``, in closed
    form ``v_j = (S y_j - (y_j^T S y_j) y_j) / m`` with ``S = Lam + Lam^T``
    built from the multipliers, and ``J J^T`` from the sample's second and
    fourth moments (``|y_j| = 1``). Retraction by normalization; the step is
    halved while it does not reduce the residual.
    """
    m = len(y)
    res = _residual(y, omega)
    err = np.linalg.norm(res)
    for _ in range(_GN_MAX_ITER):
        if err <= _GN_TOL:
            break
        feats = y[:, _ROWS] * y[:, _COLS]
        gram = (_GRAM_SECOND @ (np.diag(omega) - res).ravel()).reshape(9, 9) / m - 4.0 * (feats.T @ feats) / m**2
        lam = np.zeros((4, 4))
        lam[_ROWS, _COLS] = np.linalg.solve(gram, res[_ROWS, _COLS])
        sym = lam + lam.T
        sy = y @ sym
        step = (sy - np.sum(sy * y, axis=1, keepdims=True) * y) / m
        for _ in range(30):
            trial = y + step
            trial /= np.linalg.norm(trial, axis=1, keepdims=True)
            trial_res = _residual(trial, omega)
            trial_err = np.linalg.norm(trial_res)
            if trial_err < err:
                break
            step *= 0.5
        else:
            break  # rounding floor reached
        y, res, err = trial, trial_res, trial_err
    return y


def rss_samples(
    bingham: Bingham, m: int, method: Method = "saddlepoint"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``m`` equally weighted deterministic samples of ``bingham`` (RSS paper, Alg. 1).

    Returns ``(points, weights)``: unit quaternions (w, x, y, z) of shape
    ``(m, 4)`` on the mode's hemisphere, and ``weights = 1/m``. Their
    weighted inertia equals ``bingham.inertia(method)`` to rounding (~1e-15);
    raises ``RuntimeError`` if the correction misses it by more than 1e-10.
    Deterministic: the same input gives the same output. Needs ``m >= 5``
    (4 points already fix the inertia's 9 degrees of freedom up to sign
    choices, and the correction needs slack).
    """
    if int(m) != m or m < 5:
        raise ValueError(f"RSS needs an integer m >= 5 samples, got {m}")
    m = int(m)
    omega = np.asarray(bingham.moments(method), dtype=float)
    y = _moment_correction(_scaled_retraction(_standard_normal_dma(m), omega), omega)
    err = np.linalg.norm(_residual(y, omega))
    if not err <= _EXACT_TOL:
        raise RuntimeError(f"RSS moment correction did not converge (residual {err:.3g}) for Z={bingham.Z}, m={m}")
    return y @ bingham.M.T, np.full(m, 1.0 / m)
