"""The heading update: the magnetometer as a yaw-only measurement.

The field is turned into the world frame by the current estimate and only
its horizontal direction is compared with the reference's: a likelihood
that informs the rotation about down and nothing else
(:func:`core.observations.heading_exponent`; unscented paper, sec. IV-B,
zero concentrations for the axes a measurement does not inform), so a
magnet near the sensor cannot tilt the estimate. Readings whose norm or dip
(against the measured gravity) depart from the reference are gated first
(as VQF's magnetic disturbance detection does, by norm and dip).

During a fast start with GNSS (the gravity update not converged, its raw
readings checked against the GNSS acceleration, :mod:`fuser.model.gravity`:
after a gyro gap, or when a start in a turn runs again) the field is a whole
vector observation instead (Davenport's K,
:func:`core.observations.vector_exponent`, with the fast start's
``mag.sigma_rad``): the accelerometer's reading alone leaves the rotation
about its own direction free, and in a turn that direction is not down, so a
yaw-only heading, which turns about down through a tilt still wrong, cannot
fix it; two vectors do (Wahba's problem). Not at a cold start before GNSS: the
reference field is then the configured fallback's, whose dip would pull the
tilt (the simulated multirotor's heading 0.78 -> 1.24 deg in its first 2 s).
Started in a 30-deg turn of the JSBSim Cessna, the estimate was 30-45 deg off
in tilt and 100-120 deg in heading for 15 s, reporting 5; with this and the
restart, 1.6 and 4.6 deg after 0.5 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.observations import heading_exponent, vector_exponent
from drivers.samples import Vec3
from fuser.config import BiasSettings, MagSettings, UpdateSettings
from fuser.model import vec3
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.gate import fast_start_sigma_rad, innovation_gate
from fuser.model.state import GravityState, HeadingState
from fuser.model.tick import TickContext

__all__ = ["FieldReference", "HeadingReading", "heading_sigma_rad", "update_heading"]


@dataclass(frozen=True, slots=True)
class FieldReference:
    """Coefficients of the reference field, computed once from ``mag.field_ned_gauss``."""

    norm_gauss: float
    unit_ned: Vec3
    """The field's direction (NED), in plain floats (:mod:`fuser.model.vec3`)."""
    heading_rad: float

    @classmethod
    def of(cls, field_ned_gauss: tuple[float, float, float]) -> FieldReference:
        field = np.asarray(field_ned_gauss, dtype=float)
        norm = float(np.linalg.norm(field))
        return cls(norm, vec3.floats(field / norm), math.atan2(field[1], field[0]))

@dataclass(frozen=True, slots=True)
class HeadingReading:
    state: HeadingState
    exponent: np.ndarray | None
    diagnostic: UpdateDiagnostic


def heading_sigma_rad(params: MagSettings, bias: BiasSettings, updates: UpdateSettings, converged: bool, tick: TickContext,
                      bias_variance_rad2_s2: float, interval_s: float) -> float:
    """Sigma of a heading reading taken ``interval_s`` after the previous one.

    ``sigma_rad`` until converged (a fast start; per ``updates.fast_start_interval_s`` of readings,
    :func:`fuser.model.gate.fast_start_sigma_rad`); then the magnetometer's
    correlated error counted once per correlation time,
    ``error sqrt(correlation_s / T)`` for readings every ``T`` (a fixed sigma
    counts errors that persist for seconds as independent and follows them),
    but never slower than a correction time constant ``tau =
    heading_bias_error / bias sigma`` (``sigma^2 = Q (tau/T)^2`` for the
    process variance ``Q = q T / dt`` over ``T``, as for the tilt), so that a
    poorly known bias is still held.
    """
    if not converged or interval_s <= 0.0:
        return fast_start_sigma_rad(updates, params.sigma_rad, interval_s)
    correlated = math.radians(params.error_deg) * math.sqrt(max(params.correlation_s / interval_s, 1.0))
    tau = math.radians(params.heading_bias_error_deg) / math.sqrt(max(bias_variance_rad2_s2, bias.min_variance_rad2_s2))
    return min(correlated, math.sqrt(tick.process_variance_rad2 * interval_s / tick.dt_s) * tau / interval_s)


def update_heading(params: MagSettings, updates: UpdateSettings, reference: FieldReference, state: HeadingState, gravity: GravityState,
                   tick: TickContext, mag_body_gauss: np.ndarray, current_q: np.ndarray, sigma_rad: float) -> HeadingReading:
    """The heading update of one tick from the tick's mean field in the state's body frame, against the
    current estimate ``current_q`` and the measured down in ``gravity``. ``state`` is the heading's with
    this reading's time already noted. In plain floats (:mod:`fuser.model.vec3`)."""
    if not gravity.tilt_known:
        return HeadingReading(state, None, UpdateDiagnostic.of("heading", "gated", "before_tilt"))
    mag = vec3.floats(mag_body_gauss)
    norm = vec3.norm(mag)
    if abs(norm - reference.norm_gauss) > params.norm_gate_fraction * reference.norm_gauss:
        return HeadingReading(state, None, UpdateDiagnostic.of("heading", "gated", "norm"))
    # the dip: the field's angle to the measured specific force, both in the body frame, against the reference
    # field's to the world direction that was measured as (down, or gravity minus the GNSS acceleration): neither
    # depends on the estimate, so that a wrong estimate cannot lock the magnetometer out
    measured = vec3.angle_rad(vec3.dot(mag, vec3.floats(gravity.measured_body)) / norm)
    expected = vec3.angle_rad(vec3.dot(reference.unit_ned, vec3.floats(gravity.measured_world)))
    if abs(math.degrees(measured - expected)) > params.dip_gate_deg:
        return HeadingReading(state, None, UpdateDiagnostic.of("heading", "gated", "dip"))
    north, east, _ = vec3.rotation_rows(current_q)  # body -> NED: the field's north and east in the world
    error = math.remainder(reference.heading_rad - math.atan2(vec3.dot(east, mag), vec3.dot(north, mag)), 2.0 * math.pi)
    verdict = innovation_gate(updates, state.gated_s, abs(error), max(sigma_rad, params.sigma_rad), tick.prior_doubt_deg, tick.dt_s)
    diagnostic = UpdateDiagnostic.of("heading", verdict.outcome, "innovation" if verdict.outcome == "gated" else "",
                                     abs(error), sigma_rad, verdict.test_ratio)
    state = HeadingState(verdict.gated_s, state.last_reading_ns)
    if verdict.outcome == "gated":
        return HeadingReading(state, None, diagnostic)
    if not gravity.converged and gravity.gnss_checked:  # a fast start with GNSS: the whole field as a vector (module docstring)
        return HeadingReading(state, vector_exponent(mag_body_gauss, reference.unit_ned, sigma_rad), diagnostic)
    return HeadingReading(state, heading_exponent(current_q, error, sigma_rad), diagnostic)
