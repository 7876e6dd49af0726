"""What each measurement update did in one tick: its innovation, the sigma it used, its test ratio, its outcome.

In the spirit of PX4 EKF2's ``EstimatorAidSource`` messages (observation,
innovation, innovation variance, test ratio, fused / rejected per aid source)
and of filterpy's ``y`` and ``S`` kept after every ``update()``: a reader of a
log can see why a reading was gated, not only that it was.

The test ratio is PX4's: the squared innovation over the squared gate,
``(innovation / (k hypot(sigma, sigma_state)))^2`` with ``k`` the gate in
sigma (``fuser.updates.innovation_gate_sigma``) and ``sigma_state`` the
predicted state's RMS uncertainty; above 1 the reading lies outside the gate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

__all__ = ["Outcome", "UpdateDiagnostic", "counter_name"]

Outcome = Literal["fused", "gated", "reanchored"]
"""``fused``: in the state; ``gated``: kept out (see ``reason``); ``reanchored``: outside the gate for
``fuser.updates.reanchor_after_s``, fused anyway so that a wrong state can recover."""


@dataclass(frozen=True, slots=True)
class UpdateDiagnostic:
    """One update's account of one tick. Angles in degrees; None where the update stopped before computing it."""

    update: str
    """``gravity``, ``heading``, ``attitude``, ``velocity`` (a GNSS fix differenced, :mod:`fuser.model.velocity`)
    or ``mag_field`` (the reference field in use, :mod:`fuser.model.field`)."""
    outcome: Outcome
    reason: str = ""
    """Why it was gated: ``norm`` (specific force or field norm off), ``dip`` (field dip off),
    ``innovation`` (outside the gate), ``before_tilt`` (a heading needs the tilt first); for ``velocity``
    ``no_fix``, ``stale`` (the receiver repeated its last solution), ``jump`` (its acceleration disagrees with
    the accelerometer's), ``gap`` (no earlier fix to difference with), ``unselected`` (another receiver is
    used), ``unconverged`` (the tilt is not known well enough yet to start the aiding); for ``mag_field`` the field's source (``config``, ``wmm``, ``fallback``)."""
    innovation_deg: float | None = None
    """Angle between the measurement and the prediction: down's direction (gravity), yaw (heading),
    the whole rotation (attitude)."""
    sigma_deg: float | None = None
    """Measurement sigma the update used (per tick)."""
    test_ratio: float | None = None
    """Squared innovation over the squared gate (module docstring): > 1 is outside."""
    values: tuple[tuple[str, Any], ...] = ()
    """Further named values of this update, in order (``mag_field``: the field and where it is from; ``velocity``:
    the acceleration check in m/s^2; the aided ``gravity``: what aided it); added to the record as keys."""

    @classmethod
    def of(cls, update: str, outcome: Outcome, reason: str = "", innovation_rad: float | None = None,
           sigma_rad: float | None = None, test_ratio: float | None = None, values: tuple[tuple[str, Any], ...] = ()) -> UpdateDiagnostic:
        """From radians, as the updates compute them."""
        deg = None if innovation_rad is None else math.degrees(innovation_rad)
        return cls(update, outcome, reason, deg, None if sigma_rad is None else math.degrees(sigma_rad), test_ratio, values)

    def to_dict(self) -> dict[str, Any]:
        return {"update": self.update, "outcome": self.outcome, "reason": self.reason, "innovation_deg": self.innovation_deg,
                "sigma_deg": self.sigma_deg, "test_ratio": self.test_ratio, **dict(self.values)}


_COUNTERS = {
    ("gravity", "gated", "norm"): "accel_gated",
    ("gravity", "gated", "innovation"): "accel_gated_innovation",
    ("gravity", "reanchored", ""): "accel_reanchored",
    ("heading", "gated", "before_tilt"): "mag_before_tilt",
    ("heading", "gated", "norm"): "mag_gated_norm",
    ("heading", "gated", "dip"): "mag_gated_dip",
    ("heading", "gated", "innovation"): "mag_gated_innovation",
    ("heading", "reanchored", ""): "mag_reanchored",
    ("velocity", "fused", ""): "gnss_fused",
    ("velocity", "gated", "no_fix"): "gnss_no_fix",
    ("velocity", "gated", "stale"): "gnss_stale",
    ("velocity", "gated", "jump"): "gnss_jump",
    ("velocity", "gated", "gap"): "gnss_gap",
    ("velocity", "gated", "unselected"): "gnss_unselected",
    ("velocity", "gated", "unconverged"): "gnss_unconverged",
}
"""The status counter each outcome is counted in (names kept from before the diagnostics existed)."""


def counter_name(d: UpdateDiagnostic) -> str | None:
    """The counter ``d`` increments, or None (a plain fusion is not counted)."""
    return _COUNTERS.get((d.update, d.outcome, d.reason), None if d.outcome == "fused" else f"{d.update}_{d.outcome}_{d.reason}".rstrip("_"))
