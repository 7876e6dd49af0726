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
from typing import Any, Literal, NamedTuple

import numpy as np
from numba import njit

__all__ = ["DIAGNOSTIC", "Diagnostic", "Outcome", "UpdateDiagnostic", "counter_name", "decoded", "emit", "none", "of"]

Outcome = Literal["fused", "gated", "reanchored"]
"""``fused``: in the state; ``gated``: kept out (see ``reason``); ``reanchored``: outside the gate for
``fuser.updates.reanchor_after_s``, fused anyway so that a wrong state can recover."""


class UpdateDiagnostic(NamedTuple):
    """One update's account of one tick. Angles in degrees; None where the update stopped before computing it.
    (A named tuple: one is made for every update of every tick.)"""

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
    the acceleration check in m/s^2 and the velocity noise it used; the aided ``gravity``: what aided it); added to the record as keys."""

    def to_dict(self) -> dict[str, Any]:
        out = {"update": self.update, "outcome": self.outcome, "reason": self.reason, "innovation_deg": self.innovation_deg,
               "sigma_deg": self.sigma_deg, "test_ratio": self.test_ratio}
        if self.values:
            out.update(self.values)
        return out


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
    key = d[:3]  # (update, outcome, reason)
    if key in _COUNTERS:
        return _COUNTERS[key]
    return None if d.outcome == "fused" else f"{d.update}_{d.outcome}_{d.reason}".rstrip("_")


# -- the compiled tick's form -----------------------------------------------------------------------------------------
# The compiled updates return a :class:`Diagnostic` (codes and radians); the tick writes each into a record of
# :data:`DIAGNOSTIC` (:func:`emit`) and the model turns the records into :class:`UpdateDiagnostic` (:func:`decoded`).

UPDATES = ("gravity", "heading", "attitude", "velocity")
OUTCOMES = ("fused", "gated", "reanchored")
REASONS = ("", "norm", "innovation", "before_tilt", "dip", "no_fix", "stale", "jump", "gap", "unselected", "unconverged")
AIDING = ("", "gnss", "gnss_horizontal", "gnss_raw")
"""The codes: each name's index in its tuple (the update's, the outcome's, the reason's, the aided gravity's ``aiding``)."""

# numpy integers, not Python ints: numba types a global Python int passed as an argument as a literal and compiles
# the callee once per value (``diagnostics.of`` six times); an np.int64 is a plain int64.
GRAVITY, HEADING, ATTITUDE, VELOCITY = map(np.int64, range(4))
FUSED, GATED, REANCHORED = map(np.int64, range(3))
(NO_REASON, NORM, INNOVATION, BEFORE_TILT, DIP, NO_FIX, STALE, JUMP, GAP, UNSELECTED, UNCONVERGED) = map(np.int64, range(11))
NOT_AIDED, AIDED_3D, AIDED_HORIZONTAL, AIDED_RAW = map(np.int64, range(4))


class Diagnostic(NamedTuple):
    """One update's account in the compiled tick: codes (above), radians, NaN where :class:`UpdateDiagnostic` has None."""

    present: bool
    """False: the update made no reading this tick (no diagnostic)."""
    update: int
    outcome: int
    reason: int
    innovation_rad: float
    sigma_rad: float
    test_ratio: float
    aiding: int
    """The gravity update's aiding (``values`` ``(("aiding", ...),)``), :data:`AIDING`'s code; 0: none."""
    accel_check: bool
    """A velocity pair's acceleration check was made: the four values below are its ``values``."""
    accel_innovation_m_s2: float
    accel_gate_m_s2: float
    interval_s: float
    vertical: bool
    velocity_noise_m_s: float
    """The velocity noise per axis the pair was weighed with: the receiver's claim or, if larger, what its fixes show."""


DIAGNOSTIC = np.dtype([("update", "i8"), ("outcome", "i8"), ("reason", "i8"), ("innovation_rad", "f8"), ("sigma_rad", "f8"),
                       ("test_ratio", "f8"), ("aiding", "i8"), ("accel_check", "?"), ("accel_innovation_m_s2", "f8"),
                       ("accel_gate_m_s2", "f8"), ("interval_s", "f8"), ("vertical", "?"),
                       ("velocity_noise_m_s", "f8")], align=True)
"""A :class:`Diagnostic` as a record of the tick's output array."""


@njit(cache=True, nogil=True)
def none() -> Diagnostic:
    """No reading this tick."""
    nan = math.nan
    return Diagnostic(False, 0, 0, 0, nan, nan, nan, 0, False, nan, nan, nan, False, nan)


@njit(cache=True, nogil=True)
def of(update: int, outcome: int, reason: int, innovation_rad: float, sigma_rad: float, test_ratio: float, aiding: int) -> Diagnostic:
    """An update's account without an acceleration check (radians, as the updates compute them; NaN for None)."""
    nan = math.nan
    return Diagnostic(True, update, outcome, reason, innovation_rad, sigma_rad, test_ratio, aiding, False, nan, nan, nan, False, nan)


@njit(cache=True, nogil=True, inline="always")  # inlined: its index starts as a literal 0 at every call site's first call
def emit(out: np.ndarray, n: int, d: Diagnostic) -> int:
    """Write ``d`` (if present) as record ``n`` of ``out``; the next free index."""
    if not d.present:
        return n
    r = out[n]
    r.update, r.outcome, r.reason = d.update, d.outcome, d.reason
    r.innovation_rad, r.sigma_rad, r.test_ratio, r.aiding = d.innovation_rad, d.sigma_rad, d.test_ratio, d.aiding
    r.accel_check, r.accel_innovation_m_s2, r.accel_gate_m_s2 = d.accel_check, d.accel_innovation_m_s2, d.accel_gate_m_s2
    r.interval_s, r.vertical, r.velocity_noise_m_s = d.interval_s, d.vertical, d.velocity_noise_m_s
    return n + 1


def decoded(records: np.ndarray) -> list[UpdateDiagnostic]:
    """The :class:`UpdateDiagnostic` of each record of :data:`DIAGNOSTIC` (NaN read as None; angles to degrees)."""
    out = []
    degrees = math.degrees
    for r in records.tolist():
        update, outcome, reason, innovation, sigma, ratio, aiding, check, accel_innovation, accel_gate, interval, vertical, noise = r
        ratio = None if ratio != ratio else ratio  # NaN: None
        if check:  # a velocity pair's: its acceleration check as values, no angles
            out.append(UpdateDiagnostic(UPDATES[update], OUTCOMES[outcome], REASONS[reason], None, None, ratio, (
                ("accel_innovation_m_s2", accel_innovation), ("accel_gate_m_s2", accel_gate), ("interval_s", interval),
                ("vertical", vertical), ("velocity_noise_m_s", noise))))
            continue
        out.append(UpdateDiagnostic(UPDATES[update], OUTCOMES[outcome], REASONS[reason],  # type: ignore[arg-type]
                                    None if innovation != innovation else degrees(innovation), None if sigma != sigma else degrees(sigma),
                                    ratio, (("aiding", AIDING[aiding]),) if aiding else ()))
    return out
