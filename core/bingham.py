"""The Bingham distribution on the unit-quaternion sphere S^3.

``f(x) = exp(x^T M diag(Z) M^T x) / N(Z)`` for unit quaternions ``x`` in
(w, x, y, z) order, ``M`` orthogonal, ``Z`` ascending with ``Z[-1] = 0``; the
mode is ``+-M[:, -1]`` (saddlepoint paper, sec. II; unscented paper, Def. 1).

:class:`Bingham` is an immutable value, like scipy's ``Rotation``: every
operation returns a new one. Operations that need the normalization
constant take ``method="saddlepoint"`` (fast) or ``"exact"`` (accurate); see
:mod:`core.normalization`.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core import bingham_kernels as kernels
from core import quaternion as quat
from core.normalization import Method, fit_dispersion_trusted, log_normalizer, moments_trusted
from core.sampling import random_samples, unscented_samples

__all__ = ["Bingham", "composition_inertia"]

_ORTHO_TOL = 1e-6
_INERTIA_TOL = 1e-6
_CONJUGATE = np.diag([1.0, -1.0, -1.0, -1.0])
# Body-frame basis: columns i, j, k, 1. ``M = L(q) @ _BODY_BASIS`` puts the
# mode at q and z_1..z_3 on the x, y, z components of ``q^-1 (x) x``.
_BODY_BASIS = np.array([[0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def _hamilton_tensor() -> NDArray[np.float64]:
    """``T[a, j, k]`` with ``(p (x) q)_a = sum_jk T[a, j, k] p_j q_k``."""
    eye = np.eye(4)
    return np.stack([quat.multiply(eye[j], eye[k]) for j in range(4) for k in range(4)]).T.reshape(4, 4, 4)


_HAMILTON = _hamilton_tensor()
# K[a, c, j, l, k, m] = T[a, j, k] T[c, l, m], flattened to (16, 16, 16) for two mat-vecs.
_COMPOSITION = np.einsum("ajk,clm->acjlkm", _HAMILTON, _HAMILTON).reshape(16, 16, 16)


def composition_inertia(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Inertia ``E[s s^T]`` of ``s = q (x) r`` for independent ``q``, ``r`` with inertias ``a``, ``b``.

    QBF paper, A.9.2: ``s_a = sum_jk T_ajk q_j r_k`` is bilinear, so
    ``E[s_a s_c] = sum T_ajk T_clm E[q_j q_l] E[r_k r_m]``. Derived here from
    the Hamilton structure tensor rather than copied from the printed matrix
    (whose H_1 is printed as the identity, where ``s_1 = q_1 r_1 - q_2 r_2 -
    q_3 r_3 - q_4 r_4`` needs ``diag(1, -1, -1, -1)``); every entry is checked
    against Monte Carlo composition in the tests.
    """
    return ((_COMPOSITION @ np.ravel(b)) @ np.ravel(a)).reshape(4, 4)


def _check_inertia(S: ArrayLike) -> NDArray[np.float64]:
    arr = np.asarray(S, dtype=float)
    if arr.shape != (4, 4):
        raise ValueError(f"inertia matrix must be 4x4, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("inertia matrix has NaN or infinite entries")
    if np.max(np.abs(arr - arr.T)) > _INERTIA_TOL:
        raise ValueError("inertia matrix is not symmetric")
    if abs(np.trace(arr) - 1.0) > _INERTIA_TOL:
        raise ValueError(f"inertia matrix of unit quaternions must have trace 1, got {np.trace(arr):.9g}")
    return 0.5 * (arr + arr.T)


class Bingham:
    """Bingham distribution ``Bingham(M, Z)`` on unit quaternions (w, x, y, z)."""

    def __init__(self, M: ArrayLike, Z: ArrayLike) -> None:
        M = np.array(M, dtype=float)
        Z = np.array(Z, dtype=float)
        if M.shape != (4, 4) or Z.shape != (4,):
            raise ValueError(f"M must be 4x4 and Z of length 4, got {M.shape} and {Z.shape}")
        if not (np.all(np.isfinite(M)) and np.all(np.isfinite(Z))):
            raise ValueError("M and Z must be finite")
        if np.any(np.diff(Z) < 0):
            raise ValueError(f"Z must be sorted ascending (mode last), got {Z}")
        if np.max(np.abs(M.T @ M - np.eye(4))) > _ORTHO_TOL:
            raise ValueError("M must be orthogonal")
        self._set(M, Z)

    def _set(self, M: NDArray, Z: NDArray) -> None:
        """Take ``M`` and ``Z`` (new arrays, or another Bingham's read-only ones) as this distribution's, frozen, ``Z``
        shifted to ``Z[-1] = 0`` (eq. (3): Bingham(M, Z) = Bingham(M, Z + cI))."""
        last = float(Z[-1])
        if Z.flags.writeable and last == 0.0 and math.copysign(1.0, last) > 0.0:
            Z.setflags(write=False)  # already shifted (a fit holds z_n at +0, from which the shift would change no bit)
        elif Z.flags.writeable or last != 0.0:  # a read-only Z with Z[-1] = 0 is another Bingham's: shared as is
            Z = Z - Z[-1]
            Z.setflags(write=False)
        M.setflags(write=False)
        self._M = M
        self._Z = Z
        self._cache: dict[tuple[str, str], object] = {}

    @classmethod
    def _trusted(cls, M: NDArray, Z: NDArray, saddlepoint_moments: NDArray | None = None) -> Bingham:
        """Construct without validation, for results of this class's own operations
        (eigenvectors from ``eigh``, products of orthogonal matrices), which hold
        the invariants by construction; the checks cost more than the operations.
        ``saddlepoint_moments``, if known (a fit computes them at its solution), are cached."""
        obj = cls.__new__(cls)
        obj._set(M, Z)
        if saddlepoint_moments is not None:
            obj._cache[("moments", "saddlepoint")] = saddlepoint_moments
        return obj

    # -- constructors ---------------------------------------------------------
    @classmethod
    def uniform(cls) -> Bingham:
        """The uniform distribution on S^3 (Z = 0): no knowledge of the attitude."""
        return cls(_BODY_BASIS, np.zeros(4))

    @classmethod
    def from_mode(cls, mode: ArrayLike, z: ArrayLike) -> Bingham:
        """Bingham with the given mode and concentrations ``z`` (3 entries, <= 0).

        ``z[i]`` concentrates the body-frame components x, y, z of
        ``mode^-1 (x) x``; sorted internally. ``from_mode(IDENTITY, z)`` is
        zero-mean rotation noise.
        """
        q = quat.as_quaternion(mode)
        z3 = np.asarray(z, dtype=float)
        if z3.shape != (3,) or not np.all(np.isfinite(z3)) or np.any(z3 > 0):
            raise ValueError(f"z must be 3 finite entries <= 0, got {z}")
        order = np.argsort(z3, kind="stable")
        M = quat.left_matrix(q) @ _BODY_BASIS
        return cls(np.column_stack([M[:, order], M[:, 3]]), np.append(z3[order], 0.0))

    @classmethod
    def fit(cls, S: ArrayLike, method: Method = "saddlepoint") -> Bingham:
        """Moment-matched Bingham with inertia ``S`` (saddlepoint paper, sec. III-B).

        ``M`` are the eigenvectors of ``S`` and ``Z`` solves eq. (5) by
        Gauss-Newton. Raises ``ValueError`` for a matrix that is not 4x4,
        finite, symmetric, positive semidefinite and of trace 1.
        """
        S = _check_inertia(S)
        if np.linalg.eigvalsh(S)[0] < -_INERTIA_TOL:
            raise ValueError(f"inertia matrix is not positive semidefinite (eigenvalue {np.linalg.eigvalsh(S)[0]:.3g})")
        return cls._fit_trusted(S, method)

    @classmethod
    def _fit_trusted(cls, S: NDArray[np.float64], method: Method) -> Bingham:
        """:meth:`fit` without validation, for inertias this class computes itself (composition)."""
        evals, evecs = np.linalg.eigh(S)
        evals = np.clip(evals, 0.0, None)
        return cls._fit_moments(evecs, evals / evals.sum(), method)

    @classmethod
    def _fit_moments(cls, M: NDArray, target: NDArray, method: Method, start: NDArray | None = None) -> Bingham:
        """The Bingham with principal directions ``M`` and dispersion moments ``target`` (ascending)."""
        Z, fitted = fit_dispersion_trusted(target, method, start)
        return cls._trusted(M, Z, fitted)

    @classmethod
    def from_samples(cls, x: ArrayLike, weights: ArrayLike | None = None, method: Method = "saddlepoint") -> Bingham:
        """Moment-matched Bingham of weighted unit-quaternion samples (rows of ``x``)."""
        x = quat.as_quaternion(x)
        if x.ndim != 2:
            raise ValueError("samples must be an array of shape (n, 4)")
        w = np.full(len(x), 1.0) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != (len(x),) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError("weights must be finite, non-negative, one per sample, and not all zero")
        return cls.fit((x * (w / w.sum())[:, None]).T @ x, method)

    # -- parameters -----------------------------------------------------------
    @property
    def M(self) -> NDArray[np.float64]:
        """Orthogonal 4x4 matrix of principal directions (columns); mode last."""
        return self._M

    @property
    def Z(self) -> NDArray[np.float64]:
        """Concentrations, ascending, last entry 0."""
        return self._Z

    @property
    def mode(self) -> NDArray[np.float64]:
        """Most likely attitude (w, x, y, z), sign chosen so that w >= 0."""
        m = self._M[:, -1]
        return -m if m[0] < 0 else m.copy()

    @cached_property
    def C(self) -> NDArray[np.float64]:
        """Parameter matrix ``M diag(Z) M^T`` of the exponent."""
        return (self._M * self._Z) @ self._M.T

    def __repr__(self) -> str:
        return f"Bingham(mode={np.round(self.mode, 6).tolist()}, Z={np.round(self._Z, 6).tolist()})"

    # -- densities and moments ------------------------------------------------
    def log_normalizer(self, method: Method = "saddlepoint") -> float:
        """``log N(Z)``."""
        return self._cached("log_n", method, lambda: log_normalizer(self._Z, method))

    def moments(self, method: Method = "saddlepoint") -> NDArray[np.float64]:
        """``E[(M^T x)_i^2]``: the eigenvalues of the inertia matrix (eq. 2)."""
        return self._cached("moments", method, lambda: moments_trusted(self._Z, method))

    def _cached(self, name: str, method: Method, compute):
        key = (name, method)
        value = self._cache.get(key)
        if value is None:
            value = self._cache[key] = compute()
        return value

    def log_pdf(self, x: ArrayLike, method: Method = "saddlepoint") -> NDArray[np.float64]:
        """Log density (w.r.t. the surface measure of S^3) at unit quaternions ``x``."""
        x = quat.as_quaternion(x)
        y = x @ self._M
        return (y * y) @ self._Z - self.log_normalizer(method)

    def pdf(self, x: ArrayLike, method: Method = "saddlepoint") -> NDArray[np.float64]:
        """Density at unit quaternions ``x``."""
        return np.exp(self.log_pdf(x, method))

    def inertia(self, method: Method = "saddlepoint") -> NDArray[np.float64]:
        """``E[x x^T] = M diag(omega) M^T`` (saddlepoint paper, eq. 1)."""
        return (self._M * self.moments(method)) @ self._M.T

    def entropy(self, method: Method = "saddlepoint") -> float:
        """Differential entropy ``log N - sum_i z_i omega_i`` (QBF paper, A.7, eq. 10)."""
        return self.log_normalizer(method) - float(self._Z @ self.moments(method))

    def kl_divergence(self, other: Bingham, method: Method = "saddlepoint") -> float:
        """``KL(self || other)`` (QBF paper, A.8, eqs. 11-13).

        The cross entropy of eq. (13) is ``log N_g - tr(C_g E_f[x x^T])``,
        written here in matrix form, which needs no basis change.
        """
        cross = other.log_normalizer(method) - float(np.sum(other.C * self.inertia(method)))
        return cross - self.entropy(method)

    @classmethod
    def from_exponent(cls, C: ArrayLike) -> Bingham:
        """The Bingham ``exp(x^T C x) / N`` of a symmetric 4x4 exponent matrix ``C``."""
        C = np.asarray(C, dtype=float)
        if C.shape != (4, 4) or not np.all(np.isfinite(C)) or np.max(np.abs(C - C.T)) > _INERTIA_TOL * max(1.0, np.abs(C).max()):
            raise ValueError("the exponent must be a finite symmetric 4x4 matrix")
        evals, evecs = np.linalg.eigh(C)
        return cls._trusted(evecs, evals)

    # -- operations -----------------------------------------------------------
    def product(self, other: Bingham) -> Bingham:
        """Normalized product of the two densities (QBF paper, sec. 5, eq. 3): exponents add."""
        return self.times_exponent(other.C)

    def times_exponent(self, C: NDArray[np.float64]) -> Bingham:
        """Normalized product with ``exp(x^T C x)`` for a symmetric ``C`` (a likelihood's exponent): the
        eigendecomposition of ``self.C + C`` (:func:`core.bingham_kernels.product_parameters`)."""
        evals, evecs = kernels.product_parameters(self._M, self._Z, np.ascontiguousarray(C, dtype=np.float64))
        return Bingham._trusted(evecs, evals)

    def with_concentrations(self, z: ArrayLike) -> Bingham:
        """The Bingham with the same mode and principal directions and new ``z_1..z_3`` (each <= 0).

        ``z[i]`` goes with ``M[:, i]``; the result is re-sorted. Used to widen
        or sharpen a distribution along its own axes without an
        eigendecomposition.
        """
        z3 = np.ascontiguousarray(z, dtype=np.float64)
        if z3.shape != (3,):
            raise ValueError(f"z must be 3 finite entries <= 0, got {z}")
        M, Z, ok = kernels.sorted_concentrations(self._M, z3)
        if not ok:
            raise ValueError(f"z must be 3 finite entries <= 0, got {z}")
        return Bingham._trusted(M, Z)

    def rotate_left(self, u: ArrayLike) -> Bingham:
        """Distribution of ``u (x) x`` (QBF paper, sec. 5): ``M -> L(u) M``; ``Z``, and so the moments, kept."""
        return self._rotated(kernels.rotated_left(np.ascontiguousarray(quat.as_quaternion(u)), self._M))

    def rotate_right(self, u: ArrayLike) -> Bingham:
        """Distribution of ``x (x) u`` (QBF paper, sec. 5): ``M -> R(u) M``; ``Z``, and so the moments, kept."""
        return self._rotated(kernels.rotated_right(np.ascontiguousarray(quat.as_quaternion(u)), self._M))

    def _rotated(self, M: NDArray[np.float64]) -> Bingham:
        """This distribution with principal directions ``M``: the same ``Z``, so the same cached normalizer and moments."""
        obj = Bingham._trusted(M, self._Z)
        obj._cache.update(self._cache)
        return obj

    def inverse(self) -> Bingham:
        """Distribution of ``x^-1`` (QBF paper, sec. 5): ``M -> J M``."""
        return Bingham._trusted(_CONJUGATE @ self._M, self._Z)

    def compose(self, other: Bingham, method: Method = "saddlepoint") -> Bingham:
        """Moment-matched distribution of ``self (x) other`` for independent factors (QBF paper, A.9).

        When ``other`` is isotropic rotation noise (mode at the identity, equal
        ``z_1 = z_2 = z_3``; the usual process noise), its inertia is
        ``diag(a, b, b, b)`` and the composed inertia reduces to
        ``a S + b (I - S)``: ``x (x) e_k`` for the four basis quaternions
        ``e_k`` are orthonormal, so ``sum_k R(e_k) S R(e_k)^T = tr(S) I = I``,
        and the cross terms vanish because ``E[w_j w_l] = 0``. The principal
        directions are kept and the moments contract towards uniform,
        ``omega' = (a - b) omega + b``: no eigendecomposition, and the fit starts
        from this distribution's ``Z``. Checked against the general tensor
        form and Monte Carlo in the tests.
        """
        spread = other._isotropic_spread
        if spread is None:
            return Bingham._fit_trusted(composition_inertia(self.inertia(method), other.inertia(method)), method)
        b = float(other.moments(method)[0])
        return Bingham._fit_moments(self._M, (1.0 - 4.0 * b) * self.moments(method) + b, method, self._Z)

    @cached_property
    def _isotropic_spread(self) -> float | None:
        """``z_1`` if this is isotropic rotation noise (mode +-identity, ``z_1 = z_2 = z_3``), else None."""
        if self._Z[0] == self._Z[2] and abs(self._M[0, 3]) == 1.0:
            return float(self._Z[0])
        return None

    # -- sampling -------------------------------------------------------------
    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> NDArray[np.float64]:
        """``n`` exact random draws, shape (n, 4) (ACG rejection; :mod:`core.sampling`)."""
        return random_samples(self._M, self._Z, n, np.random.default_rng(rng))

    def unscented_samples(
        self, lam: float = 0.5, antipodal: bool = True, method: Method = "saddlepoint"
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Deterministic points and weights with this distribution's inertia (unscented paper, sec. III)."""
        return unscented_samples(self._M, self.moments(method), lam, antipodal)
