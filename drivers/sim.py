"""A simulated multirotor: true attitude and the IMU, magnetometer and attitude messages it would send.

The flight is a fixed 60-s programme, then hover: hover with wobble (0-10 s),
coordinated turns (10-25 s), aggressive roll/pitch/yaw (25-40 s), a roll flip
(42 s, 0.6 s), hover. Attitude is given by Euler 3-2-1 angles that are sums
of smoothly windowed terms with analytic derivatives, so the true body rate
is exact, not differenced. Thrust is along body -z, sized to hold altitude
(cut during the flip), so the true specific force is ``(0, 0, -thrust)``.

Sensor model per axis (numpy, vectorised): ``meas = (1 + scale) * true +
bias(t) + noise``, the bias a random walk from a random start, vibration
added to the accelerometer, clipped at the sensor range (saturation), and
samples dropped at random (dropouts). The autopilot's own attitude estimate
is the truth times a small random rotation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import can
import numpy as np
from numpy.typing import NDArray

from core import quaternion as cq

from .dronecan_encode import encode_dronecan
from .mavlink_encode import MavlinkEncoder
from .samples import AttitudeSample, ImuSample, Sample, SourceId

GRAVITY_M_S2 = 9.80665
EARTH_FIELD_NED_GAUSS = (0.21, 0.0, 0.43)
Array = NDArray[np.float64]


@dataclass(frozen=True)
class SimConfig:
    """Every knob of the simulation; the defaults resemble a small quadcopter with an ICM-20602-class IMU."""

    seed: int = 0
    duration_s: float = 60.0
    imu_rate_hz: float = 400.0
    attitude_rate_hz: float = 25.0
    mag_rate_hz: float = 100.0
    boot_time_s: float = 5.0
    gyro_noise_rad_s: float = 0.003
    accel_noise_m_s2: float = 0.03
    mag_noise_gauss: float = 0.003
    gyro_bias_rad_s: float = 0.01
    accel_bias_m_s2: float = 0.1
    gyro_bias_walk_rad_s_rt_s: float = 2e-4
    accel_bias_walk_m_s2_rt_s: float = 2e-3
    scale_error: float = 0.005
    vibration_m_s2: float = 1.5
    vibration_hz: float = 137.0
    gyro_range_rad_s: float = 34.9
    accel_range_m_s2: float = 156.9
    dropout_probability: float = 0.002
    attitude_error_rad: float = 0.01
    mag_field_ned_gauss: tuple[float, float, float] = EARTH_FIELD_NED_GAUSS


@dataclass(frozen=True)
class Flight:
    """Truth and measurements on the IMU time grid (N samples); attitude output at ``attitude_index``."""

    t_ns: NDArray[np.int64]
    q_true: Array
    gyro_true_rad_s: Array
    accel_true_m_s2: Array
    mag_true_gauss: Array
    gyro_rad_s: Array
    accel_m_s2: Array
    mag_gauss: Array
    """NaN rows where the magnetometer was not sampled."""
    gyro_bias_rad_s: Array
    accel_bias_m_s2: Array
    imu_valid: NDArray[np.bool_]
    """False where the IMU sample was dropped."""
    attitude_index: NDArray[np.int64]
    q_attitude: Array


def _smoothstep(x: Array) -> tuple[Array, Array, Array]:
    """s(x) = 3x^2 - 2x^3 on [0, 1] (0 before, 1 after), its derivative and its integral from 0."""
    c = np.clip(x, 0.0, 1.0)
    value = c * c * (3.0 - 2.0 * c)
    slope = 6.0 * c * (1.0 - c)
    integral = c**3 - 0.5 * c**4 + np.maximum(x - 1.0, 0.0)
    return value, slope, integral


def _window(t: Array, start: float, end: float, ramp: float = 2.0) -> tuple[Array, Array, Array]:
    """A window rising over ``ramp`` seconds at ``start`` and falling at ``end``: value, derivative, integral."""
    v0, d0, i0 = _smoothstep((t - start) / ramp)
    v1, d1, i1 = _smoothstep((t - end) / ramp)
    return v0 - v1, (d0 - d1) / ramp, (i0 - i1) * ramp


def _wave(t: Array, win: tuple[Array, Array, Array], amp: float, hz: float, phase: float = 0.0) -> tuple[Array, Array]:
    """amp * window(t) * sin(2 pi hz t + phase) and its derivative."""
    w, dw, _ = win
    arg = 2.0 * np.pi * hz * t + phase
    return amp * w * np.sin(arg), amp * (dw * np.sin(arg) + w * 2.0 * np.pi * hz * np.cos(arg))


def euler_programme(t: Array) -> tuple[Array, Array]:
    """Euler angles (roll, pitch, yaw) of the flight programme at times ``t`` (s), shape (N, 3), and their rates."""
    hover = _window(t, -10.0, np.inf)
    turns = _window(t, 10.0, 25.0)
    aggressive = _window(t, 25.0, 40.0, ramp=1.0)
    terms = {
        "roll": [
            _wave(t, hover, 0.03, 0.4),
            _wave(t, turns, 0.35, 0.1, np.pi / 2),
            _wave(t, aggressive, 0.7, 1.3),
        ],
        "pitch": [_wave(t, hover, 0.03, 0.33, 1.0), _wave(t, aggressive, 0.6, 0.9, 0.5)],
        "yaw": [_wave(t, hover, 0.2, 0.05), _wave(t, aggressive, 1.2, 0.7, 2.0)],
    }
    flip, flip_rate, _ = _smoothstep((t - 42.0) / 0.6)
    turn_w, turn_dw, turn_int = turns
    extra = {
        "roll": (2.0 * np.pi * flip, 2.0 * np.pi * flip_rate / 0.6),
        "pitch": (0.0 * t, 0.0 * t),
        "yaw": (0.5 * turn_int, 0.5 * turn_w),  # 0.5 rad/s sustained turn while banked
    }
    angles, rates = [], []
    for axis in ("roll", "pitch", "yaw"):
        angles.append(sum(v for v, _ in terms[axis]) + extra[axis][0])
        rates.append(sum(d for _, d in terms[axis]) + extra[axis][1])
    return np.stack(angles, -1), np.stack(rates, -1)


def _euler_to_quaternion(euler: Array) -> Array:
    z, y, x = np.eye(3)[2], np.eye(3)[1], np.eye(3)[0]
    yaw_pitch = cq.multiply(cq.from_axis_angle(z, euler[:, 2]), cq.from_axis_angle(y, euler[:, 1]))
    return cq.multiply(yaw_pitch, cq.from_axis_angle(x, euler[:, 0]))


def _body_rates(euler: Array, euler_rates: Array) -> Array:
    """Body angular velocity (p, q, r) from Euler 3-2-1 angles and their rates."""
    roll, pitch = euler[:, 0], euler[:, 1]
    droll, dpitch, dyaw = euler_rates.T
    return np.stack(
        [
            droll - dyaw * np.sin(pitch),
            dpitch * np.cos(roll) + dyaw * np.cos(pitch) * np.sin(roll),
            -dpitch * np.sin(roll) + dyaw * np.cos(pitch) * np.cos(roll),
        ],
        -1,
    )


def _thrust(q: Array) -> Array:
    """Thrust per unit mass holding altitude while the body is upright enough; 0.3 g otherwise (a flip)."""
    tilt_cos = 1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2)  # body z . world z
    return np.where(tilt_cos > 0.5, GRAVITY_M_S2 / np.maximum(tilt_cos, 0.5), 0.3 * GRAVITY_M_S2)


def _sensor(
    rng: np.random.Generator, true: Array, dt: float, noise: float, bias0: float, walk: float, scale: float, limit: float
) -> tuple[Array, Array]:
    """Measured values and the bias time line of one 3-axis sensor."""
    n = len(true)
    bias = bias0 * rng.standard_normal(3) + np.cumsum(walk * np.sqrt(dt) * rng.standard_normal((n, 3)), axis=0)
    meas = (1.0 + scale * rng.standard_normal(3)) * true + bias + noise * rng.standard_normal((n, 3))
    return np.clip(meas, -limit, limit), bias


def simulate(config: SimConfig = SimConfig()) -> Flight:
    """Run the flight programme under ``config``; deterministic for a given seed."""
    rng = np.random.default_rng(config.seed)
    n = int(round(config.duration_s * config.imu_rate_hz))
    dt = 1.0 / config.imu_rate_hz
    t = np.arange(n) * dt
    t_ns = (round(config.boot_time_s * 1e9) + np.round(t * 1e9)).astype(np.int64)
    euler, euler_rates = euler_programme(t)
    q = _euler_to_quaternion(euler)
    gyro_true = _body_rates(euler, euler_rates)
    accel_true = np.zeros((n, 3))
    accel_true[:, 2] = -_thrust(q)
    mag_true = cq.rotate(cq.conjugate(q), np.asarray(config.mag_field_ned_gauss))

    gyro, gyro_bias = _sensor(
        rng, gyro_true, dt, config.gyro_noise_rad_s, config.gyro_bias_rad_s,
        config.gyro_bias_walk_rad_s_rt_s, config.scale_error, config.gyro_range_rad_s,
    )
    vibration = config.vibration_m_s2 * np.sin(2 * np.pi * config.vibration_hz * t[:, None] + rng.uniform(0, 2 * np.pi, 3))
    accel, accel_bias = _sensor(
        rng, accel_true + vibration, dt, config.accel_noise_m_s2, config.accel_bias_m_s2,
        config.accel_bias_walk_m_s2_rt_s, config.scale_error, config.accel_range_m_s2,
    )
    mag = mag_true + config.mag_noise_gauss * rng.standard_normal((n, 3))
    mag_every = max(1, round(config.imu_rate_hz / config.mag_rate_hz))
    mag[np.arange(n) % mag_every != 0] = np.nan

    attitude_index = np.arange(0, n, max(1, round(config.imu_rate_hz / config.attitude_rate_hz)))
    error = cq.from_rotvec(config.attitude_error_rad * rng.standard_normal((len(attitude_index), 3)))
    return Flight(
        t_ns=t_ns,
        q_true=q,
        gyro_true_rad_s=gyro_true,
        accel_true_m_s2=accel_true,
        mag_true_gauss=mag_true,
        gyro_rad_s=gyro,
        accel_m_s2=accel,
        mag_gauss=mag,
        gyro_bias_rad_s=gyro_bias,
        accel_bias_m_s2=accel_bias,
        imu_valid=rng.random(n) >= config.dropout_probability,
        attitude_index=attitude_index,
        q_attitude=cq.multiply(q[attitude_index], error),
    )


SIM_SOURCE = SourceId("sim", 1, 1, 0)


def samples(flight: Flight, source: SourceId = SIM_SOURCE) -> Iterator[tuple[int, Array, list[Sample]]]:
    """Per IMU tick: (true time ns, true q_wxyz, the samples the vehicle emits at that tick)."""
    is_attitude = np.zeros(len(flight.t_ns), dtype=bool)
    is_attitude[flight.attitude_index] = True
    q_attitude = iter(flight.q_attitude.tolist())
    t_all, gyro, accel, mag = (a.tolist() for a in (flight.t_ns, flight.gyro_rad_s, flight.accel_m_s2, flight.mag_gauss))
    for k, t in enumerate(t_all):
        out: list[Sample] = []
        if flight.imu_valid[k]:
            m = mag[k]
            out.append(ImuSample(t, tuple(gyro[k]), tuple(accel[k]), None if m[0] != m[0] else tuple(m), source))  # type: ignore[arg-type]
        if is_attitude[k]:
            out.append(AttitudeSample(t, tuple(next(q_attitude)), source))  # type: ignore[arg-type]
        yield t, flight.q_true[k], out


def mavlink_stream(
    flight: Flight,
    system: int = 1,
    component: int = 1,
    imu_message: str = "HIGHRES_IMU",
    attitude_message: str = "ATTITUDE_QUATERNION",
) -> Iterator[tuple[int, Array, bytes]]:
    """Per IMU tick: (true time, true q, MAVLink bytes sent at that tick), PX4-style by default.

    ArduPilot sends ``imu_message="RAW_IMU"`` and ``attitude_message="ATTITUDE"``.
    """
    encoder = MavlinkEncoder(system, component)
    for t, q, tick in samples(flight):
        data = b"".join(
            encoder.encode(s, imu_message if isinstance(s, ImuSample) else attitude_message) for s in tick
        )
        yield t, q, data


def dronecan_stream(flight: Flight, node_id: int = 10) -> Iterator[tuple[int, Array, list[can.Message]]]:
    """Per IMU tick: (true time, true q, CAN frames sent at that tick): RawIMU, MagneticFieldStrength2, Solution."""
    transfer_ids: dict[type, int] = {}
    for t, q, tick in samples(flight):
        frames: list[can.Message] = []
        for s in tick:
            tid = transfer_ids.get(type(s), 0)
            transfer_ids[type(s)] = tid + 1
            frames += encode_dronecan(s, node_id, tid)
        yield t, q, frames


__all__ = ["Flight", "SimConfig", "dronecan_stream", "mavlink_stream", "samples", "simulate"]
