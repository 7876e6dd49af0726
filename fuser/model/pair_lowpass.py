"""A low-pass of pairs of GNSS fixes: its step and the velocity noise it holds.

Each pair of consecutive fixes of one stream, ``T`` apart, gives a mean acceleration ``(v1 - v0) / T``; a
first-order low-pass of those (``y = (1 - alpha) y + alpha x``) holds the fixes' velocity noise differenced, and
consecutive differences share a fix, so their noise telescopes. Used by the aided gravity reading
(:mod:`fuser.model.velocity`, "Sigma") and by the check of the state (:mod:`fuser.model.velocity_check`). Compiled
(numba) for the tick.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["advance", "max_age_with_latency_ns", "noise_after", "start_alpha"]


@njit(cache=True, nogil=True)
def noise_after(variance: float, covariance: float, alpha: float, span_s: float, noise_m_s: float,
                previous_noise_m_s: float) -> tuple:
    """The velocity noise in a low-pass of differenced fixes after one more: ``y = (1 - a) y + (a / T)(n1 - n0)``,
    ``n0`` shared with the previous difference (:mod:`fuser.model.velocity`, "Sigma"); (variance, covariance with ``n1``)."""
    gain = alpha / span_s
    keep = 1.0 - alpha
    variance = (keep * keep * variance + gain * gain * (noise_m_s * noise_m_s + previous_noise_m_s * previous_noise_m_s)
                - 2.0 * keep * gain * covariance)
    return variance, gain * (noise_m_s * noise_m_s)


@njit(cache=True, nogil=True)
def start_alpha(span_s: float, tau_s: float, held_s: float) -> float:
    """A low-pass step over a pair ``span_s`` long, with ``held_s`` of pairs in it (this one included): the running
    mean of the pairs until they span ``tau_s``, then the first-order low-pass (``span / tau``), as VQF starts its
    low-passes (``filterVec``: the mean of the first ``tau / Ts`` samples). A differenced velocity's noise then
    falls as ``1 / n`` over the first ``n`` pairs (their differences telescope), not as ``(1 - alpha)^n`` after a
    first pair taken whole (:mod:`fuser.model.velocity`, "Sigma")."""
    return min(1.0, max(span_s / tau_s, span_s / held_s))


@njit(cache=True, nogil=True)
def advance(restart: bool, held_s: float, variance: float, covariance: float, span_s: float, tau_s: float, noise_m_s: float,
            previous_noise_m_s: float) -> tuple:
    """One more pair ``span_s`` long into a low-pass of time constant ``tau_s`` that holds ``held_s`` of pairs and the
    velocity noise (``variance``, ``covariance``) so far; ``restart``: it starts again from this pair (its step then 1).
    Returns (the step ``alpha``, ``held_s``, ``variance``, ``covariance`` after it)."""
    if restart:
        held_s, variance, covariance = 0.0, 0.0, 0.0
    held_s += span_s
    alpha = start_alpha(span_s, tau_s, held_s)
    variance, covariance = noise_after(variance, covariance, alpha, span_s, noise_m_s, previous_noise_m_s)
    return alpha, held_s, variance, covariance


@njit(cache=True, nogil=True)
def max_age_with_latency_ns(params: np.record) -> int:
    """How long after it was measured a pair still counts (``params`` the ``gnss`` group): ``max_age_s`` and the longer
    of the fixes' latencies."""
    return round((params.max_age_s + max(params.latency_ms, params.filtered_latency_ms) * 1e-3) * 1e9)
