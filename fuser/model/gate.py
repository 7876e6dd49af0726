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

from fuser.config import UpdateSettings
from fuser.model.diagnostics import Outcome

__all__ = ["GateVerdict", "innovation_gate"]


class GateVerdict(NamedTuple):
    outcome: Outcome
    gated_s: float
    """Seconds of continuous gating after this reading (0 once fused or re-anchored)."""
    test_ratio: float
    """``(innovation / gate)^2`` (PX4's test ratio): above 1 outside the gate."""


def innovation_gate(params: UpdateSettings, gated_s: float, innovation_rad: float, sigma_rad: float,
                    prior_doubt_deg: float, dt_s: float) -> GateVerdict:
    """Verdict on one reading, given how long this update has been gated (``gated_s``) before it."""
    gate = params.innovation_gate_sigma * math.hypot(sigma_rad, math.radians(prior_doubt_deg))
    ratio = (innovation_rad / gate) ** 2
    if innovation_rad <= gate:
        return GateVerdict("fused", 0.0, ratio)
    gated_s += dt_s
    if gated_s >= params.reanchor_after_s:
        return GateVerdict("reanchored", 0.0, ratio)
    return GateVerdict("gated", gated_s, ratio)
