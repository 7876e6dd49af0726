"""The fusion model: turns one tick's samples into Bingham filter operations.

Per tick: integrate each IMU's gyro into a rotation ``u`` and predict
``x_k = x_(k-1) (x) u (x) w`` in closed form (progressive paper, Alg. 1) with
``w``'s concentration from the gyro noise density and the tick length;
update with the mean gravity direction (an exact Bingham likelihood,
:func:`core.observations.vector_exponent`), the magnetometer's heading
(yaw-only, :func:`core.observations.heading_exponent`) and, if
configured, the autopilot's attitude (identity measurement). The state
starts uniform: no prior knowledge of the attitude is needed. The gyro
bias is a point estimate beside the Bingham, learnt at rest directly and in
motion by integral feedback (VQF: D. Laidig, T. Seel, "VQF: Highly accurate
IMU orientation estimation with bias estimation and magnetic disturbance
rejection", Information Fusion 91, 2023).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from core.filters import BinghamFilter, identity_likelihood, rms_angle_deg
from core.observations import heading_exponent, vector_exponent
from drivers.euler import euler_from_quaternion
from drivers.samples import AttitudeSample, ImuSample, MagSample, Sample, SourceId
from fuser.codec import Estimate
from fuser.config import FuserConfig
from fuser.model_error import ModelError

__all__ = ["FusionModel", "GRAVITY_M_S2"]

GRAVITY_M_S2 = 9.80665
_DOWN = np.array([0.0, 0.0, 1.0])
_MIN_VARIANCE = 1e-18  # caps the noise concentration at 2e18 for a zero-length tick
_BIAS_LEARN_MAX_UNCERTAINTY_DEG = 5.0
_DEFAULT_BIAS_CORRELATION_S = 10.0
_MAX_BIAS = 0.2  # rad/s: beyond any MEMS gyro's bias; stops a wrong start from running away


def _norm(v: np.ndarray) -> float:
    """Euclidean norm of one small vector (``np.linalg.norm`` costs several times more)."""
    return math.sqrt(float(v @ v))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (``np.cross`` costs ten times more on one pair)."""
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    return np.array([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx])


def _rotation_noise(angle_variance: float) -> Bingham:
    """Isotropic rotation noise whose per-axis angle variance is ``angle_variance`` (rad^2).

    The vector part of a small rotation is half its angle, and a Bingham's
    ``E[y_i^2] -> 1/(2|z_i|)``, so ``z = -2 / variance``.
    """
    z = -2.0 / max(angle_variance, _MIN_VARIANCE)
    return Bingham.from_mode(quat.IDENTITY, [z, z, z])


class FusionModel:
    """Bingham attitude fusion of any number of IMUs, magnetometers and attitude sources."""

    def __init__(self, config: FuserConfig) -> None:
        self.config = config
        self.filter = BinghamFilter(Bingham.uniform())
        self.counters: Counter[str] = Counter()
        self._last_gyro: dict[SourceId, tuple[int, tuple[float, float, float]]] = {}  # time and rate of each IMU's last gyro sample
        self._clock_offset_ns: dict[SourceId, int] = {}  # least (tick time - sample time) seen: the loop's timeline
        self._noise_cache: dict[int, Bingham] = {}
        field = np.asarray(config.mag_field_ned_gauss, dtype=float)
        self._field_norm = float(np.linalg.norm(field))
        self._field_dip = math.asin(field[2] / self._field_norm)
        self._field_heading = math.atan2(field[1], field[0])
        self._tilt_known = False
        self._evidence = np.zeros((4, 4))  # exponent of this tick's likelihoods, applied at once
        self.gyro_bias = np.zeros(3)
        self.bias_variance = config.gyro_bias_rad_s**2
        self._rate = 0.0
        self._raw_rate: np.ndarray | None = None  # this tick's mean gyro rate, bias not removed
        self._rest_gyro_lp: np.ndarray | None = None
        self._rest_accel_lp: np.ndarray | None = None
        self._rest_s = 0.0
        self.at_rest = False
        self._accel_trusted = False
        self._acc_lp: np.ndarray | None = None
        self._converged = False  # once converged, the raw accelerometer is never trusted again
        self._q_gyro = quat.IDENTITY.copy()  # strapdown integration only: the accelerometer filter's frame
        self._down_body = _DOWN.copy()
        self._tick_variance = 0.0
        self._dt = 0.0
        self._prior_doubt_deg = 180.0
        self._rejected_s: Counter[str] = Counter()
        self.model_error = ModelError(config)

    # -- one tick ---------------------------------------------------------------
    def step(self, samples: list[Sample], dt_ns: int, t_ns: int) -> Estimate:
        """Fuse the samples of one tick of length ``dt_ns`` ending at ``t_ns``."""
        imu = [s for s in samples if isinstance(s, ImuSample)]
        self._accel_trusted = False
        self._predict(imu, dt_ns)
        predicted = self.filter.estimate
        prior_doubt_deg = self._prior_doubt_deg = rms_angle_deg(self.filter.state, self.filter.method)
        # Every update below is gated and referenced against this prediction and adds its
        # likelihood's exponent to self._evidence; the product of the tick's likelihoods is then
        # one Bingham product (exponents add: QBF paper, sec. 5, eq. 3), one eigendecomposition.
        lags = self._lags(imu)
        if imu:
            accel = self._in_last_body([s.accel_m_s2 for s in imu], lags)
            self._detect_rest(accel)
            self._update_gravity(accel, dt_ns * 1e-9)
        with_mag = [s for s in imu if s.mag_gauss is not None]
        mags = [s.mag_gauss for s in samples if isinstance(s, MagSample)]
        if with_mag:
            mag_lags = lags if len(with_mag) == len(imu) else self._lags(with_mag)
            mags.append(self._in_last_body([s.mag_gauss for s in with_mag], mag_lags))
        if mags and self.config.use_mag:
            self._update_heading(np.asarray(mags[0], dtype=float) if len(mags) == 1 else np.mean(mags, axis=0))
        if self.config.attitude_sigma_deg is not None:
            for s in samples:
                if isinstance(s, AttitudeSample):
                    self._update_attitude(s.q_wxyz)
        self._apply_evidence()
        self._learn_bias(predicted, prior_doubt_deg)
        return self._estimate(t_ns, self._published(imu, t_ns))

    def _lags(self, imu: list[ImuSample]) -> np.ndarray:
        """Seconds each sample lies behind its IMU's last gyro sample (the state's time)."""
        return np.array([(self._last_gyro[s.source][0] - s.t_ns) * 1e-9 if s.source in self._last_gyro else 0.0 for s in imu])

    def _in_last_body(self, vectors: list, lags: np.ndarray) -> np.ndarray:
        """Mean of samples' body-frame vectors, each turned into the body frame of the state's time
        (``lags`` seconds later): at 600 deg/s the body turns 3 degrees in half a 10-ms tick, which
        averaging in the moving frame would put into the tilt and heading measurements.
        Small-angle rotation at this tick's rate: ``v - (w dt) x v``."""
        v = np.asarray(vectors, dtype=float)
        mean = v.sum(axis=0) / len(v)
        if self._raw_rate is None:
            return mean
        # the rotation is linear in v: the mean of the turned vectors turns the lag-weighted mean once
        return mean - _cross(self._raw_rate - self.gyro_bias, lags @ v / len(v))

    def _detect_rest(self, accel: np.ndarray) -> None:
        """Rest detection and rest-phase bias estimation (VQF, sec. 3.3).

        The body-frame gyro and accelerometer are low-passed over
        ``rest_filter_s``; the sensor is at rest once neither has left its
        low-pass by more than its threshold (and the low-passed rate is
        below the gyro threshold) for ``rest_min_s``. At rest the low-passed
        gyro reads the bias directly: a Kalman update of the bias with it,
        whose noise is counted once per ``rest_filter_s`` (consecutive
        low-passed readings are correlated, not independent).
        """
        cfg = self.config
        gyro, dt = self._raw_rate, self._dt
        if cfg.rest_min_s <= 0 or gyro is None or dt <= 0.0:
            return
        if self._rest_gyro_lp is None or self._rest_accel_lp is None:
            self._rest_gyro_lp, self._rest_accel_lp = gyro.copy(), accel.copy()
        a = min(1.0, dt / cfg.rest_filter_s)
        self._rest_gyro_lp += a * (gyro - self._rest_gyro_lp)
        self._rest_accel_lp += a * (accel - self._rest_accel_lp)
        still = (
            _norm(gyro - self._rest_gyro_lp) < cfg.rest_gyro_rad_s
            and _norm(self._rest_gyro_lp) < cfg.rest_gyro_rad_s
            and _norm(accel - self._rest_accel_lp) < cfg.rest_accel_m_s2
        )
        self._rest_s = self._rest_s + dt if still else 0.0
        self.at_rest = self._rest_s >= cfg.rest_min_s
        if not self.at_rest:
            return
        self.counters["rest_ticks"] += 1
        noise = cfg.rest_bias_sigma_rad_s**2 * max(cfg.rest_filter_s / dt, 1.0)
        gain = self.bias_variance / (self.bias_variance + noise)
        self.gyro_bias = self.gyro_bias + gain * (self._rest_gyro_lp - self.gyro_bias)
        self.bias_variance *= 1.0 - gain

    def _tilt_time_constant(self) -> float:
        """Tilt-correction (and accelerometer low-pass) time constant for the current bias uncertainty.

        A residual bias ``b`` makes the tilt lag by ``b tau`` behind a
        correction loop of time constant ``tau``; a longer ``tau`` lets less
        linear acceleration through. So ``tau = tilt_bias_error / sigma_b``,
        capped at ``accel_lowpass_s``: fast while the bias is unknown (a
        cold start, a multirotor's 1 deg/s bias), VQF's slow 3 s once learnt.
        """
        cfg = self.config
        return min(cfg.accel_lowpass_s, math.radians(cfg.tilt_bias_error_deg) / math.sqrt(max(self.bias_variance, _MIN_VARIANCE)))

    def _learn_bias(self, predicted: np.ndarray, prior_doubt_deg: float) -> None:
        """Integral feedback of the tick's correction into the gyro bias (Mahony-style).

        A bias error ``e`` makes the prediction drift by ``e dt`` per tick, which
        the updates then correct; feeding ``-correction / tau`` back drives the
        estimate to the bias with time constant ``tau``. Learnt only when the
        accelerometer was trusted and the body turned slowly, so manoeuvres do
        not leak into it. The orientation stays a Bingham; the bias is a point
        estimate whose residual error is the process noise ``gyro_bias_rad_s``.
        """
        cfg = self.config
        if cfg.bias_time_constant_s <= 0 or self.at_rest or not self._accel_trusted or self._rate > cfg.bias_learn_max_rate_rad_s:
            return
        if prior_doubt_deg > _BIAS_LEARN_MAX_UNCERTAINTY_DEG:
            return  # the prediction was a guess (uniform start, after a gap): its correction is not drift
        correction = quat.to_rotvec(quat.multiply(quat.conjugate(predicted), self.filter.estimate))
        self.gyro_bias = np.minimum(np.maximum(self.gyro_bias - correction / cfg.bias_time_constant_s, -_MAX_BIAS), _MAX_BIAS)
        # learning for a tick shrinks the bias uncertainty towards its floor with the same time constant
        # (never raises it: a bias learnt at rest is known better than feedback can tell)
        decay = min(1.0, self._dt / cfg.bias_time_constant_s)
        self.bias_variance -= decay * max(0.0, self.bias_variance - cfg.gyro_bias_floor_rad_s**2)

    def _predict(self, imu: list[ImuSample], dt_ns: int) -> None:
        cfg = self.config
        dt = self._dt = dt_ns * 1e-9
        self.bias_variance = min(self.bias_variance + cfg.gyro_bias_walk_rad_s_rt_s**2 * dt, cfg.gyro_bias_rad_s**2)
        rates = []
        sources = {s.source for s in imu}
        for source in sorted(sources):
            mine = imu if len(sources) == 1 else [s for s in imu if s.source == source]
            rotvec, covered = self._integrate(sorted(mine, key=lambda s: s.t_ns))
            if covered > 0.0:
                rates.append(rotvec / covered)
        self._raw_rate = (sum(rates) / len(rates)) if rates else None
        # A bias error persists: over the correlation time tau it turns the
        # attitude by e*tau, the same as white noise of variance e^2 tau dt per
        # tick; (e dt)^2 would understate it by tau/dt and make the filter
        # overconfident (and the bias loop underdamped).
        correlation_s = cfg.bias_time_constant_s if cfg.bias_time_constant_s > 0 else _DEFAULT_BIAS_CORRELATION_S
        variance = cfg.gyro_noise_rad_s_rt_hz**2 * dt + self.bias_variance * correlation_s * dt
        if self._raw_rate is not None:
            rate = self._raw_rate - self.gyro_bias
            self._rate = _norm(rate)
            self.model_error.observe_rate(self._rate, dt)
            u = quat.from_rotvec(rate * dt)
            self._q_gyro = quat.normalize(quat.multiply(self._q_gyro, u))
            variance += (cfg.gyro_scale_error * self._rate * dt) ** 2
        else:
            u = None
            variance += (cfg.gyro_gap_rate_rad_s * dt) ** 2
            self.counters["no_gyro"] += 1
        self._tick_variance = variance
        self.filter.predict(self._noise(variance), u)

    def _integrate(self, samples: list[ImuSample]) -> tuple[np.ndarray, float]:
        """Rotation vector and seconds covered by one IMU's gyro samples.

        Each sample is the rate at its time stamp, so the rate between two
        samples is their mean (trapezoidal rule): holding the new rate over
        the preceding interval would lag the attitude by half a sample
        period, a degree at 600 deg/s and 286 Hz.
        """
        x = y = z = covered = 0.0  # plain floats: a tick holds a handful of samples
        for s in samples:
            rate = s.gyro_rad_s
            last = self._last_gyro.get(s.source)
            self._last_gyro[s.source] = (s.t_ns, rate)
            if last is None:
                continue
            dt = (s.t_ns - last[0]) * 1e-9
            if not 0.0 < dt <= self.config.max_gyro_dt_s:
                self.counters["gyro_gap"] += 1
                continue
            half = 0.5 * dt
            x += half * (rate[0] + last[1][0])
            y += half * (rate[1] + last[1][1])
            z += half * (rate[2] + last[1][2])
            covered += dt
        return np.array([x, y, z]), covered

    def _published(self, imu: list[ImuSample], t_ns: int) -> Bingham:
        """The state carried from the last gyro sample to the tick time at that sample's rate.

        The loop fuses samples placed up to the tick time ``t_ns`` at
        ``sample time + offset`` (its least latency) and stamps the estimate
        with the tick time; the least ``t_ns - sample time`` seen is that
        offset, so the rest of the gap is how far the tick lies past the
        state's last gyro sample (up to one sample period, half of one on
        average: 0.5 deg at 600 deg/s and 286 Hz). Only the published
        estimate moves; the filter integrates on from the sample.
        """
        if not imu:
            return self.model_error.apply(self.filter.state)
        source = min(s.source for s in imu)
        last_ns, rate = self._last_gyro[source]
        gap = t_ns - last_ns
        offset = self._clock_offset_ns[source] = min(self._clock_offset_ns.get(source, gap), gap)
        lead = min((gap - offset) * 1e-9, self._dt)
        if lead <= 0.0:
            return self.model_error.apply(self.filter.state)
        return self.model_error.apply(self.filter.state.rotate_right(quat.from_rotvec((rate - self.gyro_bias) * lead)))

    def _noise(self, variance: float) -> Bingham:
        key = round(math.log(variance) * 20)  # 5% steps: ticks repeat their length and the bias variance settles
        if key not in self._noise_cache:
            self._noise_cache[key] = _rotation_noise(variance)
        return self._noise_cache[key]

    def _apply_evidence(self) -> None:
        """Multiply the likelihoods gathered so far into the state."""
        if self._evidence.any():
            self.filter.state = self.filter.state.times_exponent(self._evidence)
            self._evidence = np.zeros((4, 4))

    def _update_gravity(self, accel: np.ndarray, dt: float) -> None:
        """Gravity direction update from the accelerometer, low-passed in a near-inertial frame.

        Every reading is rotated into an inertial frame by the gyro-only
        strapdown attitude (never corrected, so the frame holds still while
        the estimate is corrected) and low-passed there, as VQF does: linear and centripetal
        accelerations average out over the tilt time constant (up to
        ``accel_lowpass_s``, see :meth:`_tilt_time_constant`), gravity does not,
        and rotation does not smear the filter. The filtered vector, seen in
        the current body frame, is the gravity measurement. Consecutive
        filtered readings are strongly correlated, so they must not be
        counted as independent: the per-tick sigma is set so that the
        correction time constant is that same ``tau`` (``sigma^2 = q
        (tau/dt)^2`` for a per-tick process variance ``q``), which keeps the
        reported tilt uncertainty honest. Until the state first converges the
        raw reading is used with ``accel_sigma_rad``, for a fast start; never
        after, when a raw reading mid-manoeuvre is the misleading one.
        The first tilt measurement is applied at once: the heading update that
        follows in the same tick needs to know which way is down.
        """
        cfg = self.config
        tau = self._tilt_time_constant()
        to_inertial = quat.to_matrix(self._q_gyro)
        f_inertial = to_inertial @ accel
        self._converged = self._converged or self._prior_doubt_deg < cfg.converged_deg
        converged = self._converged
        if self._acc_lp is None or not converged:
            self._acc_lp = f_inertial
        else:
            self._acc_lp += min(1.0, dt / tau) * (f_inertial - self._acc_lp)
        norm = _norm(self._acc_lp)
        error = abs(norm - GRAVITY_M_S2) / GRAVITY_M_S2
        if error > cfg.accel_gate:
            self.counters["accel_gated"] += 1
            return
        filtered_body = self._acc_lp @ to_inertial
        self._down_body = -filtered_body / norm  # measured, for the magnetometer's dip check
        if converged:
            sigma = math.sqrt(self._tick_variance) * tau / max(dt, 1e-6)
        else:
            sigma = cfg.accel_sigma_rad
        predicted_down = quat.to_matrix(self.filter.estimate)[2]  # R^T e_z: world down in the body
        innovation = math.acos(max(-1.0, min(1.0, float(self._down_body @ predicted_down))))
        if self._tilt_known and not self._innovation_ok("accel", innovation, sigma):
            return
        self._evidence += vector_exponent(-filtered_body, _DOWN, sigma)
        self._accel_trusted = converged and error < 0.5 * cfg.accel_gate
        if not self._tilt_known:
            self._apply_evidence()
            self._tilt_known = True

    def _update_heading(self, mag: np.ndarray) -> None:
        """Yaw-only update (:func:`core.observations.heading_exponent`) against the predicted attitude,
        once a previous tick has measured the tilt (a heading needs to know which way is down)."""
        if not self._tilt_known:
            self.counters["mag_before_tilt"] += 1
            return
        norm = _norm(mag)
        if abs(norm - self._field_norm) > self.config.mag_norm_gate * self._field_norm:
            self.counters["mag_gated_norm"] += 1
            return
        # dip from the angle between the field and the measured gravity, both in the body frame,
        # so that a wrong tilt estimate cannot lock the magnetometer out
        dip = math.asin(max(-1.0, min(1.0, float(mag @ self._down_body) / norm)))
        if abs(math.degrees(dip - self._field_dip)) > self.config.mag_dip_gate_deg:
            self.counters["mag_gated_dip"] += 1
            return
        q = self.filter.estimate
        m_world = quat.rotate(q, mag)
        error = self._field_heading - math.atan2(m_world[1], m_world[0])
        error = math.remainder(error, 2.0 * math.pi)
        sigma = self._heading_sigma()
        if not self._innovation_ok("mag", abs(error), max(sigma, self.config.mag_sigma_rad)):
            return
        self._evidence += heading_exponent(q, error, sigma)

    def _heading_sigma(self) -> float:
        """Per-tick heading sigma: ``mag_sigma_rad`` until converged; then the magnetometer's correlated
        error counted once per correlation time, ``mag_error sqrt(T_c / dt)`` (a fixed per-tick sigma
        counts errors that persist for seconds as independent and follows them), but never slower than a
        correction time constant ``tau = heading_bias_error / bias sigma`` (``sigma^2 = q (tau/dt)^2`` for the
        tick's process variance ``q``, as for the tilt), so that a poorly known bias is still held."""
        cfg = self.config
        dt = self._dt
        if not self._converged or dt <= 0.0:
            return cfg.mag_sigma_rad
        correlated = math.radians(cfg.mag_error_deg) * math.sqrt(max(cfg.mag_correlation_s / dt, 1.0))
        tau = math.radians(cfg.heading_bias_error_deg) / math.sqrt(max(self.bias_variance, _MIN_VARIANCE))
        return min(correlated, math.sqrt(self._tick_variance) * tau / dt)

    def _innovation_ok(self, sensor: str, innovation_rad: float, sigma_rad: float) -> bool:
        """Chi-style gate: accept a reading within ``k`` sigma of the prediction (sensor and predicted
        state uncertainty combined), or after ``innovation_reanchor_s`` of continuous rejections."""
        cfg = self.config
        state_sigma = math.radians(self._prior_doubt_deg)
        if innovation_rad <= cfg.innovation_gate_sigma * math.hypot(sigma_rad, state_sigma):
            self._rejected_s[sensor] = 0.0
            return True
        self._rejected_s[sensor] += self._dt
        if self._rejected_s[sensor] >= cfg.innovation_reanchor_s:
            self._rejected_s[sensor] = 0.0
            self.counters[f"{sensor}_reanchored"] += 1
            return True
        self.counters[f"{sensor}_gated_innovation"] += 1
        return False

    def _update_attitude(self, q_wxyz: tuple[float, float, float, float]) -> None:
        sigma = math.radians(self.config.attitude_sigma_deg or 0.0)
        self._evidence += identity_likelihood(quat.normalize(q_wxyz), _rotation_noise(sigma * sigma)).C

    def _estimate(self, t_ns: int, state: Bingham) -> Estimate:
        q = tuple(state.mode.tolist())
        return Estimate(
            t_ns=t_ns,
            q_wxyz=q,  # type: ignore[arg-type]
            M=tuple(map(tuple, state.M.tolist())),  # type: ignore[arg-type]
            Z=tuple(state.Z.tolist()),  # type: ignore[arg-type]
            uncertainty_deg=rms_angle_deg(state, self.filter.method),
            euler_deg=tuple(math.degrees(a) for a in euler_from_quaternion(q)),  # type: ignore[arg-type]
            counters=dict(self.counters),
        )
