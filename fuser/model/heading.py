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

The field stays a whole vector for ``settle_s`` after such a fast start has
converged (:func:`fuser.model.fusion.tick`: ``SETTLE_TIME_CONSTANTS`` of
:mod:`fuser.model.bias` times ``accel.lowpass_s``, the time the aided
correction's low-pass takes to settle, 6 s by default). Converged in a
turn, the state knows least the rotation about the aided vector (the
lift's direction, 30 deg off down), not about down: a yaw-only reading then
moves it about that axis, which tilts it, and the heading it measures
through that tilt (``tan(dip)`` per degree) moves along: started at 22, 25,
34 or 40 s into the Cessna's turn the estimate ran 7-12 deg off (largest
15-29) reporting 3.5-5.4 and stayed there for tens of seconds. The whole
field observes the rotation about the aided vector too; once settled, the
yaw-only reading holds the state as in any flight.

Compiled (numba) for the tick (:func:`fuser.model.fusion.tick`): the heading's
memory is the state record's ``heading`` part (:data:`fuser.model.state.HEADING`),
changed in place; the reading is a :class:`fuser.model.tick.HeadingReading`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.observations import _davenport, _heading_exponent
from core.quaternion_kernels import rotation_rows
from fuser.model import diagnostics, vec3
from fuser.model.diagnostics import BEFORE_TILT, DIP, GATED, HEADING, INNOVATION, NO_REASON, NORM, NOT_AIDED
from fuser.model.gate import fast_start_sigma_rad, innovation_gate
from fuser.model.tick import HeadingReading, TickContext

__all__ = ["heading_sigma_rad", "no_reading", "update_heading"]

@njit(cache=True, nogil=True)
def heading_sigma_rad(params_mag: np.record, params_bias: np.record, params_updates: np.record, converged: bool, tick: TickContext,
                      bias_variance_rad2_s2: float, interval_s: float) -> float:
    """Sigma of a heading reading taken ``interval_s`` after the previous one (``params_*``: the ``mag``, ``bias``
    and ``updates`` groups of :mod:`fuser.model.params`).

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
        return fast_start_sigma_rad(params_updates, params_mag.sigma_rad, interval_s)
    correlated = math.radians(params_mag.error_deg) * math.sqrt(max(params_mag.correlation_s / interval_s, 1.0))
    tau = math.radians(params_mag.heading_bias_error_deg) / math.sqrt(max(bias_variance_rad2_s2, params_bias.min_variance_rad2_s2))
    return min(correlated, math.sqrt(tick.process_variance_rad2 * interval_s / tick.dt_s) * tau / interval_s)


@njit(cache=True, nogil=True)
def no_reading() -> HeadingReading:
    """No magnetometer reading this tick: nothing fused, no diagnostic."""
    return HeadingReading(False, np.zeros((4, 4)), diagnostics.none())


@njit(cache=True, nogil=True)
def _gated(reason: int) -> HeadingReading:
    """A reading gated before its innovation was computed (``before_tilt``, ``norm``, ``dip``)."""
    nan = math.nan
    return HeadingReading(False, np.zeros((4, 4)), diagnostics.of(HEADING, GATED, reason, nan, nan, nan, NOT_AIDED))


@njit(cache=True, nogil=True)
def update_heading(params_mag: np.record, params_updates: np.record, field_ned_gauss: np.ndarray, heading: np.record,
                   gravity: np.record, tick: TickContext, mag_body_gauss: tuple, current_q: tuple, sigma_rad: float,
                   settle_s: float) -> HeadingReading:
    """The heading update of one tick from the tick's mean field in the state's body frame, against the
    current estimate ``current_q`` and the measured down in ``gravity`` (the state's ``gravity`` part); the reference
    field ``field_ned_gauss`` (:mod:`fuser.model.field`). ``heading`` is the state's ``heading`` part, this reading's
    time already noted: its ``gated_s`` and ``vector_until_ns`` are changed in place (the field a whole vector for
    ``settle_s`` after a fast start with GNSS, module docstring)."""
    if not gravity.converged and gravity.gnss_checked:  # a fast start with GNSS: the whole field until it has settled
        heading.vector_until_ns = heading.last_reading_ns + round(settle_s * 1e9)
    if not gravity.tilt_known:
        return _gated(BEFORE_TILT)
    # the reference field's coefficients (three floats: computed each reading, cheaper than keeping them)
    field = (field_ned_gauss[0], field_ned_gauss[1], field_ned_gauss[2])
    reference_norm = vec3.norm(field)
    reference_unit = (field[0] / reference_norm, field[1] / reference_norm, field[2] / reference_norm)
    reference_heading = math.atan2(field[1], field[0])
    mag = mag_body_gauss
    norm = vec3.norm(mag)
    if abs(norm - reference_norm) > params_mag.norm_gate_fraction * reference_norm:
        return _gated(NORM)
    # the dip: the field's angle to the measured specific force, both in the body frame, against the reference
    # field's to the world direction that was measured as (down, or gravity minus the GNSS acceleration): neither
    # depends on the estimate, so that a wrong estimate cannot lock the magnetometer out
    measured = vec3.angle_rad(vec3.dot(mag, vec3.load(gravity.measured_body)) / norm)
    expected = vec3.angle_rad(vec3.dot(reference_unit, vec3.load(gravity.measured_world)))
    if abs(math.degrees(measured - expected)) > params_mag.dip_gate_deg:
        return _gated(DIP)
    north, east, _ = rotation_rows(current_q)  # body -> NED: the field's north and east in the world
    error = vec3.wrapped_pi(reference_heading - math.atan2(vec3.dot(east, mag), vec3.dot(north, mag)))
    verdict = innovation_gate(params_updates, heading.gated_s, abs(error), max(sigma_rad, params_mag.sigma_rad), tick.prior_doubt_deg,
                              tick.dt_s)
    diagnostic = diagnostics.of(HEADING, verdict.outcome, INNOVATION if verdict.outcome == GATED else NO_REASON, abs(error), sigma_rad,
                                verdict.test_ratio, NOT_AIDED)
    heading.gated_s = verdict.gated_s
    if verdict.outcome == GATED:
        return HeadingReading(False, np.zeros((4, 4)), diagnostic)
    if heading.last_reading_ns < heading.vector_until_ns:  # the whole field as a vector (module docstring)
        b, r = np.empty(3), np.empty(3)
        b[0], b[1], b[2] = mag
        r[0], r[1], r[2] = reference_unit
        k = _davenport(b, r, sigma_rad)
        if k is None:  # not a direction (a field that is not finite): nothing to fuse
            return HeadingReading(False, np.zeros((4, 4)), diagnostic)
        return HeadingReading(True, np.asarray(k), diagnostic)
    q = np.empty(4)
    q[0], q[1], q[2], q[3] = current_q
    return HeadingReading(True, _heading_exponent(q, error, sigma_rad), diagnostic)
