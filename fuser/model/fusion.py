"""One tick of the fusion model, from the tick's samples to the published attitude distribution.

The tick is one compiled function (:func:`tick`, numba): read it top to
bottom. Every value it uses is an argument, a parameter (``params``, the
record of :mod:`fuser.model.params`), the persistent state (``state``, the
record of :mod:`fuser.model.state`, each part changed in place by the
module that owns it) or a local computed above it. :class:`FusionModel` is
the Python around it: it lays the tick's samples out as arrays, keeps the
reference field (:mod:`fuser.model.field`, the World Magnetic Model through
``pygeomag``), and turns the tick's numbers back into a
:class:`~fuser.model.tick.TickResult`.

0. **Check** (:mod:`~fuser.model.imu_check`): the vehicle's IMUs against each
   other; a sample that disagrees is kept out of everything below.
1. **Predict** (:mod:`~fuser.model.propagation`): each IMU's gyro
   integrated, the attitude rotated and composed with the process noise in
   closed form (progressive paper, Alg. 1).
2. **Update**: GNSS velocity differenced into the world acceleration
   (:mod:`~fuser.model.velocity`); gravity (:mod:`~fuser.model.gravity`,
   or its GNSS-aided variant while fixes come), heading
   (:mod:`~fuser.model.heading`) and the autopilot's attitude
   (:mod:`~fuser.model.attitude`), each gated against the prediction. Their
   likelihood exponents add, so the tick's product is one Bingham product
   and one eigendecomposition (QBF paper, sec. 5, eq. 3); only the first tilt
   ever measured is applied at once, for the heading that follows it.
3. **Bias** (:mod:`~fuser.model.rest`, :mod:`~fuser.model.bias`): measured at
   rest, learnt in motion from the tick's tilt and heading corrections (a
   Kalman filter on the bias, VQF's motion bias estimation), each through the
   model of the correction, plain or GNSS-aided, that made it.
4. **Publish**: the posterior carried ahead of the tick to the time it is
   for (:mod:`~fuser.model.extrapolation`), widened by the model error
   (:mod:`fuser.model_error`), by the error of a gyro rate held since the
   last sample and over the lead, while an IMU is kept out, by the tilt an
   unaided accelerometer cannot see (:mod:`~fuser.model.unaided`), and by the
   bias error along the vertical while the heading is held on the gyro
   (:func:`~fuser.model.bias.held_heading_variance_rad2`).

The state is at the tick's end: the gyro carries it over the whole tick, and
every reading is turned into the body frame of that instant.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
from numba import njit

from core import saddlepoint
from core.bingham import Bingham
from core.bingham_kernels import mode, product_parameters, rms_angle_deg, rotated_left, rotated_right
from core.quaternion_kernels import yaw_turn
from drivers.samples import AttitudeSample, GnssSample, ImuSample, MagSample, SourceId
from fuser import model_error
from fuser.config import FuserConfig
from fuser.model import (attitude, bias, body_frame, extrapolation, gravity, heading, imu_check, propagation, rest, unaided, vec3,
                         velocity, velocity_check)
from fuser.model.diagnostics import DIAGNOSTIC, UpdateDiagnostic, counter_name, decoded, emit
from fuser.model.field import heading_change_rad, update_field
from fuser.model.output import OutputPredictor
from fuser.model.params import params_record
from fuser.model.state import MAX_GNSS_STREAMS, MAX_IMUS, FilterState, initial_state
from fuser.model.tick import GNSS_INPUT, IMU_INPUT, TICK_OUTPUT, TickContext, TickInput, TickResult

__all__ = ["EVENTS", "FusionModel", "tick"]

EVENTS = ("imu_disagree", "gyro_gap", "gyro_saturated", "no_gyro", "gyro_held", "gnss_lost", "rest_ticks", "gnss_restart",
          "attitude_unused", "gnss_disputes", "imu_too_many", "gnss_too_many")
"""The tick's event counters, by code (each name's index). The last two are the Python wrapper's: samples of an IMU
beyond :data:`~fuser.model.state.MAX_IMUS` or a GNSS stream beyond :data:`~fuser.model.state.MAX_GNSS_STREAMS` of
the one vehicle, not fused."""
(IMU_DISAGREE, GYRO_GAP, GYRO_SATURATED, NO_GYRO, GYRO_HELD, GNSS_LOST, REST_TICKS, GNSS_RESTART, ATTITUDE_UNUSED, GNSS_DISPUTES,
 IMU_TOO_MANY, GNSS_TOO_MANY) = map(np.int64, range(12))  # numpy integers: a Python int would compile _event once per code (fuser.model.diagnostics)

_RESTART_RAD2 = math.radians(60.0) ** 2
"""Per-axis variance added to the state when the fast start runs again: wide enough for its raw readings and
fast-start headings to take it (unconverged, ``updates.converged_deg``), as at a cold start."""

_NO_MAGS, _NO_ATTITUDES, _NO_GNSS = np.empty((0, 3)), np.empty((0, 4)), np.empty(0, GNSS_INPUT)
"""A tick without such samples (most ticks): the same empty arrays each time."""


@njit(cache=True, nogil=True, inline="always")  # inlined: called with a different literal code and count at each site
def _event(codes: np.ndarray, counts: np.ndarray, n: int, code: int, count: int) -> int:
    """Note ``count`` (> 0) events of ``code`` as pair ``n``; the next free index."""
    if count <= 0:
        return n
    codes[n], counts[n] = code, count
    return n + 1


@njit(cache=True, nogil=True)
def _copy_bingham(M: np.ndarray, Z: np.ndarray, M_out: np.ndarray, Z_out: np.ndarray) -> None:
    """``M``, ``Z`` into ``M_out``, ``Z_out`` (element loops: a slice assignment's shape check costs seconds to compile)."""
    for i in range(4):
        Z_out[i] = Z[i]
        for j in range(4):
            M_out[i, j] = M[i, j]


@njit(cache=True, nogil=True)
def _multiplied(M: np.ndarray, Z: np.ndarray, exponent: np.ndarray) -> tuple:
    """The Bingham ``(M, Z)`` times the likelihoods whose exponents sum to ``exponent`` (QBF paper, sec. 5, eq. 3)."""
    for i in range(4):
        for j in range(4):
            if exponent[i, j] != 0.0:
                evals, evecs = product_parameters(M, Z, exponent)
                last = evals[3]
                for k in range(4):  # Bingham(M, Z) = Bingham(M, Z + cI): the mode's concentration 0 (saddlepoint paper, eq. 3)
                    evals[k] -= last
                return evecs, evals
    return M, Z


@njit(cache=True, nogil=True, inline="always")  # inlined: called with a literal True and a literal False
def _vectors(rows: np.ndarray, accel: bool) -> np.ndarray:
    """The IMU samples' specific forces (``accel``) or fields as an ``(n, 3)`` array."""
    out = np.empty((rows.shape[0], 3))
    for i in range(rows.shape[0]):
        v = rows[i].accel_m_s2 if accel else rows[i].mag_gauss
        out[i, 0], out[i, 1], out[i, 2] = v[0], v[1], v[2]
    return out


@njit(cache=True, nogil=True)
def _mag_in_state_body(imu: np.ndarray, mags: np.ndarray, lags: np.ndarray, has_rate: bool, body_rate: tuple) -> tuple:
    """(present, field): the tick's mean magnetic field, the separate magnetometers' then the IMUs' own (those in
    the state's body frame, :mod:`fuser.model.body_frame`), their mean if there are several."""
    with_mag = np.empty(imu.shape[0], np.int64)
    n = 0
    for i in range(imu.shape[0]):
        if imu[i].has_mag:
            with_mag[n] = i
            n += 1
    count = mags.shape[0] + (1 if n else 0)
    if count == 0:
        return False, vec3.ZERO
    sx = sy = sz = 0.0
    for k in range(mags.shape[0]):
        sx, sy, sz = sx + mags[k, 0], sy + mags[k, 1], sz + mags[k, 2]
    if n:
        chosen = imu[with_mag[:n]]
        m = body_frame.mean_in_state_body(_vectors(chosen, False), lags[with_mag[:n]], has_rate, body_rate)
        if count == 1:
            return True, m
        sx, sy, sz = sx + m[0], sy + m[1], sz + m[2]
    return True, (sx / count, sy / count, sz / count)


@njit(cache=True, nogil=True)
def tick(params: np.ndarray, state: np.ndarray, knots_ns: np.ndarray, knots: np.ndarray, noise_table: np.ndarray,
         field_ned_gauss: np.ndarray, heading_change_rad: float, imu: np.ndarray, mags: np.ndarray, attitudes: np.ndarray,
         gnss: np.ndarray, tick_ns: int, dt_ns: int, carry_ns: int, out: np.ndarray, diagnostics: np.ndarray,
         event_codes: np.ndarray, event_counts: np.ndarray) -> tuple:
    """Fuse one tick's samples into ``state`` (module docstring); the published distribution and what it is carried
    by into ``out[0]`` (:data:`~fuser.model.tick.TICK_OUTPUT`), each update's diagnostic into ``diagnostics``
    (:data:`~fuser.model.diagnostics.DIAGNOSTIC`), the events into ``event_codes`` / ``event_counts``
    (:data:`EVENTS`); returns (diagnostics written, event pairs written, the published uncertainty in degrees).

    ``imu`` and ``gnss`` are the tick's samples (:data:`~fuser.model.tick.IMU_INPUT`,
    :data:`~fuser.model.tick.GNSS_INPUT`), ``mags`` the separate magnetometers' fields ``(n, 3)``, ``attitudes`` the
    autopilot's quaternions ``(n, 4)``; ``field_ned_gauss`` the reference field and ``heading_change_rad`` how far its
    north turned this tick (:mod:`fuser.model.field`); ``noise_table`` the process noise's coefficients
    (:func:`fuser.model.propagation.noise_table`); ``carry_ns`` how far the published state is carried.
    """
    p, s, o = params[0], state[0], out[0]
    dt = dt_ns * 1e-9
    n_diag = n_events = 0
    tilt_was_converged = s.gravity.converged  # before this tick: whether the plain correction below counts as absorbed

    # 0. the vehicle's IMUs checked against each other: one that disagrees is kept out
    kept, disagreeing = imu_check.check_imus(p.imu_check, s.imu_check, imu)
    if disagreeing:
        imu = imu[kept]
        n_events = _event(event_codes, event_counts, n_events, IMU_DISAGREE, disagreeing)
    check = s.imu_check
    imu_fault = check.has_last_fault_ns and tick_ns - check.last_fault_ns <= max(p.imu_check.compare_within_s * 1e9, dt_ns)
    has_imu = imu.shape[0] > 0

    # 1. predict: the gyro over the whole tick, then the closed-form prediction
    bias.propagate(p.bias, s.bias, dt)
    motion = propagation.integrate_gyro(p.gyro, s.gyro, imu, tick_ns - dt_ns, tick_ns)
    n_events = _event(event_codes, event_counts, n_events, GYRO_GAP, motion.gaps)
    n_events = _event(event_codes, event_counts, n_events, GYRO_SATURATED, motion.saturated_samples)
    if not has_imu:
        n_events = _event(event_codes, event_counts, n_events, NO_GYRO, 1)
    if motion.held:
        n_events = _event(event_codes, event_counts, n_events, GYRO_HELD, 1)
    prediction = propagation.predict(p.gyro, p.bias, s.attitude, s.bias, motion, dt, noise_table)
    predicted_M, predicted_Z, predicted_moments = prediction.M, prediction.Z, prediction.moments
    if heading_change_rad != 0.0:  # the reference field's north turned: the heading re-expressed against it (fuser.model.field)
        turn = yaw_turn(heading_change_rad)
        predicted_M = rotated_left(np.array(turn), predicted_M)
    if prediction.has_rate:
        rate = prediction.rate_rad_s
        model_error.observe_rate(s.model_error, rate, dt, p.accel.lowpass_s)
    else:
        rate = s.gyro.rate_rad_s
    unknown_rotation_s = motion.gap_s + motion.saturated_s  # of the tick without a usable rate: the strapdown frame breaks
    frame_broken = unknown_rotation_s > 0.0
    gravity.turn_frame(s.gravity, prediction.has_rotation, prediction.rotation, unknown_rotation_s)
    context = TickContext(dt, prediction.variance_rad2, rms_angle_deg(predicted_moments),
                          velocity.tilt_doubt_deg(predicted_M, predicted_moments))
    predicted_q = mode(predicted_M)
    has_rate = motion.known_s > 0.0
    raw_rate = vec3.scaled(motion.raw_rotation_rad, 1.0 / motion.known_s) if has_rate else vec3.ZERO
    body_rate = vec3.sub(raw_rate, vec3.load(s.bias.estimate_rad_s))

    # 2. updates, gated against the prediction; their exponents add up to one product
    M, Z = predicted_M, predicted_Z
    exponent = np.zeros((4, 4))
    interval = dt if not s.gyro.has_last_imu_tick_ns or not has_imu else (tick_ns - s.gyro.last_imu_tick_ns) * 1e-9
    lags = np.empty(imu.shape[0])
    for i in range(imu.shape[0]):
        lags[i] = (tick_ns - imu[i].placed_ns) * 1e-9
    accel = body_frame.mean_in_state_body(_vectors(imu, True), lags, has_rate, body_rate) if has_imu else vec3.ZERO
    tau = gravity.tilt_time_constant_s(p.accel, p.bias, bias.variance_rad2_s2(s.bias))
    track, n_diag = velocity.track_velocity(p.gnss, p.accel, p.updates, s.velocity, knots_ns, knots, gnss, s.gravity, has_imu, accel,
                                            tick_ns, dt_ns, predicted_q, context.prior_doubt_deg, context.prior_tilt_doubt_deg, tau,
                                            frame_broken, diagnostics, n_diag)
    if track.lost:
        n_events = _event(event_codes, event_counts, n_events, GNSS_LOST, 1)
    reading = gravity.no_reading()
    if has_imu:
        if p.rest.enabled and has_rate:  # a vehicle GNSS sees moving is not at rest
            if track.moving:
                rest.reset(s.rest)
            else:
                rest.detect_rest(p.rest, s.rest, raw_rate, accel, interval)
            if s.rest.at_rest:
                n_events = _event(event_codes, event_counts, n_events, REST_TICKS, 1)
                rest.measure_bias(p.rest, s.rest, s.bias, interval)
        if track.active:
            reading = velocity.update_gravity_aided(p.accel, p.updates, s.gravity, s.velocity, track, context, tau, predicted_q)
        else:
            has_world, world, world_noise = velocity.raw_world(p.gnss, p.accel, s.velocity, tick_ns)
            reading = gravity.update_gravity(p.accel, p.updates, s.gravity, context, accel, tau, predicted_q, interval, p.mag.enabled,
                                             has_world, world, world_noise)
            if reading.restart:  # the fast start again: the state forgets the tilt and heading it was sure of
                M, Z = model_error.with_model_error(M, Z, _RESTART_RAD2, _RESTART_RAD2)
                n_events = _event(event_codes, event_counts, n_events, GNSS_RESTART, 1)
        # an acceleration the unaided accelerometer cannot tell from gravity, as far as the estimate follows it
        unaided.learn_norm(p.accel, s.unaided, s.gravity, accel, interval, frame_broken)
        if not track.active:
            target, follow_s = unaided.unaided_target(p.accel, s.gravity, interval, tau)
            unaided.followed(p.accel, s.unaided, target, interval, follow_s)
        elif reading.has_tilt_bound and reading.diagnostic.present and not math.isnan(reading.diagnostic.sigma_rad):
            unaided.corrected(p.accel, s.unaided, context.prior_tilt_doubt_deg, reading.diagnostic.sigma_rad, reading.tilt_bound_rad)
        n_diag = emit(diagnostics, n_diag, reading.diagnostic)
        if reading.fused:
            exponent += reading.exponent
        if reading.apply_now:
            M, Z = _multiplied(M, Z, exponent)
            exponent = np.zeros((4, 4))
    heading_reading = heading.no_reading()
    since = dt
    has_mag = False
    if p.mag.enabled:
        mag_body_rate = vec3.sub(raw_rate, vec3.load(s.bias.estimate_rad_s))  # after a bias measured at rest above
        has_mag, mag = _mag_in_state_body(imu, mags, lags, has_rate, mag_body_rate)
        if has_mag:
            h = s.heading
            since = dt if not h.has_last_reading_ns else (tick_ns - h.last_reading_ns) * 1e-9
            h.has_last_reading_ns, h.last_reading_ns = True, tick_ns
            sigma = heading.heading_sigma_rad(p.mag, p.bias, p.updates, s.gravity.converged, context, bias.variance_rad2_s2(s.bias), since)
            heading_reading = heading.update_heading(p.mag, p.updates, field_ned_gauss, h, s.gravity, context, mag, mode(M), sigma,
                                                      bias.SETTLE_TIME_CONSTANTS * p.accel.lowpass_s)
            n_diag = emit(diagnostics, n_diag, heading_reading.diagnostic)
            if heading_reading.fused:
                exponent += heading_reading.exponent
                h.has_last_fused_ns, h.last_fused_ns = True, tick_ns
    attitude_fused = attitude.attitude_in_use(p.attitude, s.gyro, tick_ns)
    if attitudes.shape[0] and attitude_fused:
        source = s.attitude_source
        n_diag, fused = attitude.update_attitude(p.attitude, p.updates, source, attitudes, mode(M), s.gravity.tilt_known,
                                                 vec3.load(s.gravity.down_body), context, exponent, diagnostics, n_diag)
        if fused:
            source.has_last_fused_ns, source.last_fused_ns = True, tick_ns
    elif attitudes.shape[0]:
        n_events = _event(event_codes, event_counts, n_events, ATTITUDE_UNUSED, attitudes.shape[0])
    M, Z = _multiplied(M, Z, exponent)
    posterior_q = mode(M)
    # the tilt the plain update's corrections took from the accelerometer, which a false vertical would have put there
    plain = (has_imu and reading.fused and not track.active and not reading.restart and tilt_was_converged
             and not (attitudes.shape[0] > 0 and attitude_fused))
    unaided.absorbed(p.accel, s.unaided, dt, tau, plain, predicted_q, posterior_q)
    source = s.attitude_source
    # the autopilot's down, fused within the tilt time constant: what the accelerometer could not see, or disputes, is
    # its estimator's
    autopilot_down = source.has_last_fused_ns and tick_ns - source.last_fused_ns <= p.accel.lowpass_s * 1e9
    if autopilot_down:
        unaided.cleared(p.accel, s.unaided)

    # 3. bias learnt in motion from the tick's corrections, each through its own model (VQF's motion bias estimation)
    if has_imu:
        bias.learn_from_tick(p, s.bias, predicted_q, posterior_q, context, tau, interval, track, has_imu, reading, has_mag,
                             heading_reading, since, s.unaided, attitude_fused, s.rest.at_rest, rate,
                             frame_broken or not s.gravity.converged)

    # 4. publish: carried ahead of the tick by the held rate, widened by the model error, the error of a rate held since
    # the last sample and over the lead, an IMU kept out, without GNSS aiding the acceleration the norm reveals, a
    # disputed gravity reading or the GNSS fixes' residuals, and the bias error along the vertical while the heading
    # is held on the gyro
    ahead = extrapolation.lead(p.gyro, s.gyro, vec3.load(s.bias.estimate_rad_s), tick_ns, carry_ns)
    widening = motion.hold_variance_rad2 + ahead.variance_rad2
    if imu_fault:
        widening += math.radians(p.imu_check.fault_sigma_deg) ** 2
    field = (field_ned_gauss[0], field_ned_gauss[1], field_ned_gauss[2])
    unseen_tilt, unseen_heading = unaided.unseen_variances_rad2(p.accel, s.unaided, p.mag.enabled, field)
    disputed_rad2 = 0.0 if autopilot_down else s.gravity.disputed_rad * s.gravity.disputed_rad
    # the GNSS fixes' residuals against the state, beyond what their noise makes: the state at least that far off
    excess_rad2 = 0.0 if autopilot_down else velocity_check.attitude_excess_rad2(p.gnss, p.updates, s.velocity, tick_ns)
    if excess_rad2 > max(disputed_rad2, unseen_tilt):
        disputed_rad2 = excess_rad2
        n_events = _event(event_codes, event_counts, n_events, GNSS_DISPUTES, 1)
    if disputed_rad2 > unseen_tilt:  # a gravity reading that disputes the state may be right: the state that far off
        unseen_tilt, unseen_heading = disputed_rad2, unaided.heading_through_dip_rad2(disputed_rad2, p.mag.enabled, field)
    held_s = _heading_held_s(s.heading, s.attitude_source, tick_ns)
    if p.mag.enabled and held_s > 0.0:  # the heading held on the gyro since a magnetometer or the autopilot last corrected it
        unseen_heading += bias.held_heading_variance_rad2(p.bias, s.bias, posterior_q, held_s)
    carried_M = rotated_right(np.array(ahead.rotation), M) if ahead.has_rotation else M
    published_M, published_Z = model_error.published(p.model_error, carried_M, Z, s.model_error.rate_sq, p.mag.enabled, widening,
                                                     unseen_tilt, unseen_heading)

    # the state at the tick's end; what was published
    _copy_bingham(M, Z, s.attitude.M, s.attitude.Z)
    s.gyro.rate_rad_s = rate
    if has_imu:
        s.gyro.has_last_imu_tick_ns, s.gyro.last_imu_tick_ns = True, tick_ns
    _copy_bingham(published_M, published_Z, o.published_M, o.published_Z)
    uncertainty_deg = rms_angle_deg(saddlepoint.moments(published_Z))
    o.has_lead_rotation = ahead.has_rotation
    for i in range(4):
        o.lead_rotation[i] = ahead.rotation[i]
    o.imu_fault = imu_fault
    o.counted_until_ns = tick_ns + carry_ns
    return n_diag, n_events, uncertainty_deg


@njit(cache=True, nogil=True)
def _heading_held_s(heading_state: np.record, attitude_source: np.record, tick_ns: int) -> float:
    """Seconds since the heading was last corrected: a magnetometer reading or the autopilot's attitude fused
    (0 if it never was: then the filter's own heading is not known either)."""
    corrected, last = heading_state.has_last_fused_ns, heading_state.last_fused_ns
    if attitude_source.has_last_fused_ns and (not corrected or attitude_source.last_fused_ns > last):
        corrected, last = True, attitude_source.last_fused_ns
    return (tick_ns - last) * 1e-9 if corrected else 0.0


class FusionModel:
    """Bingham attitude fusion of up to :data:`MAX_IMUS` IMUs (and :data:`MAX_GNSS_STREAMS` GNSS streams; samples of
    further ones are counted, not fused), magnetometers and attitude sources.

    ``config`` holds the parameters; :attr:`state` the persistent state (read,
    set, :meth:`reset`), the reference field in use included. :meth:`step` runs one tick.
    """

    def __init__(self, config: FuserConfig) -> None:
        self.config = config
        self.counters: Counter[str] = Counter()
        """Events so far: readings gated by reason, gyro gaps, rest ticks, ..."""
        self._params = params_record(config)
        self._noise_table = propagation.noise_table()
        self._ahead_ns, self._carry_ns = extrapolation.ahead_ns(config), extrapolation.carry_ns(config)
        self._state = initial_state(config)
        self._field_ned_gauss = np.array(self._state.field.field_ned_gauss)
        self._out = np.zeros(1, TICK_OUTPUT)
        self._published_M, self._published_Z = (self._out[name][0] for name in ("published_M", "published_Z"))
        """Views of the tick's output (its arrays, read after every tick without a record look-up)."""
        self._diagnostics = np.zeros(16, DIAGNOSTIC)
        self._event_codes, self._event_counts = np.zeros(len(EVENTS), np.int64), np.zeros(len(EVENTS), np.int64)

    @property
    def state(self) -> FilterState:
        """The persistent state after the last tick (a copy: it stays as it is after further ticks)."""
        return self._state.copy()

    @state.setter
    def state(self, state: FilterState) -> None:
        if not isinstance(state, FilterState):
            raise TypeError(f"state must be a FilterState, got {type(state).__name__}")
        if state.knots.shape != self._state.knots.shape:
            raise ValueError(f"state is of a model with another loop rate or GNSS horizon: {state.knots.shape[0]} knots, "
                             f"this model keeps {self._state.knots.shape[0]}")
        self._state = state.copy()
        self._field_ned_gauss = np.array(state.field.field_ned_gauss)

    def reset(self) -> None:
        """Back to the start: uniform attitude, bias unknown."""
        self._state = initial_state(self.config)
        self._field_ned_gauss = np.array(self._state.field.field_ned_gauss)

    def output_predictor(self) -> OutputPredictor:
        """An output predictor (:mod:`fuser.model.output`) for this model's ticks, started by :meth:`start_output`."""
        return OutputPredictor(self._params, round(self.config.extrapolation.imu_delay_ms * 1e6))

    def start_output(self, predictor: OutputPredictor) -> None:
        """Start ``predictor`` from the last tick: its published distribution, lead, and the gyro and bias after it."""
        predictor.start(self._out, self._state.record)

    def _imu_slot(self, source: SourceId) -> int:
        """The IMU's slot in the state's IMU check (a new IMU the next free one; -1 beyond :data:`MAX_IMUS`)."""
        slots = self._state.imu_slots
        try:
            return slots.index(source)
        except ValueError:
            pass
        if len(slots) == MAX_IMUS:
            return -1
        self._state.imu_slots = (*slots, source)
        return len(slots)

    def _gnss_slot(self, key: tuple[SourceId, bool]) -> int:
        """The GNSS stream's slot in the state's velocity aiding (-1 beyond :data:`MAX_GNSS_STREAMS`); a new stream
        ranks the slots again by (filtered, source), the order in which one of several fresh streams is chosen
        (:mod:`fuser.model.velocity`)."""
        slots = self._state.gnss_slots
        if key in slots:
            return slots.index(key)
        if len(slots) == MAX_GNSS_STREAMS:
            return -1
        slots = self._state.gnss_slots = (*slots, key)
        ranks = sorted(range(len(slots)), key=lambda i: (slots[i][1], slots[i][0]))
        for rank, i in enumerate(ranks):
            self._state.record[0]["velocity"]["stream_rank"][i] = rank
        return len(slots) - 1

    def _inputs(self, tick_input: TickInput) -> tuple[list, list, list, list, list[GnssSample], list[tuple[str, int]]]:
        """The tick's samples as the compiled tick's rows (IMU, magnetometer, attitude, GNSS), the GNSS fixes, and the
        samples of an IMU or GNSS stream beyond the state's slots (counted, not fused)."""
        placed = tick_input.placed_ns
        if placed is None:
            placed = [x.t_ns for x in tick_input.samples]
        imu_rows: list = []
        mag_rows: list = []
        attitude_rows: list = []
        gnss_rows: list = []
        fixes: list[GnssSample] = []
        dropped: list[tuple[str, int]] = []
        for x, t in zip(tick_input.samples, placed):
            kind = type(x)
            if kind is ImuSample:
                slot = self._imu_slot(x.source)
                if slot < 0:
                    dropped.append((EVENTS[IMU_TOO_MANY], 1))
                    continue
                mag = x.mag_gauss
                imu_rows.append((t, x.gyro_rad_s, x.accel_m_s2, mag is not None, vec3.ZERO if mag is None else mag, slot))
            elif kind is MagSample:
                mag_rows.append(x.mag_gauss)
            elif kind is AttitudeSample:
                attitude_rows.append(x.q_wxyz)
            elif kind is GnssSample:
                fixes.append(x)
                slot = self._gnss_slot((x.source, x.filtered))
                if slot < 0:
                    dropped.append((EVENTS[GNSS_TOO_MANY], 1))
                    continue
                accuracy = x.speed_accuracy_m_s
                gnss_rows.append((t, x.fix_type, x.vel_ned_m_s is not None, x.vel_ned_m_s or vec3.ZERO, x.vertical_velocity,
                                  accuracy is not None, math.nan if accuracy is None else accuracy, x.filtered, slot))
        return imu_rows, mag_rows, attitude_rows, gnss_rows, fixes, dropped

    def step(self, tick_input: TickInput) -> TickResult:
        """Fuse the samples of one tick (:class:`~fuser.model.tick.TickInput`)."""
        cfg, s = self.config, self._state
        imu_rows, mag_rows, attitude_rows, gnss_rows, fixes, dropped = self._inputs(tick_input)
        # the reference field: the WMM's at the first GNSS position (if not configured); the heading turned with its north
        change = 0.0
        field_diagnostic = None
        if fixes or not s.field.reported:
            field, field_diagnostic = update_field(cfg.mag, s.field, fixes, tick_input.t_ns)
            if field.field_ned_gauss != s.field.field_ned_gauss:
                change = heading_change_rad(s.field, field) if cfg.mag.enabled else 0.0
                self._field_ned_gauss = np.array(field.field_ned_gauss)
            s.field = field
        capacity = len(gnss_rows) + len(attitude_rows) + 4
        if capacity > self._diagnostics.shape[0]:
            self._diagnostics = np.zeros(2 * capacity, DIAGNOSTIC)
        n_diagnostics, n_events, uncertainty_deg = tick(self._params, s.record, s.knots_ns, s.knots, self._noise_table, self._field_ned_gauss, change,
             np.array(imu_rows, IMU_INPUT), np.array(mag_rows, float).reshape(-1, 3) if mag_rows else _NO_MAGS,
             np.array(attitude_rows, float).reshape(-1, 4) if attitude_rows else _NO_ATTITUDES,
             np.array(gnss_rows, GNSS_INPUT) if gnss_rows else _NO_GNSS, tick_input.t_ns, tick_input.dt_ns, self._carry_ns, self._out,
             self._diagnostics, self._event_codes, self._event_counts)
        updates: list[UpdateDiagnostic] = [] if field_diagnostic is None else [field_diagnostic]
        updates += decoded(self._diagnostics[:n_diagnostics])
        counters = self.counters
        if n_events:
            for code, n in zip(self._event_codes[:n_events].tolist(), self._event_counts[:n_events].tolist()):
                counters[EVENTS[code]] += n
        for name, n in dropped:
            counters[name] += n
        for d in updates:
            name = counter_name(d)
            if name is not None:
                counters[name] += 1
        published = Bingham._trusted(self._published_M.copy(), self._published_Z.copy())
        return TickResult(published, uncertainty_deg, tuple(updates), dict(counters), self._ahead_ns)
