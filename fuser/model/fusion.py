"""One tick of the fusion model, from the tick's samples to the published attitude distribution.

Read :meth:`FusionModel.step` top to bottom: every value it uses is either
an argument, a setting, the persistent :class:`~fuser.model.state.FilterState`
or a local computed above it.

0. **Check** (:mod:`~fuser.model.imu_check`): the vehicle's IMUs against each
   other; a sample that disagrees is kept out of everything below.
1. **Predict** (:mod:`~fuser.model.propagation`): each IMU's gyro
   integrated, the attitude rotated and composed with the process noise in
   closed form (progressive paper, Alg. 1).
2. **Update**: GNSS velocity differenced into the world acceleration
   (:mod:`~fuser.model.velocity`) and the reference field from the GNSS
   position (:mod:`~fuser.model.field`); gravity (:mod:`~fuser.model.gravity`,
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
   last sample and over the lead, and while an IMU is kept out.

The state is at the tick's end: the gyro carries it over the whole tick, and
every reading is turned into the body frame of that instant.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from functools import lru_cache

import numpy as np

from core.bingham import Bingham
from core.filters import rms_angle_deg
from core.normalization import Method
from drivers.samples import AttitudeSample, GnssSample, ImuSample, MagSample
from fuser import model_error
from fuser.config import FuserConfig
from fuser.model import bias as bias_feedback
from fuser.model.attitude import attitude_in_use, update_attitude
from fuser.model.body_frame import lags_s, mean_in_state_body
from fuser.model.diagnostics import UpdateDiagnostic, counter_name
from fuser.model.extrapolation import ahead_ns, carry_ns, lead
from fuser.model.field import heading_change_rad, turned_heading, update_field
from fuser.model.gravity import tilt_time_constant_s, turn_frame, update_gravity
from fuser.model.heading import FieldReference, heading_sigma_rad, update_heading
from fuser.model.imu_check import check_imus
from fuser.model.propagation import integrate_gyro, predict
from fuser.model.rest import detect_rest, measure_bias
from fuser.model.state import FilterState, GyroState, HeadingState, RestState, initial_state
from fuser.model.tick import TickContext, TickInput, TickResult
from fuser.model.unaided import absorbed, cleared, corrected, followed, learn_norm, unaided_target, unseen_variances_rad2
from fuser.model.velocity import raw_world, tilt_doubt_deg, track_velocity, update_gravity_aided

__all__ = ["FusionModel"]


_RESTART_RAD2 = math.radians(60.0) ** 2
"""Per-axis variance added to the state when the fast start runs again: wide enough for its raw readings and
fast-start headings to take it (unconverged, ``updates.converged_deg``), as at a cold start."""

_field_reference = lru_cache(maxsize=8)(FieldReference.of)
"""The heading update's coefficients of a reference field (computed once per field)."""


def _multiplied(belief: Bingham, exponent: np.ndarray) -> Bingham:
    """``belief`` times the likelihoods whose exponents sum to ``exponent``."""
    return belief.times_exponent(exponent) if exponent.any() else belief


class FusionModel:
    """Bingham attitude fusion of any number of IMUs, magnetometers and attitude sources.

    ``config`` holds the parameters; :attr:`state` the persistent state (read,
    set, :meth:`reset`), the reference field in use included. :meth:`step` runs one tick.
    """

    def __init__(self, config: FuserConfig, method: Method = "saddlepoint") -> None:
        self.config = config
        self.method: Method = method
        """Normalization constant behind every moment match (:mod:`core.normalization`)."""
        self.counters: Counter[str] = Counter()
        """Events so far: readings gated by reason, gyro gaps, rest ticks, ..."""
        self._ahead_ns, self._carry_ns = ahead_ns(config), carry_ns(config)
        self._state = initial_state(config)

    @property
    def state(self) -> FilterState:
        """The persistent state after the last tick (an immutable value)."""
        return self._state

    @state.setter
    def state(self, state: FilterState) -> None:
        if not isinstance(state, FilterState):
            raise TypeError(f"state must be a FilterState, got {type(state).__name__}")
        self._state = state

    def reset(self) -> None:
        """Back to the start: uniform attitude, bias unknown."""
        self._state = initial_state(self.config)

    def step(self, tick: TickInput) -> TickResult:
        """Fuse the samples of one tick (:class:`~fuser.model.tick.TickInput`)."""
        cfg, s = self.config, self._state
        dt = tick.dt_ns * 1e-9
        placed = [x.t_ns for x in tick.samples] if tick.placed_ns is None else tick.placed_ns
        imu: list[tuple[ImuSample, int]] = []
        gnss: list[tuple[GnssSample, int]] = []
        attitudes: list[AttitudeSample] = []
        for x, t in zip(tick.samples, placed):
            if isinstance(x, ImuSample):
                imu.append((x, t))
            elif isinstance(x, GnssSample):
                gnss.append((x, t))
            elif isinstance(x, AttitudeSample):
                attitudes.append(x)
        events: list[str] = []

        # 0. the vehicle's IMUs checked against each other: one that disagrees is kept out
        imu_samples, imu_placed = [x for x, _ in imu], [t for _, t in imu]
        imu_check, kept, disagreeing = check_imus(cfg.imu_check, s.imu_check, imu_samples, imu_placed)
        if disagreeing:
            imu = [imu[i] for i in kept]
            imu_samples, imu_placed = [x for x, _ in imu], [t for _, t in imu]
            events += ["imu_disagree"] * disagreeing
        imu_fault = imu_check.last_fault_ns is not None and tick.t_ns - imu_check.last_fault_ns <= max(cfg.imu_check.compare_within_s * 1e9, tick.dt_ns)

        # 1. predict: the gyro over the whole tick, then the closed-form prediction
        bias = bias_feedback.propagate(cfg.bias, s.bias, dt)
        track, motion = integrate_gyro(cfg.gyro, s.gyro.track, imu_samples, imu_placed, tick.t_ns - tick.dt_ns, tick.t_ns)
        events += ["gyro_gap"] * motion.gaps + ["gyro_saturated"] * motion.saturated_samples
        if not imu:
            events.append("no_gyro")
        if motion.held:
            events.append("gyro_held")
        prediction = predict(cfg.gyro, cfg.bias, s.attitude, bias, motion, dt, self.method)
        # the reference field: the WMM's at the first GNSS position (if not configured); the heading turned with its north
        field, field_diagnostic = update_field(cfg.mag, s.field, [x for x, _ in gnss], tick.t_ns)
        if cfg.mag.enabled and field.field_ned_gauss != s.field.field_ned_gauss:
            prediction = dataclasses.replace(prediction, attitude=turned_heading(prediction.attitude, heading_change_rad(s.field, field)))
        if prediction.rate_rad_s is None:
            rate, error_state = s.gyro.rate_rad_s, s.model_error
        else:
            rate = prediction.rate_rad_s
            error_state = model_error.observe_rate(s.model_error, rate, dt, cfg.accel.lowpass_s)
        unknown_rotation_s = motion.gap_s + motion.saturated_s  # of the tick without a usable rate: the strapdown frame breaks
        gravity = turn_frame(s.gravity, prediction.rotation, unknown_rotation_s)
        context = TickContext(dt, prediction.variance_rad2, rms_angle_deg(prediction.attitude, self.method),
                              tilt_doubt_deg(prediction.attitude, self.method))
        predicted_q = prediction.attitude.mode
        raw_rate = motion.raw_rate_rad_s
        body_rate = None if raw_rate is None else raw_rate - bias.estimate_rad_s

        # 2. updates, gated against the prediction; their exponents add up to one product
        belief, exponent = prediction.attitude, np.zeros((4, 4))
        diagnostics: list[UpdateDiagnostic] = []
        rest, heading, unaided = s.rest, s.heading, s.unaided
        reading, h, since = None, None, dt  # the tick's readings, for the bias (step 3)
        interval = dt if s.gyro.last_imu_tick_ns is None or not imu else (tick.t_ns - s.gyro.last_imu_tick_ns) * 1e-9
        if field_diagnostic is not None:
            diagnostics.append(field_diagnostic)
        lags = lags_s(imu_placed, tick.t_ns)
        accel = mean_in_state_body([x.accel_m_s2 for x in imu_samples], lags, body_rate) if imu else None
        tau = tilt_time_constant_s(cfg.accel, cfg.bias, bias.variance_rad2_s2)
        velocity = track_velocity(cfg.gnss, cfg.accel, cfg.updates, s.velocity, gnss, gravity, accel, tick.t_ns, tick.dt_ns,
                                  predicted_q, context.prior_doubt_deg, context.prior_tilt_doubt_deg, tau, unknown_rotation_s > 0.0)
        diagnostics += velocity.diagnostics
        events += velocity.events
        if accel is not None:
            if cfg.rest.enabled and raw_rate is not None:  # a vehicle GNSS sees moving is not at rest
                rest = RestState() if velocity.moving else detect_rest(cfg.rest, rest, raw_rate, accel, interval)
                if rest.at_rest:
                    events.append("rest_ticks")
                    bias = measure_bias(cfg.rest, rest, bias, interval)
            if velocity.active:
                reading = update_gravity_aided(cfg.accel, cfg.gnss, cfg.updates, gravity, velocity, context, tau, predicted_q)
            else:
                reading = update_gravity(cfg.accel, cfg.updates, gravity, context, accel, tau, predicted_q, interval, cfg.mag.enabled,
                                         raw_world(cfg.gnss, cfg.accel, velocity.state, tick.t_ns))
                if reading.restart:  # the fast start again: the state forgets the tilt and heading it was sure of
                    belief = model_error.with_model_error(belief, _RESTART_RAD2, _RESTART_RAD2)
                    events.append("gnss_restart")
            gravity = reading.state
            # an acceleration the unaided accelerometer cannot tell from gravity, as far as the estimate follows it
            unaided = learn_norm(cfg.accel, unaided, gravity, accel, interval, unknown_rotation_s > 0.0)
            if not velocity.active:
                target, follow_s = unaided_target(cfg.accel, gravity, interval, tau)
                unaided = followed(cfg.accel, unaided, target, interval, follow_s)
            elif reading.tilt_bound_rad is not None and reading.diagnostic is not None and reading.diagnostic.sigma_deg is not None:
                unaided = corrected(cfg.accel, unaided, context.prior_tilt_doubt_deg, reading.diagnostic.sigma_deg,
                                    reading.tilt_bound_rad)
            if reading.diagnostic is not None:
                diagnostics.append(reading.diagnostic)
            if reading.exponent is not None:
                exponent = exponent + reading.exponent
            if reading.apply_now:
                belief, exponent = _multiplied(belief, exponent), np.zeros((4, 4))
        mag = self._mag_in_state_body(tick, imu_samples, lags, None if raw_rate is None else raw_rate - bias.estimate_rad_s)
        if mag is not None:
            since = dt if heading.last_reading_ns is None else (tick.t_ns - heading.last_reading_ns) * 1e-9
            heading = HeadingState(heading.gated_s, tick.t_ns)
            sigma = heading_sigma_rad(cfg.mag, cfg.bias, cfg.updates, gravity.converged, context, bias.variance_rad2_s2, since)
            h = update_heading(cfg.mag, cfg.updates, _field_reference(field.field_ned_gauss), heading, gravity, context, mag, belief.mode, sigma)
            heading = h.state
            diagnostics.append(h.diagnostic)
            if h.exponent is not None:
                exponent = exponent + h.exponent
        attitude_source = s.attitude_source
        attitude_fused = attitude_in_use(cfg.attitude, track, tick.t_ns)
        if attitudes and attitude_fused:
            a = update_attitude(cfg.attitude, cfg.updates, attitude_source, attitudes, belief.mode,
                                gravity.down_body if gravity.tilt_known else None, context)
            attitude_source = a.state
            for e in a.exponents:
                exponent = exponent + e
            diagnostics += a.diagnostics
            if a.exponents:
                attitude_source = dataclasses.replace(attitude_source, last_fused_ns=tick.t_ns)
        elif attitudes:
            events += ["attitude_unused"] * len(attitudes)
        posterior = _multiplied(belief, exponent)
        # the tilt the plain update's corrections took from the accelerometer, which a false vertical would have put there
        plain = (reading is not None and reading.exponent is not None and not velocity.active and not reading.restart
                 and s.gravity.converged and not (attitudes and attitude_fused))
        unaided = absorbed(cfg.accel, unaided, dt, tau, (predicted_q, posterior.mode) if plain else None)
        if attitude_source.last_fused_ns is not None and tick.t_ns - attitude_source.last_fused_ns <= cfg.accel.lowpass_s * 1e9:
            # the autopilot's down, fused within the tilt time constant: what the accelerometer could not see is its estimator's
            unaided = cleared(cfg.accel, unaided)

        # 3. bias learnt in motion from the tick's corrections, each through its own model (VQF's motion bias estimation)
        if imu:
            bias = bias_feedback.learn_from_tick(cfg, bias, prediction.attitude, posterior.mode, context, tau, interval,
                                                 velocity, reading, h, since, unaided, attitude_fused,
                                                 rest.at_rest, rate, unknown_rotation_s > 0.0 or not gravity.converged)

        # 4. publish: carried ahead of the tick by the held rate, widened by the model error, the error of a rate held since
        # the last sample and over the lead, an IMU kept out and, without GNSS aiding, the acceleration the norm reveals
        ahead = lead(cfg.gyro, track, bias.estimate_rad_s, tick.t_ns, self._carry_ns)
        widening = motion.hold_variance_rad2 + ahead.variance_rad2 + (math.radians(cfg.imu_check.fault_sigma_deg) ** 2 if imu_fault else 0.0)
        unseen_rad2 = unseen_variances_rad2(cfg.accel, unaided, field.field_ned_gauss if cfg.mag.enabled else None)
        carried = posterior if ahead.rotation is None else posterior.rotate_right(ahead.rotation)
        published = model_error.published(cfg.model_error, carried, error_state.rate_sq, cfg.mag.enabled, widening, unseen_rad2)

        self._state = FilterState(attitude=posterior, bias=bias, gyro=GyroState(track, rate, tick.t_ns if imu else s.gyro.last_imu_tick_ns),
                                  rest=rest, gravity=gravity, heading=heading, attitude_source=attitude_source, imu_check=imu_check,
                                  model_error=error_state, velocity=velocity.state, field=field, unaided=unaided)
        events += [c for c in map(counter_name, diagnostics) if c is not None]
        if events:
            self.counters.update(events)
        return TickResult(published, rms_angle_deg(published, self.method), tuple(diagnostics), dict(self.counters), self._ahead_ns,
                          ahead.rotation, imu_fault)

    def _mag_in_state_body(self, tick: TickInput, imu: list[ImuSample], lags: np.ndarray, body_rate: np.ndarray | None) -> np.ndarray | None:
        """The tick's mean magnetic field (separate magnetometers, then the IMUs' own, in the state's body
        frame), or None without one or with the magnetometer off; ``lags`` are the IMU samples' before the tick."""
        if not self.config.mag.enabled:
            return None
        mags: list = [x.mag_gauss for x in tick.samples if isinstance(x, MagSample)]
        with_mag = [i for i, x in enumerate(imu) if x.mag_gauss is not None]
        if with_mag:
            mags.append(mean_in_state_body([imu[i].mag_gauss for i in with_mag], lags if len(with_mag) == len(imu) else lags[with_mag],
                                           body_rate))
        if not mags:
            return None
        return np.asarray(mags[0], dtype=float) if len(mags) == 1 else np.mean(mags, axis=0)
