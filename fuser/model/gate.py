"""The innovation gate every vector update shares: accept within k sigma, re-anchor after a while.

A reading is fused when its innovation lies within ``k hypot(sigma,
sigma_state)`` of the prediction (sensor and predicted state uncertainty
combined, a chi-style test with one degree of freedom per angle); after
``reanchor_after_s`` of continuous gating it is fused anyway, so that a state
that went wrong (a gyro fault, a bad start) is pulled back instead of
rejecting the truth for ever.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from fuser.model.diagnostics import FUSED, GATED, REANCHORED

__all__ = ["GateVerdict", "fast_start_sigma_rad", "gate_rad", "innovation_gate"]


class GateVerdict(NamedTuple):
    outcome: int
    """:data:`fuser.model.diagnostics.OUTCOMES`' code."""
    gated_s: float
    """Seconds of continuous gating after this reading (0 once fused or re-anchored)."""
    test_ratio: float
    """``(innovation / gate)^2`` (PX4's test ratio): above 1 outside the gate."""


@njit(cache=True, nogil=True)
def innovation_gate(params: np.record, gated_s: float, innovation_rad: float, sigma_rad: float, prior_doubt_deg: float,
                    dt_s: float) -> GateVerdict:
    """Verdict on one reading, given how long this update has been gated (``gated_s``) before it; ``params`` the
    ``updates`` group (:mod:`fuser.model.params`)."""
    gate = gate_rad(params, sigma_rad, prior_doubt_deg)
    ratio = (innovation_rad / gate) * (innovation_rad / gate)
    if innovation_rad <= gate:
        return GateVerdict(FUSED, 0.0, ratio)
    gated_s += dt_s
    if gated_s >= params.reanchor_after_s:
        return GateVerdict(REANCHORED, 0.0, ratio)
    return GateVerdict(GATED, gated_s, ratio)


@njit(cache=True, nogil=True)
def gate_rad(params: np.record, sigma_rad: float, prior_doubt_deg: float) -> float:
    """The gate's half-width: ``k hypot(sigma, sigma_state)`` (``params`` the ``updates`` group)."""
    return params.innovation_gate_sigma * math.hypot(sigma_rad, math.radians(prior_doubt_deg))


@njit(cache=True, nogil=True)
def fast_start_sigma_rad(params: np.record, sigma_rad: float, interval_s: float) -> float:
    """The sigma of a fast-start reading (``accel.sigma_rad``, ``mag.sigma_rad``: per reading
    ``updates.fast_start_interval_s`` apart) taken ``interval_s`` after the previous one: readings closer together
    count for less, ``sigma sqrt(fast_start_interval_s / interval)``, so that the fast start gathers the same
    evidence per second at any loop rate (the per-second information ``1 / (sigma^2 T)`` of readings every ``T``
    then stays that of the nominal spacing, as :func:`fuser.model.heading.heading_sigma_rad` counts the converged
    magnetometer's correlated error); sparser readings count as given. At a 200 Hz loop the fast start had
    converged on three readings in 15 ms and started 1-2 deg off in heading, a transient the bias feedback then
    learnt as a z bias (tests/test_fuser_gnss_flights.py, a faster loop)."""
    if interval_s <= 0.0:
        return sigma_rad
    return sigma_rad * math.sqrt(max(params.fast_start_interval_s / interval_s, 1.0))
