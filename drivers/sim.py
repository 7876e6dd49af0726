"""Simulated vehicles: true motion and the IMU, magnetometer, attitude and GNSS messages they would send.

Two parts, so that every simulator shares one sensor model:

* a **trajectory** (:class:`Trajectory`): the true attitude, body rate,
  specific force, NED velocity and geodetic position on the IMU time grid.
  :func:`simulate` flies the built-in multirotor below;
  ``drivers.jsbsim_flight`` flies a fixed-wing aircraft in JSBSim.
* :func:`measure`: the sensors of that trajectory (noise, bias, vibration,
  saturation, dropouts, the magnetometer, the autopilot's attitude, GNSS),
  giving a :class:`Flight` that :func:`samples`, :func:`mavlink_stream` and
  :func:`dronecan_stream` turn into what the vehicle sends.

The multirotor flies a fixed 60-s programme, then hovers: hover with wobble
(0-10 s), coordinated turns (10-25 s), aggressive roll/pitch/yaw (25-40 s), a
roll flip (42 s, 0.6 s), hover. Attitude is given by Euler 3-2-1 angles that
are sums of smoothly windowed terms with analytic derivatives, so the true
body rate is exact, not differenced. Translation follows from the forces:
thrust along body -z and a linear rotor drag ``-k v`` on the body-horizontal
velocity (blade flapping and induced drag; k of 0.2-0.6 1/s is typical of
small multirotors), so the specific force is ``(-k u, -k v, -thrust)`` in
body FRD and ``dv_NED/dt = R f + g``. The thrust holds altitude: it makes the
vertical acceleration ``-c v_down`` (the vertical velocity decays at rate c),
and is cut to 0.3 g while more than 60 degrees from upright (the flip). With
``rotor_drag_1_s=0`` and ``vertical_damping_1_s=0`` the specific force is the
earlier model's ``(0, 0, -g / cos tilt)`` exactly. Velocity is integrated at
the IMU rate (explicit Euler: ``v_k+1 = v_k + dt a_k``), position by the
trapezoidal rule, from rest at ``origin`` (flat earth: metres to degrees with
the WGS84 radii of curvature at the origin, exact to centimetres over a few km).

Sensor model per axis (numpy, vectorised): ``meas = (1 + scale) * true +
bias(t) + noise``, the bias a random walk from a random start, vibration
added to the accelerometer, clipped at the sensor range (saturation), and
samples dropped at random (dropouts). The magnetometer reads the earth field
(a fixed NED vector, or the World Magnetic Model's at the trajectory's
position, :mod:`core.earth_field`) rotated into the body, plus noise, at its
own rate. The autopilot's own attitude estimate is the truth times a small
random rotation. GNSS: a fix every ``1/gnss_rate_hz`` s, measured at the fix
time (its ``t_ns``) and sent ``gnss_latency_s`` later (with the first IMU
sample at or after that time); velocity = truth + white noise, position =
truth + a first-order Gauss-Markov error (horizontal sigma, twice that
vertically), as receivers' position errors wander over tens of seconds. An
autopilot's navigation solution (GLOBAL_POSITION_INT) is sent with each fix
too: its EKF predicts to the time it sends, so its velocity is the truth *at
the send time* plus white noise, stamped with that time (no latency).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterator

import numpy as np
from numpy.typing import NDArray

from core import earth_field
from core import quaternion as cq

from .mavlink_encode import MavlinkEncoder
from .samples import AttitudeSample, GnssSample, ImuSample, Sample, SourceId

if TYPE_CHECKING:
    import can

GRAVITY_M_S2 = 9.80665
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
GNSS_FIX_3D = 3
Array = NDArray[np.float64]


MAX_RATE_HZ = 10_000.0
"""The fastest stream the simulator sends (IMU, attitude, magnetometer, GNSS): beyond any IMU a MAVLink link or a
DroneCAN bus carries."""
MAX_IMU_SAMPLES = 2_000_000
"""The most IMU samples in one flight: the simulator lays the whole flight out in memory first, about 1.5 kB a
sample (357 MB for 240,000), so 3 GB; 83 minutes at 400 Hz."""


@dataclass(frozen=True)
class SimConfig:
    """Every knob of the simulation; the defaults resemble a small quadcopter with an ICM-20602-class IMU
    and a u-blox M8-class GNSS receiver. Each field's unit is in its name; checked at construction."""

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
    mag_field_ned_gauss: tuple[float, float, float] | None = None
    """The earth field the magnetometer reads (north, east, down); None (the default): the World Magnetic Model's
    at the flight's position and date, declination included, as a real magnetometer reads it."""
    rotor_drag_1_s: float = 0.35
    """Multirotor: specific force per m/s of body-horizontal velocity (linear rotor drag)."""
    vertical_damping_1_s: float = 1.0
    """Multirotor: rate at which its altitude hold brings the vertical velocity back to zero."""
    gnss: bool = True
    """Whether the vehicle has (and sends) GNSS."""
    gnss_rate_hz: float = 10.0
    gnss_latency_s: float = 0.15
    gnss_vel_noise_m_s: float = 0.1
    """One-sigma white noise per NED axis of the velocity; also the speed accuracy the receiver reports."""
    gnss_pos_noise_m: float = 1.5
    """One-sigma horizontal position error per axis (vertical: twice this)."""
    gnss_pos_correlation_s: float = 60.0
    origin_lat_deg: float = 47.3977
    """Where the flight starts (PX4 SITL's default home, Zurich)."""
    origin_lon_deg: float = 8.5456
    origin_alt_m: float = 488.0
    """Above mean sea level."""
    decimal_year: float = 2026.5
    """Date of the flight (for the WMM field), e.g. 2026.5 = 1 July 2026."""

    def __post_init__(self) -> None:
        positive = ("duration_s", "imu_rate_hz", "attitude_rate_hz", "mag_rate_hz", "vibration_hz", "gyro_range_rad_s",
                    "accel_range_m_s2", "gnss_rate_hz", "gnss_pos_correlation_s")
        non_negative = ("boot_time_s", "gyro_noise_rad_s", "accel_noise_m_s2", "mag_noise_gauss", "gyro_bias_rad_s",
                        "accel_bias_m_s2", "gyro_bias_walk_rad_s_rt_s", "accel_bias_walk_m_s2_rt_s", "scale_error",
                        "vibration_m_s2", "attitude_error_rad", "rotor_drag_1_s", "vertical_damping_1_s", "gnss_latency_s",
                        "gnss_vel_noise_m_s", "gnss_pos_noise_m")
        for name in positive + non_negative:
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0 or (value == 0 and name in positive):
                raise ValueError(f"SimConfig.{name} must be {'positive' if name in positive else 'non-negative'} and finite, got {value}")
        rates = ("imu_rate_hz", "attitude_rate_hz", "mag_rate_hz", "gnss_rate_hz")
        if too_fast := [f"{name} {getattr(self, name):g}" for name in rates if getattr(self, name) > MAX_RATE_HZ]:
            raise ValueError(f"SimConfig: {', '.join(too_fast)} Hz: at most {MAX_RATE_HZ:g} Hz")
        if not 2 <= (samples := self.duration_s * self.imu_rate_hz) <= MAX_IMU_SAMPLES:
            raise ValueError(f"SimConfig: {self.duration_s:g} s at {self.imu_rate_hz:g} Hz is a flight of {samples:.3g} IMU samples: the "
                             f"simulator needs 2 at least, and lays the whole flight out in memory (about 1.5 kB a sample): "
                             f"{MAX_IMU_SAMPLES:,} at most ({MAX_IMU_SAMPLES / 400 / 60:.0f} min at 400 Hz)")
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"SimConfig.seed must be a non-negative integer (numpy's seed), got {self.seed!r}")
        if not 0.0 <= self.dropout_probability < 1.0:
            raise ValueError(f"SimConfig.dropout_probability must be in [0, 1), got {self.dropout_probability}")
        if not -90.0 < self.origin_lat_deg < 90.0 or not -180.0 <= self.origin_lon_deg <= 180.0:
            raise ValueError(f"SimConfig.origin_lat_deg/origin_lon_deg out of range: {self.origin_lat_deg}, {self.origin_lon_deg}")
        if self.mag_field_ned_gauss is None:
            earth_field.field_ned_gauss(self.origin_lat_deg, self.origin_lon_deg, self.origin_alt_m, self.decimal_year)  # raises naming the argument
        elif len(self.mag_field_ned_gauss) != 3 or not all(math.isfinite(v) for v in self.mag_field_ned_gauss):
            raise ValueError(f"SimConfig.mag_field_ned_gauss must be three finite numbers or None, got {self.mag_field_ned_gauss}")


@dataclass(frozen=True)
class Trajectory:
    """True motion on the IMU time grid (N samples, ``t_s`` from 0 at the IMU rate): what :func:`measure` senses."""

    t_s: Array
    q_true: Array
    """(N, 4) body FRD -> world NED, (w, x, y, z)."""
    gyro_true_rad_s: Array
    """(N, 3) body rate FRD, what a perfect gyro reads."""
    accel_true_m_s2: Array
    """(N, 3) specific force FRD (non-gravitational acceleration), what a perfect accelerometer reads."""
    vel_ned_true_m_s: Array
    lat_true_deg: Array
    lon_true_deg: Array
    alt_true_m: Array
    """Above mean sea level."""


@dataclass(frozen=True)
class GnssTrack:
    """The fixes a GNSS receiver sends: fix ``i`` is measured at ``t_ns[i]`` and sent with IMU sample ``index[i]``."""

    index: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    vel_ned_m_s: Array
    lat_deg: Array
    lon_deg: Array
    alt_m: Array
    speed_accuracy_m_s: float
    solution_vel_ned_m_s: Array
    """The autopilot's navigation solution sent with fix ``i``: its velocity at the send time (IMU sample ``index[i]``)."""
    fix_type: int = GNSS_FIX_3D

    def cut(self, first: int, last: int) -> GnssTrack:
        """The fixes sent with IMU samples ``first`` to ``last - 1``, indices renumbered from ``first``."""
        keep = (self.index >= first) & (self.index < last)
        return dataclasses.replace(
            self, index=self.index[keep] - first, t_ns=self.t_ns[keep], vel_ned_m_s=self.vel_ned_m_s[keep],
            lat_deg=self.lat_deg[keep], lon_deg=self.lon_deg[keep], alt_m=self.alt_m[keep],
            solution_vel_ned_m_s=self.solution_vel_ned_m_s[keep],
        )


_PER_SAMPLE = ("t_ns", "q_true", "gyro_true_rad_s", "accel_true_m_s2", "mag_true_gauss", "gyro_rad_s", "accel_m_s2",
               "mag_gauss", "gyro_bias_rad_s", "accel_bias_m_s2", "imu_valid", "vel_ned_true_m_s", "lat_true_deg",
               "lon_true_deg", "alt_true_m")


@dataclass(frozen=True)
class Flight:
    """Truth and measurements on the IMU time grid (N samples); attitude output at ``attitude_index``;
    GNSS fixes in ``gnss`` (None: no receiver)."""

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
    vel_ned_true_m_s: Array
    lat_true_deg: Array
    lon_true_deg: Array
    alt_true_m: Array
    mag_field_ned_gauss: tuple[float, float, float]
    """The earth field (north, east, down, gauss) at the start: the reference a fuser should be given."""
    gnss: GnssTrack | None

    def cut(self, first: int, last: int) -> Flight:
        """IMU samples ``first`` to ``last - 1`` and the messages sent with them."""
        att = (self.attitude_index >= first) & (self.attitude_index < last)
        return dataclasses.replace(
            self,
            **{name: getattr(self, name)[first:last] for name in _PER_SAMPLE},
            attitude_index=self.attitude_index[att] - first,
            q_attitude=self.q_attitude[att],
            gnss=None if self.gnss is None else self.gnss.cut(first, last),
        )


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


def euler_to_quaternion(euler: Array) -> Array:
    """Euler 3-2-1 angles (roll, pitch, yaw), shape (N, 3), as quaternions body FRD -> world NED."""
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


def _multirotor_translation(q: Array, dt: float, drag_1_s: float, damping_1_s: float) -> tuple[Array, Array, Array]:
    """Specific force (body FRD), NED velocity and NED position of the multirotor, integrated from rest.

    Per sample: body velocity ``u, v, w = R^T v_NED``; drag ``f_x = -k u, f_y = -k v``; thrust ``T``
    solves ``(R f)_down = -g - c v_down`` (``T = (g + c v_down + R_20 f_x + R_21 f_y) / R_22``), or
    0.3 g when ``R_22 <= 0.5``; then ``a = R f + (0, 0, g)`` drives ``v`` (Euler) and ``p`` (trapezoid).
    Plain floats: the loop is sequential (the drag feeds back) and numpy's per-call cost would dominate.
    """
    rot = cq.to_matrix(q).tolist()
    n = len(rot)
    f_out = [(0.0, 0.0, 0.0)] * n
    v_out = [(0.0, 0.0, 0.0)] * n
    p_out = [(0.0, 0.0, 0.0)] * n
    vn = ve = vd = pn = pe = pd = 0.0
    g = GRAVITY_M_S2
    for k, ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22)) in enumerate(rot):
        v_out[k] = (vn, ve, vd)
        p_out[k] = (pn, pe, pd)
        fx = -drag_1_s * (r00 * vn + r10 * ve + r20 * vd)
        fy = -drag_1_s * (r01 * vn + r11 * ve + r21 * vd)
        thrust = max(0.0, (g + damping_1_s * vd + r20 * fx + r21 * fy) / r22) if r22 > 0.5 else 0.3 * g
        f_out[k] = (fx, fy, -thrust)
        an = r00 * fx + r01 * fy - r02 * thrust
        ae = r10 * fx + r11 * fy - r12 * thrust
        ad = r20 * fx + r21 * fy - r22 * thrust + g
        nn, ne, nd = vn + dt * an, ve + dt * ae, vd + dt * ad
        pn, pe, pd = pn + 0.5 * dt * (vn + nn), pe + 0.5 * dt * (ve + ne), pd + 0.5 * dt * (vd + nd)
        vn, ve, vd = nn, ne, nd
    return np.array(f_out), np.array(v_out), np.array(p_out)


def _radii_m(lat_deg: float) -> tuple[float, float]:
    """WGS84 meridian and prime-vertical radii of curvature at a latitude."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    w = math.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w


def ned_to_geodetic(lat_deg: float, lon_deg: float, alt_m: float, ned_m: Array) -> tuple[Array, Array, Array]:
    """Latitude, longitude (degrees) and altitude (m) of NED offsets (metres, shape (N, 3)) from a point (flat earth)."""
    meridian, normal = _radii_m(lat_deg)
    ned_m = np.asarray(ned_m, dtype=float)
    lat = lat_deg + np.degrees(ned_m[:, 0] / (meridian + alt_m))
    lon = lon_deg + np.degrees(ned_m[:, 1] / ((normal + alt_m) * math.cos(math.radians(lat_deg))))
    return lat, lon, alt_m - ned_m[:, 2]


def _sensor(
    rng: np.random.Generator, true: Array, dt: float, noise: float, bias0: float, walk: float, scale: float, limit: float
) -> tuple[Array, Array]:
    """Measured values and the bias time line of one 3-axis sensor."""
    n = len(true)
    bias = bias0 * rng.standard_normal(3) + np.cumsum(walk * np.sqrt(dt) * rng.standard_normal((n, 3)), axis=0)
    meas = (1.0 + scale * rng.standard_normal(3)) * true + bias + noise * rng.standard_normal((n, 3))
    return np.clip(meas, -limit, limit), bias


def _earth_field_ned(config: SimConfig, traj: Trajectory) -> Array:
    """(N, 3) earth field along the trajectory: the configured constant, or the WMM's (at 1-s spacing, interpolated)."""
    n = len(traj.t_s)
    if config.mag_field_ned_gauss is not None:
        return np.broadcast_to(np.asarray(config.mag_field_ned_gauss, dtype=float), (n, 3))
    knots = np.unique(np.append(np.searchsorted(traj.t_s, np.arange(0.0, traj.t_s[-1], 1.0)), n - 1))
    at_knots = np.array([
        earth_field.field_ned_gauss(float(traj.lat_true_deg[i]), float(traj.lon_true_deg[i]), float(traj.alt_true_m[i]), config.decimal_year)
        for i in knots
    ])
    return np.column_stack([np.interp(traj.t_s, traj.t_s[knots], at_knots[:, j]) for j in range(3)])


def _gnss(config: SimConfig, rng: np.random.Generator, t_ns: NDArray[np.int64], traj: Trajectory) -> GnssTrack:
    """Fixes at ``gnss_rate_hz`` on the IMU grid, each sent ``gnss_latency_s`` after it was measured."""
    n = len(t_ns)
    step = max(1, round(config.imu_rate_hz / config.gnss_rate_hz))
    fix = np.arange(0, n, step)
    send = np.searchsorted(t_ns, t_ns[fix] + round(config.gnss_latency_s * 1e9))
    fix, send = fix[send < n], send[send < n]
    m = len(fix)
    vel = traj.vel_ned_true_m_s[fix] + config.gnss_vel_noise_m_s * rng.standard_normal((m, 3))
    white = config.gnss_pos_noise_m * np.array([1.0, 1.0, 2.0]) * rng.standard_normal((m, 3))
    a = math.exp(-step / config.imu_rate_hz / config.gnss_pos_correlation_s)
    err = np.empty_like(white)
    for i in range(m):  # first-order Gauss-Markov, stationary from the first fix
        err[i] = white[i] if i == 0 else a * err[i - 1] + math.sqrt(1.0 - a * a) * white[i]
    lat, lon, alt = traj.lat_true_deg[fix].copy(), traj.lon_true_deg[fix].copy(), traj.alt_true_m[fix].copy()
    for i in range(m):
        la, lo, al = ned_to_geodetic(float(lat[i]), float(lon[i]), float(alt[i]), err[i : i + 1])
        lat[i], lon[i], alt[i] = la[0], lo[0], al[0]
    solution = traj.vel_ned_true_m_s[send] + config.gnss_vel_noise_m_s * rng.standard_normal((m, 3))
    return GnssTrack(
        index=send.astype(np.int64), t_ns=(t_ns[fix] // 1000) * 1000, vel_ned_m_s=vel,
        lat_deg=lat, lon_deg=lon, alt_m=alt, speed_accuracy_m_s=config.gnss_vel_noise_m_s, solution_vel_ned_m_s=solution,
    )


def measure(config: SimConfig, traj: Trajectory) -> Flight:
    """What the vehicle's sensors read along ``traj`` under ``config``; deterministic for a given seed."""
    rng = np.random.default_rng(config.seed)
    n = len(traj.t_s)
    dt = 1.0 / config.imu_rate_hz
    t = traj.t_s
    t_ns = (round(config.boot_time_s * 1e9) + np.round(t * 1e9)).astype(np.int64)
    q = traj.q_true
    field = _earth_field_ned(config, traj)
    mag_true = cq.rotate(cq.conjugate(q), field)

    gyro, gyro_bias = _sensor(
        rng, traj.gyro_true_rad_s, dt, config.gyro_noise_rad_s, config.gyro_bias_rad_s,
        config.gyro_bias_walk_rad_s_rt_s, config.scale_error, config.gyro_range_rad_s,
    )
    vibration = config.vibration_m_s2 * np.sin(2 * np.pi * config.vibration_hz * t[:, None] + rng.uniform(0, 2 * np.pi, 3))
    accel, accel_bias = _sensor(
        rng, traj.accel_true_m_s2 + vibration, dt, config.accel_noise_m_s2, config.accel_bias_m_s2,
        config.accel_bias_walk_m_s2_rt_s, config.scale_error, config.accel_range_m_s2,
    )
    mag = mag_true + config.mag_noise_gauss * rng.standard_normal((n, 3))
    mag_every = max(1, round(config.imu_rate_hz / config.mag_rate_hz))
    mag[np.arange(n) % mag_every != 0] = np.nan

    attitude_index = np.arange(0, n, max(1, round(config.imu_rate_hz / config.attitude_rate_hz)))
    error = cq.from_rotvec(config.attitude_error_rad * rng.standard_normal((len(attitude_index), 3)))
    imu_valid = rng.random(n) >= config.dropout_probability
    return Flight(
        t_ns=t_ns,
        q_true=q,
        gyro_true_rad_s=traj.gyro_true_rad_s,
        accel_true_m_s2=traj.accel_true_m_s2,
        mag_true_gauss=mag_true,
        gyro_rad_s=gyro,
        accel_m_s2=accel,
        mag_gauss=mag,
        gyro_bias_rad_s=gyro_bias,
        accel_bias_m_s2=accel_bias,
        imu_valid=imu_valid,
        attitude_index=attitude_index,
        q_attitude=cq.multiply(q[attitude_index], error),
        vel_ned_true_m_s=traj.vel_ned_true_m_s,
        lat_true_deg=traj.lat_true_deg,
        lon_true_deg=traj.lon_true_deg,
        alt_true_m=traj.alt_true_m,
        mag_field_ned_gauss=tuple(float(v) for v in field[0]),  # type: ignore[arg-type]
        gnss=_gnss(config, rng, t_ns, traj) if config.gnss else None,
    )


def multirotor_trajectory(config: SimConfig = SimConfig()) -> Trajectory:
    """The multirotor's programme (module docstring) for ``config.duration_s`` at ``config.imu_rate_hz``."""
    n = int(round(config.duration_s * config.imu_rate_hz))
    dt = 1.0 / config.imu_rate_hz
    t = np.arange(n) * dt
    euler, euler_rates = euler_programme(t)
    q = euler_to_quaternion(euler)
    accel, vel, pos = _multirotor_translation(q, dt, config.rotor_drag_1_s, config.vertical_damping_1_s)
    lat, lon, alt = ned_to_geodetic(config.origin_lat_deg, config.origin_lon_deg, config.origin_alt_m, pos)
    return Trajectory(t, q, _body_rates(euler, euler_rates), accel, vel, lat, lon, alt)


def simulate(config: SimConfig = SimConfig()) -> Flight:
    """Fly the multirotor programme under ``config``; deterministic for a given seed."""
    return measure(config, multirotor_trajectory(config))


SIM_SOURCE = SourceId("sim", 1, 1, 0)


def _gnss_samples(flight: Flight, source: SourceId, solution: bool) -> dict[int, list[GnssSample]]:
    """The GNSS samples sent with each IMU index: the receiver's fixes, or the autopilot's navigation solutions
    (``solution``: stamped at the send time, no speed accuracy, ``filtered``)."""
    out: dict[int, list[GnssSample]] = {}
    g = flight.gnss
    if g is None:
        return out
    t_send = flight.t_ns[g.index]
    vel = g.solution_vel_ned_m_s if solution else g.vel_ned_m_s
    times = ((t_send // 1000) * 1000 if solution else g.t_ns).tolist()
    accuracy = None if solution else g.speed_accuracy_m_s
    for k, t, v, lat, lon, alt in zip(g.index.tolist(), times, vel.tolist(), g.lat_deg.tolist(), g.lon_deg.tolist(), g.alt_m.tolist()):
        out.setdefault(k, []).append(GnssSample(t, g.fix_type, tuple(v), True, accuracy, lat, lon, alt, solution, source))  # type: ignore[arg-type]
    return out


def samples(flight: Flight, source: SourceId = SIM_SOURCE, gnss_solution: bool = False) -> Iterator[tuple[int, Array, list[Sample]]]:
    """Per IMU tick: (true time ns, true q_wxyz, the samples the vehicle emits at that tick): IMU, attitude, GNSS
    (the receiver's fixes, or with ``gnss_solution`` the autopilot's navigation solutions)."""
    is_attitude = np.zeros(len(flight.t_ns), dtype=bool)
    is_attitude[flight.attitude_index] = True
    q_attitude = iter(flight.q_attitude.tolist())
    gnss = _gnss_samples(flight, source, gnss_solution)
    t_all, gyro, accel, mag = (a.tolist() for a in (flight.t_ns, flight.gyro_rad_s, flight.accel_m_s2, flight.mag_gauss))
    for k, t in enumerate(t_all):
        out: list[Sample] = []
        if flight.imu_valid[k]:
            m = mag[k]
            out.append(ImuSample(t, tuple(gyro[k]), tuple(accel[k]), None if m[0] != m[0] else tuple(m), source))  # type: ignore[arg-type]
        if is_attitude[k]:
            out.append(AttitudeSample(t, tuple(next(q_attitude)), source))  # type: ignore[arg-type]
        out += gnss.get(k, ())
        yield t, flight.q_true[k], out


def mavlink_stream(
    flight: Flight,
    system: int = 1,
    component: int = 1,
    imu_message: str = "HIGHRES_IMU",
    attitude_message: str = "ATTITUDE_QUATERNION",
    gnss_message: str = "GPS_RAW_INT",
) -> Iterator[tuple[int, Array, bytes]]:
    """Per IMU tick: (true time, true q, MAVLink bytes sent at that tick), PX4-style by default.

    ArduPilot sends ``imu_message="RAW_IMU"`` and ``attitude_message="ATTITUDE"``. GNSS goes as the
    receiver's GPS_RAW_INT (ground speed and course, no vertical velocity), GPS_INPUT or HIL_GPS (NED
    velocity), or, with ``gnss_message="GLOBAL_POSITION_INT"``, as the autopilot's navigation solution.
    """
    encoder = MavlinkEncoder(system, component)
    message = {ImuSample: imu_message, AttitudeSample: attitude_message, GnssSample: gnss_message}
    for t, q, tick in samples(flight, gnss_solution=gnss_message == "GLOBAL_POSITION_INT"):
        yield t, q, b"".join(encoder.encode(s, message[type(s)]) for s in tick)


def dronecan_stream(flight: Flight, node_id: int = 10) -> Iterator[tuple[int, Array, list[can.Message]]]:
    """Per IMU tick: (true time, true q, CAN frames sent at that tick): RawIMU, MagneticFieldStrength2, Solution,
    and the receiver's fixes as uavcan.equipment.gnss.Fix2 (NED velocity, its speed accuracy as the velocity
    covariance, stamped with the fix time on the node's time base)."""
    from .dronecan_encode import encode_dronecan  # here: importing dronecan parses its DSDL (a third of a second)

    transfer_ids: dict[type, int] = {}
    for t, q, tick in samples(flight):
        frames: list[can.Message] = []
        for s in tick:
            tid = transfer_ids.get(type(s), 0)
            transfer_ids[type(s)] = tid + 1
            frames += encode_dronecan(s, node_id, tid)
        yield t, q, frames


__all__ = [
    "Flight", "GnssTrack", "SimConfig", "Trajectory", "dronecan_stream", "euler_to_quaternion", "mavlink_stream",
    "measure", "multirotor_trajectory", "ned_to_geodetic", "samples", "simulate",
]
