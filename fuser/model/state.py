"""The fusion model's persistent state: one immutable value, read, set and reset as a whole.

After VQF's parameter / state / coefficient split (``VQFParams``,
``VQFState``, ``VQFCoefficients`` in dlaidig/vqf): the parameters are the
frozen :class:`fuser.config.FuserConfig`, the coefficients are derived from
them once (:class:`fuser.model.heading.FieldReference`, the process-noise
table), and everything a tick carries to the next is here. Each update
module owns one part and returns a new one; nothing is changed in place, so
a state read with :attr:`FusionModel.state <fuser.model.FusionModel.state>`
stays valid after further ticks and can be set into another model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from drivers.samples import Vec3
from fuser.config import FuserConfig, MagSettings
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.imu_check import ImuCheckState
from fuser.model_error import ModelErrorState

__all__ = ["AttitudeState", "BiasState", "FieldState", "FilterState", "GnssStream", "GravityState", "GyroState", "GyroTrack",
           "HeadingState", "RestState", "VelocityState", "initial_state"]


@dataclass(frozen=True, slots=True)
class GyroTrack:
    """The vehicle's gyro stream (all its IMUs) on the loop's timeline (:mod:`fuser.model.propagation`)."""

    last_ns: int
    """Time of the last gyro sample (ns, loop timeline)."""
    last_rate_rad_s: Vec3
    """Its raw rate (rad/s, bias not removed): the rate held until the next sample."""
    covered_ns: int
    """The attitude has been carried up to here (the last tick's end)."""
    held_rad: Vec3
    """Raw rotation the hold applied since ``last_ns``: taken back when the next sample closes the interval."""
    interval_s: float | None = None
    """Interval between samples, low-passed over ``gyro.rate_window_s`` (None before the second sample)."""
    saturated: bool = False
    """The last sample was saturated: the rate since it is unknown."""

    def rate_hz(self, now_ns: int) -> float:
        """The stream's measured rate at ``now_ns``: a stream that stops is slow."""
        interval = max(self.interval_s or 0.0, (now_ns - self.last_ns) * 1e-9)
        return 1.0 / interval if interval > 0.0 else math.inf


@dataclass(frozen=True, slots=True)
class GyroState:
    track: GyroTrack | None = None
    """None until the first gyro sample."""
    rate_rad_s: float = 0.0
    """Norm of the last known bias-corrected rate: the bias feedback learns only below its threshold."""
    last_imu_tick_ns: int | None = None
    """The last tick that held IMU samples: the gravity and rest updates count their readings per interval."""


@dataclass(frozen=True, slots=True)
class BiasState:
    """The gyro bias (rad/s, body FRD), a Gaussian beside the attitude (:mod:`fuser.model.bias`)."""

    estimate_rad_s: np.ndarray
    covariance_rad2_s2: np.ndarray
    """3x3 covariance of the estimate's error ((rad/s)^2)."""
    rotation_lp: np.ndarray | None = None
    """The attitude's rotation matrix (body -> world) low-passed for the motion estimate: after the tilt
    correction's first and second stage, and after the heading correction's one (3 x 3 x 3; None until the first
    reading)."""
    rotated_lp_rad_s: np.ndarray | None = None
    """The rotated estimate ``R b`` through the same stages (3 x 3)."""
    tilt_aided: bool = False
    """The tilt correction the stages follow is GNSS-aided (:mod:`fuser.model.velocity`), not the plain one."""
    tilt_settled_s: float = 0.0
    """Seconds the stages have followed that same tilt correction (they start again when it changes)."""

    @property
    def variance_rad2_s2(self) -> float:
        """Mean per-axis variance: the uncertainty the time constants and the process noise scale with."""
        c = self.covariance_rad2_s2  # the diagonal read directly: np.trace's call costs ten times the sum, every tick
        return (float(c[0, 0]) + float(c[1, 1]) + float(c[2, 2])) / 3.0

    def with_covariance(self, covariance_rad2_s2: np.ndarray) -> BiasState:
        return self.with_estimate(self.estimate_rad_s, covariance_rad2_s2)

    def with_estimate(self, estimate_rad_s: np.ndarray, covariance_rad2_s2: np.ndarray) -> BiasState:
        # built directly rather than by dataclasses.replace, which costs microseconds a call on the tick's path
        return BiasState(estimate_rad_s, covariance_rad2_s2, self.rotation_lp, self.rotated_lp_rad_s, self.tilt_aided, self.tilt_settled_s)


@dataclass(frozen=True, slots=True)
class RestState:
    """Rest detector (VQF, rest detection): low-passed gyro and accelerometer, seconds still, and the verdict."""

    gyro_lp_rad_s: np.ndarray | None = None
    accel_lp_m_s2: np.ndarray | None = None
    still_s: float = 0.0
    at_rest: bool = False


@dataclass(frozen=True, slots=True)
class GravityState:
    """The gravity update's memory: the low-passed specific force in the gyro-only strapdown frame."""

    q_strapdown: np.ndarray = field(default_factory=lambda: quat.IDENTITY.copy())
    """Gyro-only attitude (never corrected): the almost-inertial frame of the low-pass (VQF, inclination correction)."""
    accel_lp_m_s2: np.ndarray | None = None
    """Low-passed specific force in that frame."""
    down_body: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    """Last measured direction of down in the body frame: the magnetometer's dip reference."""
    converged: bool = False
    """Once the state has converged the raw accelerometer is not trusted again (until a gyro gap breaks the frame)."""
    tilt_known: bool = False
    """A gravity reading has been fused: the heading may be measured."""
    gated_s: float = 0.0
    """Seconds of continuous gating by innovation (re-anchored after ``updates.reanchor_after_s``)."""
    raw_mean_m_s2: np.ndarray | None = None
    """Mean of the raw readings fused before convergence, in the strapdown frame (None: none since the low-pass was
    last in use or the frame broke): what the estimate has followed, and where the low-pass starts."""
    raw_s: float = 0.0
    """Seconds of raw readings in that mean."""
    measured_body: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    """The last measured specific force's direction, negated (down at rest), in the body frame."""
    gnss_checked: bool = False
    """A raw reading has been compared with the first GNSS acceleration (once: the readings before it were all
    taken for down; after a broken frame the aided update's state is the one to keep)."""
    measured_world: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    """The world direction it was measured as: down without GNSS, gravity minus the GNSS acceleration with it (its
    vertical part taken as zero when the fixes have none). With ``measured_body`` the magnetometer's dip gate
    (:mod:`fuser.model.heading`), which neither may depend on the estimate."""


@dataclass(frozen=True, slots=True)
class UnaidedState:
    """What the accelerometer's norm reveals of an acceleration it cannot tell from gravity (:mod:`fuser.model.unaided`)."""

    excess_m2_s4: float = 0.0
    """The low-passed specific force's signed excess norm ``|f|^2 - g^2``, as far as the estimate has followed it."""
    norm_mean_m_s2: np.ndarray | None = None
    """Long-run mean of the specific force in the strapdown frame: gravity as this sensor reads it, its scale error
    and bias included (None: none yet, or the frame broke)."""
    norm_mean_s: float = 0.0
    """Seconds of readings in that mean."""
    absorbed_rad: tuple[float, float] = (0.0, 0.0)
    """North and east (world frame) of the tilt the plain gravity update's corrections have moved the estimate by,
    summed with a leak: what a false vertical may have put into it (:func:`fuser.model.unaided.absorbed`)."""


@dataclass(frozen=True, slots=True)
class HeadingState:
    gated_s: float = 0.0
    """Seconds of continuous gating by innovation."""
    last_reading_ns: int | None = None
    """Tick of the last magnetometer reading: the heading's correlated error is counted per interval."""


@dataclass(frozen=True, slots=True)
class AttitudeState:
    gated_s: float = 0.0
    """Seconds the autopilot's attitude has been kept out as a jump."""
    last_fused_ns: int | None = None
    """The tick that last fused it."""


FieldSource = Literal["config", "wmm", "fallback"]
DateSource = Literal["config", "gnss", "timeline", "undated"]


@dataclass(frozen=True, slots=True)
class FieldState:
    """The magnetometer's reference field in use and where it came from (:mod:`fuser.model.field`)."""

    field_ned_gauss: tuple[float, float, float]
    source: FieldSource
    position: tuple[float, float, float] | None = None
    """Latitude, longitude (deg) and altitude (m) the WMM was evaluated at (None: not yet)."""
    decimal_year: float | None = None
    date_source: DateSource | None = None
    reported: bool = False
    """Its ``mag_field`` diagnostic has been given."""

    @classmethod
    def of(cls, params: MagSettings) -> FieldState:
        """The configured field, or the fallback until a GNSS position gives the WMM's."""
        if params.field_ned_gauss is not None:
            return cls(params.field_ned_gauss, "config")
        return cls(params.fallback_field_ned_gauss, "fallback")

    def diagnostic(self) -> UpdateDiagnostic:
        """The ``mag_field`` diagnostic: the field, its source (as ``reason``), its declination and where it is from."""
        n, e, d = self.field_ned_gauss
        values: dict[str, Any] = {"field_ned_gauss": [n, e, d], "declination_deg": math.degrees(math.atan2(e, n))}
        if self.position is not None:
            values |= {"lat_deg": self.position[0], "lon_deg": self.position[1], "alt_m": self.position[2],
                       "decimal_year": self.decimal_year, "date_source": self.date_source}
        return UpdateDiagnostic("mag_field", "fused", self.source, values=tuple(values.items()))


@dataclass(frozen=True, slots=True)
class GnssStream:
    """One GNSS stream's last new fix (:mod:`fuser.model.velocity`)."""

    key: tuple
    """(source, filtered): a receiver's fix and an autopilot's solution from one source are two streams."""
    measured_ns: int
    """When its velocity was measured, on the loop's timeline (placed time minus the latency)."""
    vel_ned_m_s: Vec3
    vertical: bool
    """Its down component was measured."""
    noise_m_s: float
    """One-sigma velocity noise per axis."""


@dataclass(frozen=True, slots=True)
class VelocityState:
    """GNSS velocity aiding's memory (:mod:`fuser.model.velocity`)."""

    streams: tuple[GnssStream, ...] = ()
    force_knots: tuple[tuple[int, np.ndarray, np.ndarray], ...] = ()
    """(tick ns, integral of the specific force in the strapdown frame since the first knot (m/s), the tick's mean
    specific force there (m/s^2)): the accelerometer's history, delayed to the GNSS intervals."""
    body_lp_m_s2: np.ndarray | None = None
    """Low-pass of the minus specific force over the GNSS intervals, in the strapdown frame (None: not aiding)."""
    world_lp_m_s2: np.ndarray | None = None
    """The same low-pass of ``g e_z - a`` (NED), ``a`` the GNSS acceleration over the same intervals."""
    vertical: bool = True
    """The last pair's vertical acceleration was measured (else taken as zero in the low-pass)."""
    noise_var_m2_s4: float = 0.0
    """Variance (per axis) of the GNSS velocity noise left in the world low-pass, (m/s^2)^2."""
    noise_cov_m2_s3: float = 0.0
    """Its covariance with the last fix's velocity noise (the next difference shares that fix), m^2/s^3."""
    last_fused_ns: int | None = None
    """The tick that last fused a pair into the low-pass."""
    recent_world_m_s2: np.ndarray | None = None
    """``g e_z - a``, ``a`` the pairs of fixes' mean acceleration (its vertical part zero when the fixes have none)
    low-passed over ``gnss.raw_lowpass_s``, aiding or not: what the gravity update's raw readings measure in the
    world (None: no pair yet)."""
    recent_ns: int | None = None
    """When the newest pair in it was measured (the middle of its interval)."""
    recent_noise_var_m2_s4: float = 0.0
    """Variance (per axis) of the velocity noise left in it, (m/s^2)^2."""
    recent_noise_cov_m2_s3: float = 0.0
    """Its covariance with the last fix's velocity noise, m^2/s^3."""


@dataclass(frozen=True, slots=True)
class FilterState:
    """Everything one tick hands to the next."""

    attitude: Bingham
    """The filter's Bingham over the attitude quaternion (body FRD -> world NED)."""
    bias: BiasState
    gyro: GyroState = GyroState()
    rest: RestState = RestState()
    gravity: GravityState = GravityState()
    heading: HeadingState = HeadingState()
    attitude_source: AttitudeState = AttitudeState()
    imu_check: ImuCheckState = ImuCheckState()
    model_error: ModelErrorState = ModelErrorState()
    velocity: VelocityState = VelocityState()
    field: FieldState = FieldState.of(MagSettings())
    """The reference field (the default settings' until :func:`initial_state` gives the configured one)."""
    unaided: UnaidedState = UnaidedState()
    """An acceleration the unaided accelerometer cannot tell from gravity (:mod:`fuser.model.unaided`)."""


def initial_state(config: FuserConfig) -> FilterState:
    """The start: a uniform attitude (no prior knowledge needed), zero bias with its initial uncertainty, the
    configured reference field (or the fallback until a GNSS position)."""
    return FilterState(attitude=Bingham.uniform(), bias=BiasState(np.zeros(3), config.bias.initial_sigma_rad_s**2 * np.eye(3)),
                       field=FieldState.of(config.mag))
