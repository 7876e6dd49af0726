"""The heading update: the magnetometer as a yaw-only measurement.

The field is turned into the world frame by the current estimate and only
its horizontal direction is compared with the reference's: a likelihood
that informs the rotation about down and nothing else
(:func:`core.observations.heading_exponent`; unscented paper, sec. IV-B,
zero concentrations for the axes a measurement does not inform), so a
magnet near the sensor cannot tilt the estimate.

**Magnetic disturbances** (VQF: D. Laidig, T. Seel, Information Fusion 91,
2023, magnetic disturbance rejection; :func:`track_field`). The field's norm
and dip (against the measured gravity, so that a wrong tilt cannot lock the
magnetometer out) are compared with the undisturbed field's. A field that
departs from it is disturbed: the heading is held on the gyro (its
uncertainty grows by the process noise, the bias uncertainty included) until
the field has matched again for a while, for at most ``max_rejection_s``.
The reference follows the measured field slowly while undisturbed (a
calibration offset, a slightly wrong configured field), and a field that
stays steady while the sensor turns is accepted as the new reference (the
sensor was carried to another place, not disturbed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from core import quaternion as quat
from core.observations import heading_exponent
from fuser.config import BiasSettings, MagSettings, UpdateSettings
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.gate import innovation_gate
from fuser.model.state import MagDisturbanceState, GravityState, HeadingState
from fuser.model.tick import TickContext

__all__ = ["FieldReference", "HeadingReading", "heading_sigma_rad", "heading_time_constant_s", "track_field", "update_heading"]


@dataclass(frozen=True, slots=True)
class FieldReference:
    """Coefficients of the reference field, computed once from ``mag.field_ned_gauss``."""

    norm_gauss: float
    dip_rad: float
    heading_rad: float

    @classmethod
    def of(cls, field_ned_gauss: tuple[float, float, float]) -> FieldReference:
        field = np.asarray(field_ned_gauss, dtype=float)
        norm = float(np.linalg.norm(field))
        return cls(norm, math.asin(field[2] / norm), math.atan2(field[1], field[0]))


@dataclass(frozen=True, slots=True)
class HeadingReading:
    state: HeadingState
    exponent: np.ndarray | None
    diagnostic: UpdateDiagnostic


def heading_sigma_rad(params: MagSettings, bias: BiasSettings, converged: bool, tick: TickContext, bias_variance_rad2_s2: float,
                      interval_s: float) -> float:
    """Sigma of a heading reading taken ``interval_s`` after the previous one.

    ``sigma_rad`` until converged (a fast start); then the magnetometer's
    correlated error counted once per correlation time,
    ``error sqrt(correlation_s / T)`` for readings every ``T`` (a fixed sigma
    counts errors that persist for seconds as independent and follows them),
    but never slower than a correction time constant ``tau =
    heading_bias_error / bias sigma`` (``sigma^2 = Q (tau/T)^2`` for the
    process variance ``Q = q T / dt`` over ``T``, as for the tilt), so that a
    poorly known bias is still held.
    """
    if not converged or interval_s <= 0.0:
        return params.sigma_rad
    correlated = math.radians(params.error_deg) * math.sqrt(max(params.correlation_s / interval_s, 1.0))
    tau = math.radians(params.heading_bias_error_deg) / math.sqrt(max(bias_variance_rad2_s2, bias.min_variance_rad2_s2))
    return min(correlated, math.sqrt(tick.process_variance_rad2 * interval_s / tick.dt_s) * tau / interval_s)


def heading_time_constant_s(sigma_rad: float, tick: TickContext, interval_s: float) -> float:
    """Time constant of the heading correction with readings of sigma ``sigma_rad`` every ``interval_s``: the
    steady-state Kalman gain of a random walk of variance ``Q`` per reading under noise ``sigma^2`` is
    ``sqrt(Q) / sigma`` (for a small gain), so ``tau = T sigma / sqrt(Q)`` (the inverse of
    :func:`heading_sigma_rad`'s ``sigma^2 = Q (tau/T)^2``)."""
    q = tick.process_variance_rad2 * interval_s / tick.dt_s
    return interval_s * sigma_rad / math.sqrt(q) if q > 0.0 else math.inf


def _off(params: MagSettings, norm: float, dip: float, ref_norm: float, ref_dip: float) -> str:
    """The gate ``(norm, dip)`` breaks against ``(ref_norm, ref_dip)`` (``"norm"``, ``"dip"``), or "" when they match."""
    if abs(norm - ref_norm) > params.norm_gate_fraction * ref_norm:
        return "norm"
    if abs(math.degrees(dip - ref_dip)) > params.dip_gate_deg:
        return "dip"
    return ""


def track_field(params: MagSettings, reference: FieldReference, state: MagDisturbanceState | None, norm: float, dip: float,
                rate_lp_rad_s: float, interval_s: float) -> MagDisturbanceState:
    """The disturbance detector after one reading (VQF's magnetic disturbance detection and new field acceptance).

    Norm and dip are low-passed over ``current_s``. The field is undisturbed
    once they have matched the reference for ``undisturbed_min_s``; the
    reference then follows them over ``reference_s``. A field that differs
    from the reference but stays steady for ``new_field_s`` of turning
    becomes the reference (the sensor was moved to another field). While
    disturbed, ``rejected_s`` counts the time held on the gyro.
    """
    interval_s = max(interval_s, 0.0)
    if state is None:
        state = MagDisturbanceState(norm, dip, reference.norm_gauss, reference.dip_rad, undisturbed_s=params.undisturbed_min_s,
                           candidate_norm_gauss=norm, candidate_dip_rad=dip)
    a = min(1.0, interval_s / params.current_s)
    norm = state.norm_gauss + a * (norm - state.norm_gauss)
    dip = state.dip_rad + a * (dip - state.dip_rad)
    k = min(1.0, interval_s / params.reference_s)
    ref_norm, ref_dip, disturbed = state.reference_norm_gauss, state.reference_dip_rad, state.disturbed
    undisturbed_s = state.undisturbed_s
    if not _off(params, norm, dip, ref_norm, ref_dip):
        undisturbed_s += interval_s
        if undisturbed_s >= params.undisturbed_min_s:
            disturbed = False
            ref_norm, ref_dip = ref_norm + k * (norm - ref_norm), ref_dip + k * (dip - ref_dip)
    else:
        undisturbed_s, disturbed = 0.0, True
    cand_norm, cand_dip, cand_s = state.candidate_norm_gauss, state.candidate_dip_rad, state.candidate_s
    if not _off(params, norm, dip, cand_norm, cand_dip):
        if rate_lp_rad_s >= params.new_field_min_rate_rad_s:
            cand_s += interval_s
        cand_norm, cand_dip = cand_norm + k * (norm - cand_norm), cand_dip + k * (dip - cand_dip)
        if disturbed and cand_s >= params.new_field_s:
            ref_norm, ref_dip, disturbed, undisturbed_s = cand_norm, cand_dip, False, params.undisturbed_min_s
    else:
        cand_norm, cand_dip, cand_s = norm, dip, 0.0
    if disturbed:
        rejected_s = state.rejected_s + interval_s
    else:
        rejected_s = max(0.0, state.rejected_s - params.rejection_factor * interval_s)
    return MagDisturbanceState(norm, dip, ref_norm, ref_dip, disturbed, undisturbed_s, cand_norm, cand_dip, cand_s, rejected_s)


def update_heading(params: MagSettings, updates: UpdateSettings, reference: FieldReference, state: HeadingState, gravity: GravityState,
                   tick: TickContext, mag_body_gauss: np.ndarray, current_q: np.ndarray, sigma_rad: float, rate_lp_rad_s: float,
                   interval_s: float) -> HeadingReading:
    """The heading update of one tick from the tick's mean field in the state's body frame, against the
    current estimate ``current_q`` and the measured down in ``gravity``, ``interval_s`` after the previous
    reading; ``rate_lp_rad_s`` is the rest detector's low-passed rotation rate. ``state`` is the heading's with
    this reading's time already noted.

    With ``disturbance_rejection`` (:func:`track_field`) a disturbed field is
    kept out (``norm``, ``dip``: the reading is off the reference;
    ``disturbed``: it is back but not yet for ``undisturbed_min_s``) for up to
    ``max_rejection_s``, then fused with a sigma ``rejection_factor`` times
    larger: the heading runs on the gyro meanwhile and its uncertainty grows
    by the process noise. Without it each reading is gated on its own norm
    and dip against the configured reference.
    """
    if not gravity.tilt_known:
        return HeadingReading(state, None, UpdateDiagnostic.of("heading", "gated", "before_tilt"))
    norm = math.sqrt(float(mag_body_gauss @ mag_body_gauss))
    # dip from the angle between the field and the measured gravity, both in the body frame,
    # so that a wrong tilt estimate cannot lock the magnetometer out
    dip = math.asin(max(-1.0, min(1.0, float(mag_body_gauss @ gravity.down_body) / norm)))
    field = state.disturbance
    if params.disturbance_rejection:
        field = track_field(params, reference, field, norm, dip, rate_lp_rad_s, interval_s)
        off = _off(params, field.norm_gauss, field.dip_rad, field.reference_norm_gauss, field.reference_dip_rad)
        if field.disturbed and field.rejected_s <= params.max_rejection_s:
            return HeadingReading(replace(state, disturbance=field), None, UpdateDiagnostic.of("heading", "gated", off or "disturbed"))
        if field.disturbed:
            sigma_rad *= params.rejection_factor
    elif off := _off(params, norm, dip, reference.norm_gauss, reference.dip_rad):
        return HeadingReading(state, None, UpdateDiagnostic.of("heading", "gated", off))
    m_world = quat.rotate(current_q, mag_body_gauss)
    error = math.remainder(reference.heading_rad - math.atan2(m_world[1], m_world[0]), 2.0 * math.pi)
    verdict = innovation_gate(updates, state.gated_s, abs(error), max(sigma_rad, params.sigma_rad), tick.prior_doubt_deg, tick.dt_s)
    diagnostic = UpdateDiagnostic.of("heading", verdict.outcome, "innovation" if verdict.outcome == "gated" else "",
                                     abs(error), sigma_rad, verdict.test_ratio)
    state = HeadingState(verdict.gated_s, state.last_reading_ns, field)
    if verdict.outcome == "gated":
        return HeadingReading(state, None, diagnostic)
    return HeadingReading(state, heading_exponent(current_q, error, sigma_rad), diagnostic)
