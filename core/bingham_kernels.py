"""Compiled per-tick operations of :class:`core.bingham.Bingham` on its parameters ``(M, Z)``.

Compiled with numba (``cache=True``, no fastmath: every operation is IEEE
arithmetic in a fixed order, so a replay is byte-identical run to run). Each
kernel does what a few numpy calls did, in one call: a filter tick spends its
time in the overhead of many small numpy operations on 4x4 matrices, not in
arithmetic. The numpy forms they replace are kept as the references in
``tests/test_bingham_kernels.py``.

The product of two Binghams is the Bingham of the summed exponents (QBF paper,
sec. 5, eq. 3); its parameters are the eigendecomposition of the 4x4
symmetric ``M diag(Z) M^T + C``, here by the cyclic Jacobi method (Golub & Van
Loan, *Matrix Computations*, 4th ed., sec. 8.5.2-8.5.3, Alg. 8.5.2 and 8.5.3
with Rutishauser's stable rotation formulas): for a 4x4 matrix a few sweeps of
six rotations, no LAPACK call (whose numba bindings cost seconds to compile),
eigenvectors orthonormal to rounding and small eigenvalues accurate relative to
the largest.

Compile cost (a fresh install compiles every kernel once, before its first
tick): each kernel is called with one type signature, a helper used inside
one kernel is inlined into it at numba IR level (``inline="always"``: not
compiled and cached on its own, still callable from Python), and arrays are
made by ``np.empty`` only (each other constructor is one more numba overload
to compile). ``tests/test_warmup.py`` checks the first two;
``benchmarks/RESULTS.md`` ("Compile cost, third pass") has the figures. The
same holds for :mod:`core.saddlepoint`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core import quaternion_kernels as qk

__all__ = ["down_alignment_sq", "mode", "product_parameters", "rms_angle_deg", "rotated_left", "rotated_right", "sorted_concentrations",
           "symmetric_eigh"]

_MAX_SWEEPS = 60


@njit(cache=True, nogil=True, inline="always")
def _sort_columns(keys: np.ndarray, columns: np.ndarray, n: int) -> None:
    """Sort ``keys[:n]`` ascending in place, equal keys in their order (insertion sort: a few entries), and the first
    ``n`` columns of ``columns`` alike."""
    for i in range(1, n):
        j = i
        while j > 0 and keys[j - 1] > keys[j]:
            keys[j - 1], keys[j] = keys[j], keys[j - 1]
            for k in range(columns.shape[0]):
                columns[k, j - 1], columns[k, j] = columns[k, j], columns[k, j - 1]
            j -= 1


@njit(cache=True, nogil=True, inline="always")
def symmetric_eigh(a_in: np.ndarray) -> tuple:
    """Eigenvalues (ascending) and eigenvectors (columns) of a symmetric matrix, by cyclic Jacobi.

    A rotation in the plane ``(p, q)`` zeroes ``a[p, q]`` (``t = tan(phi)`` the
    smaller root of ``t^2 + 2 t theta - 1 = 0``, ``theta = (a_qq - a_pp) /
    (2 a_pq)``); an off-diagonal entry below the rounding of both diagonal
    entries it couples is set to zero after the third sweep, so the iteration
    ends with an exactly diagonal matrix. Equal eigenvalues keep the order the
    sweeps left them in (a stable sort): the result is a function of the input
    bits alone.
    """
    n = a_in.shape[0]
    a = np.empty((n, n))
    v = np.empty((n, n))
    for i in range(n):
        for k in range(n):
            a[i, k] = a_in[i, k]
            v[i, k] = 1.0 if i == k else 0.0
    for sweep in range(_MAX_SWEEPS):
        off = 0.0
        for p in range(n - 1):
            for q in range(p + 1, n):
                off += abs(a[p, q])
        if off == 0.0:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                app = a[p, p]
                aqq = a[q, q]
                g = 100.0 * abs(apq)
                if sweep > 3 and abs(app) + g == abs(app) and abs(aqq) + g == abs(aqq):
                    a[p, q] = 0.0
                    a[q, p] = 0.0
                    continue
                theta = (aqq - app) / (2.0 * apq)
                if abs(theta) > 1e150:
                    t = 0.5 / theta
                else:
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):  # A J
                    akp = a[k, p]
                    akq = a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(n):  # J^T (A J)
                    apk = a[p, k]
                    aqk = a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
                a[p, q] = 0.0
                a[q, p] = 0.0
                for k in range(n):  # V J
                    vkp = v[k, p]
                    vkq = v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    evals = np.empty(n)
    for i in range(n):
        evals[i] = a[i, i]
    _sort_columns(evals, v, n)
    return evals, v


@njit(cache=True, nogil=True)
def product_parameters(M: np.ndarray, Z: np.ndarray, C: np.ndarray) -> tuple:
    """``(Z', M')``, ascending, of the exponent ``M diag(Z) M^T + C`` (``C`` symmetric): the product of
    ``Bingham(M, Z)`` with the likelihood ``exp(x^T C x)`` (QBF paper, sec. 5, eq. 3)."""
    a = np.empty((4, 4))
    for i in range(4):
        for j in range(i, 4):
            s = 0.0
            for k in range(4):
                s += M[i, k] * Z[k] * M[j, k]
            s += 0.5 * (C[i, j] + C[j, i])
            a[i, j] = s
            a[j, i] = s
    return symmetric_eigh(a)


@njit(cache=True, nogil=True)
def rotated_right(u: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``R(u) M``: the principal directions of ``x (x) u`` (QBF paper, sec. 5), ``R(u) p = p (x) u``."""
    out = np.empty((4, 4))
    for j in range(4):
        out[0, j], out[1, j], out[2, j], out[3, j] = qk.multiply((M[0, j], M[1, j], M[2, j], M[3, j]), (u[0], u[1], u[2], u[3]))
    return out


@njit(cache=True, nogil=True)
def rotated_left(u: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``L(u) M``: the principal directions of ``u (x) x`` (QBF paper, sec. 5), ``L(u) p = u (x) p``."""
    out = np.empty((4, 4))
    for j in range(4):
        out[0, j], out[1, j], out[2, j], out[3, j] = qk.multiply((u[0], u[1], u[2], u[3]), (M[0, j], M[1, j], M[2, j], M[3, j]))
    return out


@njit(cache=True, nogil=True)
def sorted_concentrations(M: np.ndarray, z3: np.ndarray) -> tuple:
    """``(M', Z', ok)``: the columns ``M[:, :3]`` sorted by ``z3`` ascending (stable), ``M[:, 3]`` last, ``Z' =
    (sorted z3, 0)``; ``ok`` is False unless every ``z3`` is finite and ``<= 0``."""
    ok = True
    for i in range(3):
        if not (z3[i] <= 0.0 and math.isfinite(z3[i])):
            ok = False
    out = np.empty((4, 4))
    Z = np.empty(4)
    for i in range(4):
        Z[i] = z3[i] if i < 3 else 0.0
        for k in range(4):
            out[k, i] = M[k, i]
    _sort_columns(Z, out, 3)
    return out, Z, ok


@njit(cache=True, nogil=True, inline="always")
def down_alignment_sq(M: np.ndarray) -> np.ndarray:
    """Squared cosine, per principal direction ``m_i`` (``i < 3``), between the body axis ``vec(mode^* m_i)``
    and world down (NED ``z``) seen in the body, ``vec(mode^* k mode)``: left-multiplying by ``mode^*`` is
    orthogonal, so it is ``(m_i . (k mode))^2``, with ``k (x) mode = (-m_z, -m_y, m_x, m_w)`` for the mode ``M[:, 3]``."""
    down = (-M[3, 3], -M[2, 3], M[1, 3], M[0, 3])
    out = np.empty(3)
    for i in range(3):
        cos = down[0] * M[0, i] + down[1] * M[1, i] + down[2] * M[2, i] + down[3] * M[3, i]
        out[i] = cos * cos
    return out


@njit(cache=True, nogil=True)
def mode(M: np.ndarray) -> tuple:
    """The most likely attitude ``M[:, 3]`` as a tuple (w, x, y, z), sign chosen so that ``w >= 0``
    (:attr:`core.bingham.Bingham.mode`)."""
    if M[0, 3] < 0:
        return -M[0, 3], -M[1, 3], -M[2, 3], -M[3, 3]
    return M[0, 3], M[1, 3], M[2, 3], M[3, 3]


@njit(cache=True, nogil=True)
def rms_angle_deg(moments: np.ndarray) -> float:
    """``2 asin(sqrt(E[sin^2(theta/2)]))`` in degrees for ``theta`` the angle to the mode, from a Bingham's moments
    (mode last; :func:`core.filters.rms_angle_deg`)."""
    dispersion = min(max(1.0 - moments[3], 0.0), 1.0)
    return math.degrees(2.0 * math.asin(math.sqrt(dispersion)))
