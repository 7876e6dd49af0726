"""Errors of estimates against a reference attitude (truth, or an autopilot's estimate).

Total error is the rotation angle between estimate and reference; tilt error
the angle between their down directions (roll and pitch); heading error the
difference of their yaw about world down. The reference is interpolated
(slerp) at the estimate times; estimates outside the reference's time span
are left out.

Calibration: :func:`credible_level` says in which credible region of each
published Bingham the reference lies (the truth inside the region of mass
``a`` iff the level is at most ``a``), and :func:`tilt_credible_level` the
same for the tilt alone (roll and pitch, whatever the heading).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2

from core import quaternion as quat

__all__ = ["REGIONS", "AttitudeErrors", "attitude_errors", "credible_level", "tilt_credible_level"]

REGIONS = (0.5, 0.9, 0.95)
"""The credible regions whose coverage a score reports: an honest uncertainty holds the truth in each about as often
as its mass (more often is too wide, less often overconfident)."""


@dataclass(frozen=True)
class AttitudeErrors:
    """Per-estimate errors in degrees at times ``t_ns``, with the reported uncertainty."""

    t_ns: NDArray[np.int64]
    total_deg: NDArray[np.float64]
    tilt_deg: NDArray[np.float64]
    heading_deg: NDArray[np.float64]
    uncertainty_deg: NDArray[np.float64]
    q_est: NDArray[np.float64]
    """The estimates compared (w, x, y, z), one row per time."""
    q_ref: NDArray[np.float64]
    """The reference interpolated (slerp) at the same times."""
    level: NDArray[np.float64] | None = None
    """Per estimate, the smallest credible region of its Bingham that holds the reference (:func:`credible_level`);
    None when the estimates' Binghams were not given."""

    def _since(self, since_s: float) -> NDArray[np.bool_]:
        return (self.t_ns - self.t_ns[0]) >= since_s * 1e9

    def rms(self, since_s: float = 0.0) -> dict[str, float]:
        """RMS of each error (degrees) over estimates at least ``since_s`` after the first."""
        keep = self._since(since_s)
        return {
            name: float(np.sqrt(np.mean(values[keep] ** 2)))
            for name, values in (("total", self.total_deg), ("tilt", self.tilt_deg), ("heading", self.heading_deg), ("uncertainty", self.uncertainty_deg))
        }

    def coverage(self, since_s: float = 0.0) -> dict[float, float]:
        """For each of :data:`REGIONS`, the fraction of the estimates at least ``since_s`` after the first whose
        credible region of that mass holds the reference (empty without :attr:`level`)."""
        if self.level is None:
            return {}
        level = self.level[self._since(since_s)]
        return {a: float(np.mean(level <= a)) for a in REGIONS} if level.size else {}


def _yaw(q: NDArray) -> NDArray:
    forward = quat.rotate(q, [1.0, 0.0, 0.0])
    return np.arctan2(forward[..., 1], forward[..., 0])


def _usable_reference(ref_t: NDArray, q_ref: NDArray) -> tuple[NDArray, NDArray]:
    """The reference sorted by time, the first sample of each time, finite non-zero quaternions only."""
    norm = np.linalg.norm(q_ref, axis=-1) if q_ref.size else np.zeros(0)
    ok = np.isfinite(norm) & (norm > 0)
    ref_t, q_ref = ref_t[ok], q_ref[ok]
    order = np.argsort(ref_t, kind="stable")
    ref_t, q_ref = ref_t[order], q_ref[order]
    first = np.concatenate(([True], np.diff(ref_t) > 0)) if ref_t.size else np.zeros(0, dtype=bool)
    return ref_t[first], q_ref[first]


def attitude_errors(
    t_ns: NDArray, q_est: NDArray, uncertainty_deg: NDArray, ref_t_ns: NDArray, q_ref: NDArray,
    bingham: tuple[NDArray, NDArray] | None = None,
) -> AttitudeErrors:
    """Compare estimates (w, x, y, z) with a reference sampled at ``ref_t_ns``; with ``bingham``, the estimates'
    ``(M, Z)`` (n x 4 x 4, n x 4), also the credible level of the reference in each (:attr:`AttitudeErrors.level`).

    The reference is used in time order whatever order it comes in (a log's
    attitude messages are in receive order; a sender's clock can step back),
    with one sample per time (the first) and without unusable quaternions
    (zero or not finite); with fewer than two left, no estimate is scored.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    ref_t, q_ref = _usable_reference(np.asarray(ref_t_ns, dtype=np.int64), np.asarray(q_ref, dtype=float))
    if ref_t.size < 2:
        inside = np.zeros(t_ns.shape, dtype=bool)
        empty, no_q = np.zeros(0), np.zeros((0, 4))
        return AttitudeErrors(t_ns[inside], empty, empty, empty, empty, no_q, no_q, None if bingham is None else empty)
    inside = (t_ns >= ref_t[0]) & (t_ns <= ref_t[-1])
    t_ns = t_ns[inside]
    q_est = np.asarray(q_est, dtype=float)[inside]
    t0 = ref_t[0]
    slerp = Slerp((ref_t - t0) * 1e-9, Rotation.from_quat(q_ref[:, [1, 2, 3, 0]]))
    q_r = slerp((t_ns - t0) * 1e-9).as_quat()[:, [3, 0, 1, 2]]
    down = np.array([0.0, 0.0, 1.0])
    d_est = quat.rotate(quat.conjugate(q_est), down)
    d_ref = quat.rotate(quat.conjugate(q_r), down)
    tilt = np.degrees(np.arctan2(np.linalg.norm(np.cross(d_est, d_ref), axis=-1), np.sum(d_est * d_ref, axis=-1)))
    heading = np.degrees(np.abs(np.remainder(_yaw(q_est) - _yaw(q_r) + np.pi, 2 * np.pi) - np.pi))
    return AttitudeErrors(
        t_ns,
        np.degrees(quat.angular_distance(q_est, q_r)),
        tilt,
        heading,
        np.asarray(uncertainty_deg, dtype=float)[inside],
        q_est,
        q_r,
        None if bingham is None else credible_level(np.asarray(bingham[0], dtype=float)[inside], np.asarray(bingham[1], dtype=float)[inside], q_r),
    )


def credible_level(M: NDArray, Z: NDArray, q_true: NDArray) -> NDArray[np.float64]:
    """Per estimate, the smallest credible region of its Bingham ``(M, Z)`` (stacks: n x 4 x 4, n x 4) that holds
    ``q_true`` (n x 4, w x y z): the truth lies inside the region of mass ``a`` iff the level is <= ``a``.

    A Bingham's credible region of mass ``a`` is the superlevel set ``{x: x^T C x >= t_a}``, so the level is
    ``P(X^T C X > q^T C q)``; for a concentrated Bingham ``-2 X^T C X`` is chi-square with 3 degrees of
    freedom, so the level is ``chi2.cdf(-2 q^T C q, 3)`` (``benchmarks/broad.py`` checks this against Monte
    Carlo draws from the Bingham).
    """
    y = np.einsum("nij,ni->nj", np.asarray(M, dtype=float), np.asarray(q_true, dtype=float))  # the truth along the principal directions
    return chi2.cdf(-2.0 * np.sum(np.asarray(Z, dtype=float) * y * y, axis=1), 3)


_DOWN_PURE = np.array([0.0, 0.0, 0.0, 1.0])


def tilt_credible_level(M: NDArray, Z: NDArray, q_true: NDArray) -> NDArray[np.float64]:
    """Per estimate, the smallest credible region of its *tilt* (the body-frame down direction) that holds the
    true tilt: chi-square with 2 degrees of freedom of the tilt error against the tilt covariance.

    For a concentrated Bingham the body-frame rotation error ``e`` (``x = mode (x) (1, e/2)``) has covariance
    ``sum_i (1 / (2|z_i|)) 4 u_i u_i^T``, ``u_i = vec(mode^* m_i)`` (``E[(m_i . x)^2] = 1/(2|z_i|)``). The tilt
    error is the part of the true error ``e`` across the estimated down ``d`` (a rotation about ``d`` leaves the
    tilt), and its covariance the same projection of that covariance; an unknown heading (``z_i = 0``) costs
    nothing here, its axis being along ``d``.
    """
    M = np.asarray(M, dtype=float)
    Z = np.asarray(Z, dtype=float)
    q_true = np.asarray(q_true, dtype=float)
    mode = M[:, :, 3]
    # the true error in the estimate's body frame: mode^* (x) q_true = (cos, e/2 ...)
    delta = quat.multiply(quat.conjugate(mode), q_true * np.sign(np.sum(mode * q_true, axis=1))[:, None])
    e = 2.0 * delta[:, 1:]
    d = quat.rotate(quat.conjugate(mode), np.array([0.0, 0.0, 1.0]))  # world down in the body
    u = quat.multiply(quat.conjugate(mode)[:, None, :], np.swapaxes(M[:, :, :3], 1, 2))[..., 1:]  # n x 3 axes x 3
    variance = 2.0 / np.maximum(np.abs(Z[:, :3]), 1e-12)  # angle variance along each axis
    project = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # across down
    pu = np.einsum("nij,nkj->nki", project, u)
    cov = np.einsum("nk,nki,nkj->nij", variance, pu, pu)
    cov += 1e-12 * np.eye(3)[None] + np.einsum("ni,nj->nij", d, d)  # regular along down: the projected error has none there
    pe = np.einsum("nij,nj->ni", project, e)
    m2 = np.einsum("ni,ni->n", pe, np.linalg.solve(cov, pe[..., None])[..., 0])
    return chi2.cdf(m2, 2)
