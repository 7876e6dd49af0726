"""The fuser's configuration: general settings plus one frozen, validated dataclass per group.

Layout (after PX4 EKF2's grouped ``struct parameters`` in ``EKF/common.h`` and
VQF's ``VQFParams``, whose features are switched by booleans, never by a 0
that means "off"):

* ``[fuser]``: general settings (``vehicle``, ``rate_hz``, ``latency_ms``, ``record``);
* ``[fuser.<group>]``: one table per group (:class:`GyroSettings` as ``gyro``,
  :class:`BiasSettings` as ``bias``, ...), one field of :class:`FuserConfig` each.

Every name carries its unit. Each group validates its values when it is
constructed (types, ranges), whether it comes from a file or from code, and
every error names the key, e.g. ``fuser.accel.lowpass_s must be >= 0.001 s,
got 0``. The loader is generic: a new group is one more field of
:class:`FuserConfig` whose default is a frozen dataclass; :class:`Settings`
and :data:`Range` give it the same validation.

Ranges are closed wherever the arithmetic needs it, and wide enough for any
real sensor or vehicle (``tests/test_config_extremes.py`` replays a flight at
both ends of each): durations and time constants 1 ms to a day (:data:`Seconds`),
one-sigma angles 0.001-180 deg (:data:`Sigma`; a raw reading's direction
noise 1e-5 to pi rad), gates at least one sigma (:data:`GateSigmas`), the
loop 1 Hz to :data:`MAX_RATE_HZ`, waits and delays up to :data:`MAX_WAIT_MS`
and 1 s. Noise densities and walks stop at 1 rad/s/sqrt(Hz), 100 rad/s/sqrt(s)
(the rate's walk) and 1 rad/s/sqrt(s) (the bias's), a gap's assumed rate at
100 rad/s and the bias's sigmas at 1 rad/s: far beyond any gyro (a MEMS
gyro's noise is about 3e-4, its bias below 0.05 rad/s), where the squared
concentrations still fit a float. Before, a sigma of 1e-300 or a noise of
1e300 divided by zero inside the compiled tick, a loop of 1e9 Hz asked for
51 GiB and a model error of 1e300 deg made every estimate NaN.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from drivers.link import LinkSettings
from drivers.validation import MAG_MAX_GAUSS, MAG_MIN_FIELD_GAUSS
from fuser.mavlink_out import MavlinkOutSettings
from fuser.ros2 import Ros2Settings

__all__ = [
    "AccelSettings",
    "AttitudeSettings",
    "BiasSettings",
    "ExtrapolationSettings",
    "FuserConfig",
    "GnssSettings",
    "GyroSettings",
    "ImuCheckSettings",
    "LatencySettings",
    "MagSettings",
    "ModelErrorSettings",
    "Range",
    "RestSettings",
    "Settings",
    "UpdateSettings",
    "ZenohSettings",
    "load_config",
]


@dataclass(frozen=True)
class Range:
    """Bounds of a numeric setting (``Annotated[float, Range(gt=0, unit="s")]``) and its unit for messages."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    unit: str = ""

    def violation(self, value: float) -> str | None:
        """The bound ``value`` breaks, as text (``"> 0 s"``), or None."""
        unit = f" {self.unit}" if self.unit else ""
        for bound, op, ok in ((self.gt, ">", lambda b: value > b), (self.ge, ">=", lambda b: value >= b),
                              (self.lt, "<", lambda b: value < b), (self.le, "<=", lambda b: value <= b)):
            if bound is not None and not ok(bound):
                return f"{op} {bound:g}{unit}"
        return None


def _check(key: str, hint: Any, value: Any) -> Any:
    """``value`` checked against the type hint ``hint`` (and its :class:`Range`), converted where the
    type says so (int -> float, list -> tuple); a ValueError naming ``key`` otherwise."""
    bounds = None
    if typing.get_origin(hint) is Annotated:
        hint, *extra = typing.get_args(hint)
        bounds = next((e for e in extra if isinstance(e, Range)), None)
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    given = value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _check(key, Annotated[inner, bounds] if bounds else inner, value)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{key} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{key} must be a finite number, got {value!r}")
        value = float(value)
    elif hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{key} must be an integer, got {value!r}")
    elif hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{key} must be true or false, got {value!r}")
    elif hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{key} must be a string, got {value!r}")
    elif origin is Literal:
        if value not in args:
            raise ValueError(f"{key} must be one of {', '.join(map(repr, args))}, got {value!r}")
    elif origin is tuple:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise ValueError(f"{key} must be a list, got {value!r}")
        items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
        if len(items) != len(value):
            raise ValueError(f"{key} must be a list of {len(items)} values, got {list(value)!r}")
        return tuple(_check(f"{key}[{i}]", Annotated[t, bounds] if bounds else t, v) for i, (t, v) in enumerate(zip(items, value)))
    else:
        raise TypeError(f"{key}: unsupported setting type {hint!r}")
    if bounds is not None and (broken := bounds.violation(value)) is not None:
        raise ValueError(f"{key} must be {broken}, got {given!r}")
    return value


@cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


class Settings:
    """Base of every settings group: validates each field against its type hint when constructed.

    A group is ``@dataclass(frozen=True)``, sets ``section`` (its key in the
    file, e.g. ``"fuser.accel"``), annotates each field with its type and,
    for numbers, a :class:`Range`; cross-field rules go in :meth:`_validate`.
    """

    section: ClassVar[str]

    def __post_init__(self) -> None:
        hints = _hints(type(self))
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value, hint = getattr(self, f.name), hints[f.name]
            if isinstance(hint, type) and dataclasses.is_dataclass(hint):
                if type(value) is not hint:  # a nested group validates itself
                    raise ValueError(f"{self.section}.{f.name} must be a {hint.__name__} ([{self.section}.{f.name}]), got {value!r}")
                continue
            checked = _check(f"{self.section}.{f.name}", hint, value)
            if checked is not value:
                object.__setattr__(self, f.name, checked)
        self._validate()

    def _validate(self) -> None:
        """Rules between fields (override)."""


Seconds = Annotated[float, Range(ge=1e-3, le=86_400, unit="s")]
"""A time constant or duration: from a millisecond (a tick of the fastest loop, :data:`MAX_RATE_HZ`) to a day (longer
than any flight: "never" for a flight), so that every rate, exponential and nanosecond count made of it stays finite."""
Sigma = Annotated[float, Range(ge=1e-3, le=180, unit="deg")]
"""A one-sigma angle: from a thousandth of a degree (finer than any attitude sensor; below it the squared
concentrations overflow) to 180 deg (beyond it an angle says nothing: a uniform attitude)."""
GateSigmas = Annotated[float, Range(ge=1)]
"""An innovation gate in sigmas: below one it would refuse a third of the readings of a sensor as good as configured."""
MAX_RATE_HZ = 2000.0
"""The fastest loop: twice the fastest IMU stream a MAVLink link or a DroneCAN bus carries (1 kHz); a faster loop
gains nothing and its tick history (:func:`fuser.model.state.knot_capacity`) grows with the rate."""
MAX_CONFIG_BYTES = 1024 * 1024
"""The largest settings file read: a full one is about 5 kB (``--config /dev/zero`` read until memory ran out)."""
MAX_WAIT_MS = 10_000.0
"""The longest a tick may wait for samples in flight: beyond it an estimate is too late for any consumer."""


@dataclass(frozen=True)
class GyroSettings(Settings):
    """The rate gyro and the prediction (process noise) it drives."""

    section: ClassVar[str] = "fuser.gyro"

    noise_rad_s_rt_hz: Annotated[float, Range(ge=0, le=1, unit="rad/s/sqrt(Hz)")] = 3e-4
    """White-noise density of the rate."""
    scale_error_fraction: Annotated[float, Range(ge=0, lt=1)] = 0.01
    """Relative scale and misalignment error: process noise proportional to the rotation rate."""
    gap_rate_rad_s: Annotated[float, Range(ge=0, le=100, unit="rad/s")] = 1.0
    """Assumed rotation rate while no gyro data arrives: how fast the uncertainty grows in a gap."""
    max_interval_s: Seconds = 0.6
    """Longest interval between two gyro samples that is integrated, and the longest the last rate is held
    after a sample; longer ones are gaps. 0.6 s integrates a telemetry link's 2 Hz."""
    rate_window_s: Seconds = 1.0
    """Time constant over which the IMU stream is measured: its sample interval, low-passed (``attitude.mode =
    "auto"`` fuses the autopilot's attitude while it is slow), and the rate walk its samples show, released
    (:mod:`fuser.model.propagation`)."""
    smooth_interval_s: Seconds = 0.03
    """A gyro stream whose sample interval (low-passed over ``rate_window_s``) is up to this long is sampled finely
    enough that the rate's path between two samples is the one they show (an IMU's filters and the vehicle's
    inertia leave no turn unseen at 50 Hz, jitter and all, or faster); a slower one counts the rate walk its samples
    show when it exceeds ``rate_walk_rad_s_rt_s`` (:mod:`fuser.model.propagation`)."""
    rate_walk_rad_s_rt_s: Annotated[float, Range(ge=0, le=100, unit="rad/s/sqrt(s)")] = 0.3
    """How fast the true rate may depart from the last sample (a random walk of the rate): the error of the
    rate between samples, ``s^2 h^3 / 12`` interpolated over an interval ``h``, ``s^2 h^3 / 3`` held for ``h``."""
    min_process_variance_rad2: Annotated[float, Range(gt=0, unit="rad^2")] = 1e-18
    """Floor of the per-tick process variance: caps the noise concentration (2e18) of a zero-length tick."""
    range_rad_s: Annotated[float, Range(gt=0, unit="rad/s")] = 34.9
    """Measuring range of the gyro (2000 deg/s, the usual MEMS maximum)."""
    saturation_fraction: Annotated[float, Range(gt=0, le=1)] = 0.98
    """A sample with any axis at or beyond this fraction of ``range_rad_s`` is saturated: its rate is unknown
    (the true one may be anything beyond the range, or the sensor has failed), so the attitude is not turned
    by it and its uncertainty grows at ``range_rad_s`` while it lasts."""


@dataclass(frozen=True)
class ImuCheckSettings(Settings):
    """Cross-checks between the vehicle's IMUs: one that disagrees with the others is kept out."""

    section: ClassVar[str] = "fuser.imu_check"

    enabled: bool = True
    """Compare each IMU sample with the other IMUs' latest (``compare_within_s``) and keep out those that disagree."""
    disagree_rad_s: Annotated[float, Range(gt=0, unit="rad/s")] = 1.0
    """Rates further apart than this (plus ``angular_accel_rad_s2`` times their time difference) disagree;
    IMUs on one board differ by their biases and vibration, a few hundredths of a rad/s."""
    disagree_m_s2: Annotated[float, Range(gt=0, unit="m/s^2")] = 8.0
    """Specific forces further apart than this disagree (vibration differs between IMUs by a few m/s^2)."""
    angular_accel_rad_s2: Annotated[float, Range(ge=0, unit="rad/s^2")] = 200.0
    """How fast the rate may change between two IMUs' samples: a flip reaches 100 rad/s^2."""
    compare_within_s: Seconds = 0.05
    """Only samples this close in time are compared (slower IMUs are not cross-checked)."""
    roughness_s: Seconds = 0.5
    """Time constant of each IMU's roughness (its squared sample-to-sample change of rate, low-passed): of two
    IMUs that disagree, the rougher is the one kept out."""
    frozen_samples: Annotated[int, Range(gt=1, le=1_000_000)] = 50
    """A gyro axis that repeats its value exactly this many samples in a row, while another IMU of the vehicle's
    same axis does not, is frozen: that IMU is kept out until it moves again. A working MEMS gyro's noise moves
    its reading by a least step or more most samples: quantised to 1 mrad/s (MAVLink SCALED_IMU) at rest, where a
    repeat may be as likely as 0.6, 50 repeats happen once in 10^11 samples. PX4's sensor voting flags a sensor
    whose data stays unchanged for 100 samples as stale (``DataValidator``); at 200 Hz 50 is 0.25 s of a stuck
    axis averaged in."""
    fault_sigma_deg: Annotated[float, Range(ge=0, le=180, unit="deg")] = 3.0
    """While an IMU is kept out (and ``compare_within_s`` after), the estimate rests on fewer IMUs than the
    vehicle has: the published one is widened by this much, per axis."""


@dataclass(frozen=True)
class BiasSettings(Settings):
    """The gyro bias: a Gaussian beside the Bingham, measured at rest (:class:`RestSettings`) and learnt in motion
    from the tilt and heading corrections (VQF's motion bias estimation, :mod:`fuser.model.bias`); its uncertainty
    enters the process noise as a correlated error."""

    section: ClassVar[str] = "fuser.bias"

    initial_sigma_rad_s: Annotated[float, Range(gt=0, le=1, unit="rad/s")] = 0.015
    """Uncertainty of the bias before it has been learnt (one sigma, per axis); also its ceiling."""
    floor_sigma_rad_s: Annotated[float, Range(ge=0, le=1, unit="rad/s")] = 0.003
    """The least uncertainty learning in motion brings the estimate to (one sigma, per axis): the corrections also
    carry the slowly varying errors of what they follow, which their noise model counts as white; a bias measured
    better at rest keeps its own."""
    walk_rad_s_rt_s: Annotated[float, Range(ge=0, le=1, unit="rad/s/sqrt(s)")] = 1e-4
    """Random walk of the bias (temperature, instability): a bias learnt at rest is not trusted for ever."""
    feedback_enabled: bool = True
    """Learn the bias in motion: from the plain tilt and the heading corrections (VQF's motion bias estimation), by
    integral feedback while GNSS aids the tilt or the autopilot's attitude is in use (:mod:`fuser.model.bias`)."""
    time_constant_s: Seconds = 5.0
    """Time constant of the integral feedback (GNSS aiding, the autopilot's attitude), and the correlation time of
    the residual bias in the process noise while it is learnt in motion (an error held for this long turns the
    attitude by itself times this)."""
    correlation_without_feedback_s: Seconds = 10.0
    """Correlation time of the residual bias in the process noise while it is not learnt in motion."""
    learn_max_rate_rad_s: Annotated[float, Range(gt=0, unit="rad/s")] = 0.2
    """The integral feedback (GNSS aiding, the autopilot's attitude) learns only in ticks rotating slower than this."""
    learn_max_uncertainty_deg: Annotated[float, Range(gt=0, unit="deg")] = 5.0
    """Learn in motion only when the prediction was this sure: a guess (uniform start, after a gap) is not drift."""
    max_abs_rad_s: Annotated[float, Range(gt=0, unit="rad/s")] = 0.2
    """Clamp of each axis of the estimate: beyond any MEMS gyro's bias, stops a wrong start from running away."""
    min_variance_rad2_s2: Annotated[float, Range(gt=0, unit="(rad/s)^2")] = 1e-18
    """Floor of the bias variance where a time constant divides by its square root."""

    def _validate(self) -> None:
        if self.floor_sigma_rad_s > self.initial_sigma_rad_s:
            raise ValueError(f"{self.section}.floor_sigma_rad_s must be <= initial_sigma_rad_s "
                             f"({self.initial_sigma_rad_s:g} rad/s), got {self.floor_sigma_rad_s!r}")


@dataclass(frozen=True)
class RestSettings(Settings):
    """Rest detection and the bias measured at rest (VQF's rest detection: restMinT, restFilterTau, restThGyr,
    restThAcc, biasSigmaRest)."""

    section: ClassVar[str] = "fuser.rest"

    enabled: bool = True
    """Detect rest and measure the gyro bias directly from the low-passed gyro while at rest."""
    min_s: Seconds = 1.5
    """At rest once gyro and accelerometer have stayed within their thresholds this long."""
    filter_s: Seconds = 0.5
    """Time constant of the detector's low-pass filters."""
    gyro_rad_s: Annotated[float, Range(gt=0, unit="rad/s")] = 0.035
    """Threshold on the gyro's deviation from its low-pass, and on the low-passed rate itself, so that a
    slow steady turn is not taken for a bias (VQF's restThGyr and biasClip, 2 deg/s)."""
    accel_m_s2: Annotated[float, Range(gt=0, unit="m/s^2")] = 0.5
    """Threshold on the accelerometer's deviation from its low-pass."""
    bias_sigma_rad_s: Annotated[float, Range(gt=0, unit="rad/s")] = 5e-4
    """Noise of the low-passed gyro as a measurement of the bias (0.03 deg/s)."""


@dataclass(frozen=True)
class AccelSettings(Settings):
    """The accelerometer as a gravity-direction measurement (the gravity update)."""

    section: ClassVar[str] = "fuser.accel"

    sigma_rad: Annotated[float, Range(ge=1e-5, le=math.pi, unit="rad")] = 0.1
    """Direction noise of a raw reading, used until the state has first converged (a fast start)."""
    lowpass_s: Seconds = 3.0
    """Longest time constant of the low-pass in the gyro-predicted inertial frame, which is also the tilt
    correction's once converged (VQF's tauAcc); reached once the bias is known (``tilt_bias_error_deg``)."""
    tilt_bias_error_deg: Sigma = 0.5
    """Tilt error a residual bias may build up within one correction time constant: the time constant is
    ``tilt_bias_error / bias sigma``, capped at ``lowpass_s`` (fast while the bias is unknown)."""
    lowpass_error_deg: Sigma = 0.5
    """Error of the low-passed down the plain tilt correction follows (the linear acceleration its low-pass leaves),
    correlated over the tilt time constant: the sigma its innovation gate allows once converged (with the state's
    doubt), and the noise of the tilt correction as a measurement of the bias (:mod:`fuser.model.bias`; this was
    ``bias.motion_tilt_noise_deg``)."""
    norm_gate_fraction: Annotated[float, Range(gt=0)] = 0.2
    """Gate when | |f| - g | / g of the low-passed specific force exceeds this (manoeuvres, impacts)."""
    gravity_m_s2: Annotated[float, Range(gt=0, unit="m/s^2")] = 9.80665
    """Local gravity: the norm the gate expects."""
    unaided_norm_tolerance_fraction: Annotated[float, Range(ge=0)] = 0.03
    """Without GNSS velocity, the low-passed specific force's norm beyond ``g (1 + this)`` is read as a horizontal
    acceleration the filter cannot see, and the published tilt widened by its angle (:mod:`fuser.model.unaided`),
    until the sensor's own norm is learnt."""
    unaided_learnt_tolerance_fraction: Annotated[float, Range(ge=0)] = 0.005
    """Once it is: beyond the learnt norm times ``1 + this`` (its change with the orientation, from the axes'
    different scale errors, and with temperature)."""
    unaided_norm_window_s: Seconds = 60.0
    """The sensor's norm is learnt as the norm of the specific force's mean in the strapdown frame over this long
    (a growing window until then): the vehicle's acceleration averages out of it, as its velocity is bounded."""
    unaided_speed_change_m_s: Annotated[float, Range(ge=0, unit="m/s")] = 1.0
    """Vertical speed the vehicle may have gained over that window: its mean acceleration ``dv / T`` biases the
    learnt ``|f|^2`` by up to ``2 g dv / T``, which the tolerance keeps until the window is long enough."""
    unaided_memory_time_constants: Annotated[float, Range(gt=0)] = 2.0
    """The tilt the plain update's corrections have moved the estimate by is remembered with a leak of this many tilt
    time constants (:func:`fuser.model.unaided.absorbed`): an error taken from a false vertical rises and decays over
    one each, and a bias residue of ``b`` reads as ``b`` times the memory."""


@dataclass(frozen=True)
class MagSettings(Settings):
    """The magnetometer as a yaw-only heading measurement (the heading update)."""

    section: ClassVar[str] = "fuser.mag"

    enabled: bool = True
    """Fuse magnetometer headings (false: 6-D fusion, heading from the gyro only)."""
    field_ned_gauss: tuple[float, float, float] | None = None
    """The earth field (north, east, down, gauss; north is true north, so the east component carries the
    declination): the heading reference and the norm and dip gates'. A configured field always wins
    (``field_source`` ``"config"``). None, the default, means *not configured*: the World Magnetic Model's
    field at the first GNSS fix with a position (``"wmm"``; :mod:`fuser.model.field`), and until such a
    fix (or without GNSS) ``fallback_field_ned_gauss`` (``"fallback"``)."""
    fallback_field_ned_gauss: tuple[float, float, float] = (0.21, 0.0, 0.43)
    """The reference while no field is configured and no GNSS position is known: a mid-latitude field
    without declination (central Europe's norm and dip), so the heading is then magnetic, not true."""
    wmm_decimal_year: Annotated[float, Range(ge=2010, lt=2030, unit="year")] | None = None
    """Date at which the WMM is evaluated. None: the GNSS fix's own time when it is a Unix time, else the
    loop's timeline when that is one (the host's clock live, a log's receive times in replay), else
    ``wmm_undated_decimal_year`` (a simulated flight on its own clock, ``sim --speed 0``)."""
    wmm_undated_decimal_year: Annotated[float, Range(ge=2010, lt=2030, unit="year")] = 2026.5
    """The WMM's date when no time in the input is a Unix time (the declination moves about 0.1 deg a year)."""
    sigma_rad: Annotated[float, Range(ge=1e-5, le=math.pi, unit="rad")] = 0.3
    """Heading noise per tick until the state has converged, and the least sigma the innovation gate assumes."""
    error_deg: Sigma = 2.0
    """Heading error of the magnetometer once converged (one sigma): local distortion along the path, tilt
    error through the dip. Correlated over ``correlation_s``, so the per-tick sigma is
    ``error sqrt(correlation_s / dt)``: counted once per correlation time. Measured on BROAD 16: the
    magnetometer's heading sits 1-3 deg off the truth for 10-30 s at a time."""
    correlation_s: Seconds = 10.0
    """Correlation time of the heading error (see ``error_deg``)."""
    heading_bias_error_deg: Sigma = 1.5
    """Heading error a residual gyro bias may build up within one heading-correction time constant, as
    ``accel.tilt_bias_error_deg`` for the tilt: an unlearnt bias cannot drag the heading away."""
    norm_gate_fraction: Annotated[float, Range(gt=0)] = 0.1
    """Gate when the field's norm departs from the expected one by this fraction."""
    dip_gate_deg: Annotated[float, Range(gt=0, unit="deg")] = 10.0
    """Gate when the field's dip (against the measured gravity) departs from the expected one by this much."""

    def _validate(self) -> None:
        for key in ("field_ned_gauss", "fallback_field_ned_gauss"):
            value = getattr(self, key)
            if value is not None and not MAG_MIN_FIELD_GAUSS <= math.hypot(*value) <= MAG_MAX_GAUSS:  # NaN fails too
                raise ValueError(f"{self.section}.{key} must be a field a magnetometer reads (norm {MAG_MIN_FIELD_GAUSS:g} to "
                                 f"{MAG_MAX_GAUSS:g} gauss, the drivers' range; the Earth's is 0.22-0.67), got {list(value)!r}")

    @property
    def field_source(self) -> Literal["config", "wmm"]:
        """Where the reference field comes from: ``"config"`` (``field_ned_gauss`` given) or ``"wmm"``
        (not configured: the World Magnetic Model at the first GNSS position, the fallback until then)."""
        return "wmm" if self.field_ned_gauss is None else "config"


@dataclass(frozen=True)
class AttitudeSettings(Settings):
    """An autopilot's own attitude (ATTITUDE, ATTITUDE_QUATERNION, DroneCAN Solution) as a measurement."""

    section: ClassVar[str] = "fuser.attitude"

    mode: Literal["auto", "always", "off"] = "auto"
    """``"auto"``: fuse the attitude while the IMU is too slow to carry the estimate (below
    ``auto_below_imu_hz``, or no IMU at all: a telemetry radio), not while it is fast (a wired link, where
    the autopilot's estimate would only pull ours towards its own); ``"always"``: fuse every attitude sample;
    ``"off"``: never."""
    sigma_deg: Sigma = 2.0
    """One-sigma noise of the autopilot's attitude, per axis: an EKF's attitude error in flight is 1-2 deg."""
    auto_below_imu_hz: Annotated[float, Range(gt=0, unit="Hz")] = 20.0
    """``"auto"`` fuses the attitude while the measured IMU rate (all the vehicle's IMUs together) is below this."""
    tilt_check_deg: Annotated[float, Range(gt=0, unit="deg")] = 10.0
    """An attitude outside the innovation gate (a jump) is fused at once only if its tilt agrees with the
    accelerometer's down within this (then the state is what went wrong); otherwise it is kept out."""
    reanchor_after_s: Seconds = 10.0
    """An attitude source kept out this long is fused again (it was reset, not faulty)."""


@dataclass(frozen=True)
class UpdateSettings(Settings):
    """What every measurement update shares: the innovation gate and the start-up phase."""

    section: ClassVar[str] = "fuser.updates"

    innovation_gate_sigma: GateSigmas = 3.0
    """Gate a gravity or heading reading further than this many sigma (sensor and state) from the prediction."""
    reanchor_after_s: Seconds = 0.5
    """After this long of continuous gating a reading is fused again, so that a wrong state can recover."""
    converged_deg: Annotated[float, Range(gt=0, unit="deg")] = 10.0
    """Above this RMS uncertainty the state counts as unconverged (raw accelerometer, fast fixes)."""
    fast_start_interval_s: Seconds = 0.01
    """The spacing of the readings the fast start's sigmas (``accel.sigma_rad``, ``mag.sigma_rad``) are for: readings
    closer together count for less (their sigma times ``sqrt(this / interval)``), so that the fast start gathers
    the same evidence in the same time at any loop rate; sparser ones count as given."""


@dataclass(frozen=True)
class ModelErrorSettings(Settings):
    """Published uncertainty only: the errors the filter cannot see (:mod:`fuser.model_error`).

    Composed into every estimate as an independent world-frame error (a
    consider term; the filter's own state and gains are unchanged). The
    three values are fitted on the eight BROAD trials by
    ``benchmarks/fit_model_error.py``: the highest mean log-likelihood of the
    truth among the sets whose 50/90/95 % regions cover within 5 points of nominal, or, where none does, the set
    whose largest deviation from nominal is smallest. Refitted after the tilt the corrections absorb was published
    (:func:`fuser.model.unaided.absorbed`), which took over the tilt floor and the rate term: 59.7 / 82.2 / 87.0 % in
    sample, 59.4 / 80.5 / 82.9 leaving each trial out, every held-out trial but 27 at 87-96 % in its 90 % region
    (before, 3.25 deg / 0.15 deg / 0.75 ms: 55.8 / 79.7 / 82.8 leaving each trial out, trial 10 at 99 %).
    """

    section: ClassVar[str] = "fuser.model_error"

    tilt_deg: Annotated[float, Range(ge=0, le=180, unit="deg")] = 0.0
    """Floor of the tilt error (accelerometer bias and misalignment), one sigma per axis."""
    heading_deg: Annotated[float, Range(ge=0, le=180, unit="deg")] = 2.5
    """Floor of the heading error (local field distortion, an offset the motion never reveals); only with a
    magnetometer. Set mostly by BROAD trial 27, whose heading sits a steady 4.5-7 deg off; 0.5 without it."""
    rate_s: Annotated[float, Range(ge=0, le=1, unit="s")] = 0.0
    """Attitude error (rad, every axis) per rad/s of the recent RMS rotation rate: time-stamp and
    synchronisation errors (``rate dt``) and scale errors left over the correction time (``s rate T``)."""


@dataclass(frozen=True)
class ExtrapolationSettings(Settings):
    """How far ahead of its tick the published estimate is carried by the gyro (:mod:`fuser.model.extrapolation`)."""

    section: ClassVar[str] = "fuser.extrapolation"

    to: Literal["hold_midpoint", "published", "tick"] = "hold_midpoint"
    """``"published"``: to the instant the loop publishes it (``latency_ms`` after the tick), so that a consumer
    gets the attitude of the moment it receives it; ``"hold_midpoint"``: half a tick period further, the middle
    of the interval a consumer holds it; ``"tick"``: not carried (the attitude at the tick). The estimate is
    stamped with the time it is for."""
    imu_delay_ms: Annotated[float, Range(ge=0, le=1000, unit="ms")] = 3.5
    """How long before its stamp the motion an IMU sample describes happened: the IMU's filter group delay, plus
    half the interval for a rate averaged over the interval since the previous sample. The published state is
    carried this much further (the filter's state, like the samples, is that far behind its tick)."""
    every_imu_sample: bool = True
    """Publish an estimate at every sample of the reference IMU too, not only at the ticks (PX4 EKF2's output
    predictor, :mod:`fuser.model.output`): the tick's state turned by the gyro through the samples since, each
    stamped at its arrival; the tick's own estimate then at its due time, and ``to`` does not apply. The filter
    still runs at ``rate_hz``. false: one estimate per tick, carried as ``to`` says."""


@dataclass(frozen=True)
class GnssSettings(Settings):
    """GNSS velocity as the world acceleration the gravity update takes out of the specific force
    (:mod:`fuser.model.velocity`)."""

    section: ClassVar[str] = "fuser.gnss"

    enabled: bool = True
    """Aid the gravity update with GNSS velocity when fixes arrive (false: the accelerometer alone, as
    without GNSS; the fixes' positions still give the WMM field)."""
    velocity_noise_m_s: Annotated[float, Range(gt=0, unit="m/s")] = 0.3
    """One-sigma velocity noise per axis of a fix whose message carries no speed accuracy (GLOBAL_POSITION_INT,
    HIL_GPS); otherwise the receiver's own figure is used."""
    latency_ms: Annotated[float, Range(ge=0, le=1000, unit="ms")] = 150.0
    """How much older a receiver's velocity is than its arrival (GPS_RAW_INT, GPS_INPUT, HIL_GPS, DroneCAN
    Fix2): measurement to the fix's time on the loop's timeline. PX4's EKF2_GPS_DELAY defaults to 110 ms,
    ArduPilot's GPS lag to 120-220 ms by receiver."""
    filtered_latency_ms: Annotated[float, Range(ge=0, le=1000, unit="ms")] = 0.0
    """The same for an autopilot's navigation solution (GLOBAL_POSITION_INT): its EKF's output is
    predicted to the time it is sent."""
    raw_lowpass_s: Seconds = 0.3
    """The acceleration the gravity update's raw readings take out (its fast start, :mod:`fuser.model.gravity`):
    the pairs of fixes low-passed with this time constant, their differenced noise down by about 2.5 at 10 Hz;
    a turn's acceleration turns meanwhile by its rate times this, 2 deg at 0.1 rad/s."""
    max_age_s: Annotated[float, Range(gt=0, le=10, unit="s")] = 1.0
    """Two fixes further apart than this are not differenced (the acceleration between them is too smeared),
    and the aiding stops once the latest fix is this old (the gravity update falls back to the
    accelerometer alone)."""
    noise_window_s: Seconds = 10.0
    """The velocity noise a receiver delivers is measured over about this long (:mod:`fuser.model.velocity`,
    "Noise"); where it is above what the receiver claims (or ``velocity_noise_m_s``), the measured one is used."""
    gate_sigma: GateSigmas = 5.0
    """A fix whose acceleration differs from the accelerometer's (rotated by the estimate) by more than this
    many sigma is a jump: kept out of the low-pass."""
    accel_error_m_s2: Annotated[float, Range(ge=0, le=100, unit="m/s^2")] = 0.5
    """The accelerometer's error in that comparison (bias, scale, vibration left over a GNSS interval), one sigma."""
    residual_lowpass_s: Seconds = 2.0
    """The same comparison, pair by pair, low-passed in the world with this time constant: how far the estimate
    is off, which the published attitude covers where it exceeds what the comparison's own error explains
    (:func:`fuser.model.velocity_check.attitude_excess_rad2`); the differenced velocity noise down by about 4 at 10 Hz."""
    moving_speed_m_s: Annotated[float, Range(gt=0, unit="m/s")] = 1.0
    """A vehicle whose latest fix is faster than this is moving, whatever its IMU says: rest detection is off
    (a smooth cruise with little vibration otherwise passes for rest, and its slow turn rates for a bias)."""


@dataclass(frozen=True)
class LatencySettings(Settings):
    """How long a tick waits for samples in flight (:mod:`fuser.loop`): ``fuser.latency_ms`` at least, more
    when the link's latency varies."""

    section: ClassVar[str] = "fuser.latency"

    adaptive: bool = True
    """Wait for a high quantile of each stream's measured lateness (false: always ``fuser.latency_ms``)."""
    quantile: Annotated[float, Range(gt=0, le=1)] = 0.995
    """The quantile of each stream's lateness (receive time minus placed time) that the wait covers."""
    window_s: Seconds = 30.0
    """Lateness is measured over each stream's samples of the last ``window_s`` (receive time)."""
    max_ms: Annotated[float, Range(ge=0, le=MAX_WAIT_MS, unit="ms")] = 250.0
    """The cap on the wait (and the wait until a stream has shown its lateness): a sample later than this
    is dropped as late rather than holding every estimate back. ``fuser.latency_ms`` wins if it is larger."""


@dataclass(frozen=True)
class ZenohSettings(Settings):
    """Where the estimates are published (``bingham_fuser/<vehicle>/...``)."""

    section: ClassVar[str] = "fuser.zenoh"

    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    """Endpoints the fuser listens on."""
    connect: tuple[str, ...] = ()
    """Routers or peers it connects to."""


@dataclass(frozen=True)
class FuserConfig(Settings):
    """Every setting of the fuser; defaults suit a small multirotor with a MEMS IMU.

    Noise figures are one-sigma. Frames: body FRD, world NED. The general
    settings are the ``[fuser]`` table, each group a ``[fuser.<group>]`` table.
    """

    section: ClassVar[str] = "fuser"

    vehicle: str | None = None
    """Name used in the zenoh key expressions ``bingham_fuser/<vehicle>/...``. None, the default: the command's
    own (:data:`fuser.cli.DEFAULT_VEHICLE`): ``sim`` for the simulated vehicle, ``vehicle`` for a live one, and
    ``listen`` hears every vehicle."""
    rate_hz: Annotated[float, Range(ge=1, le=MAX_RATE_HZ, unit="Hz")] = 100.0
    """Filter ticks per second, each with its estimate (between them the output predictor's at every IMU sample,
    ``[fuser.extrapolation] every_imu_sample``)."""
    latency_ms: Annotated[float, Range(ge=0, le=MAX_WAIT_MS, unit="ms")] = 5.0
    """How long a tick waits at least after its due time for samples still in flight (``[fuser.latency]``
    waits longer on links whose latency varies)."""
    record: str | None = None
    """MCAP file to record inputs and estimates to (None: do not record)."""
    gyro: GyroSettings = GyroSettings()
    imu_check: ImuCheckSettings = ImuCheckSettings()
    bias: BiasSettings = BiasSettings()
    rest: RestSettings = RestSettings()
    accel: AccelSettings = AccelSettings()
    mag: MagSettings = MagSettings()
    attitude: AttitudeSettings = AttitudeSettings()
    updates: UpdateSettings = UpdateSettings()
    model_error: ModelErrorSettings = ModelErrorSettings()
    extrapolation: ExtrapolationSettings = ExtrapolationSettings()
    gnss: GnssSettings = GnssSettings()
    latency: LatencySettings = LatencySettings()
    zenoh: ZenohSettings = ZenohSettings()
    link: LinkSettings = LinkSettings()
    """MAVLink vehicle selection, signing and dialect (``[fuser.link]``; see drivers/link.py)."""
    ros2: Ros2Settings = Ros2Settings()
    """ROS 2 output over rmw_zenoh (``[fuser.ros2]``; ``--ros2``): :mod:`fuser.ros2`."""
    mavlink_out: MavlinkOutSettings = MavlinkOutSettings()
    """MAVLink output to ground stations (``[fuser.mavlink_out]``; ``--mavlink-out CONN``): :mod:`fuser.mavlink_out`."""

    def replace(self, **changes: Any) -> FuserConfig:
        """A copy with some settings changed: general ones by value, a group by a mapping of its fields
        (``config.replace(rate_hz=50, mag={"enabled": False})``) or by a whole group."""
        values: dict[str, Any] = {}
        for key, value in changes.items():
            current = getattr(self, key, None)
            if dataclasses.is_dataclass(current) and isinstance(value, Mapping):
                value = dataclasses.replace(current, **value)  # type: ignore[type-var]
            values[key] = value
        return dataclasses.replace(self, **values)


MOVED: dict[str, str] = {
    "gyro_noise_rad_s_rt_hz": "gyro.noise_rad_s_rt_hz",
    "gyro_scale_error": "gyro.scale_error_fraction",
    "gyro_gap_rate_rad_s": "gyro.gap_rate_rad_s",
    "max_gyro_dt_s": "gyro.max_interval_s",
    "gyro_bias_rad_s": "bias.initial_sigma_rad_s",
    "gyro_bias_floor_rad_s": "bias.floor_sigma_rad_s",
    "gyro_bias_walk_rad_s_rt_s": "bias.walk_rad_s_rt_s",
    "bias_time_constant_s": "bias.time_constant_s",
    "bias_learn_max_rate_rad_s": "bias.learn_max_rate_rad_s",
    "rest_min_s": "rest.min_s",
    "rest_filter_s": "rest.filter_s",
    "rest_gyro_rad_s": "rest.gyro_rad_s",
    "rest_accel_m_s2": "rest.accel_m_s2",
    "rest_bias_sigma_rad_s": "rest.bias_sigma_rad_s",
    "accel_sigma_rad": "accel.sigma_rad",
    "accel_lowpass_s": "accel.lowpass_s",
    "tilt_bias_error_deg": "accel.tilt_bias_error_deg",
    "accel_gate": "accel.norm_gate_fraction",
    "converged_deg": "updates.converged_deg",
    "innovation_gate_sigma": "updates.innovation_gate_sigma",
    "innovation_reanchor_s": "updates.reanchor_after_s",
    "tilt_model_error_deg": "model_error.tilt_deg",
    "heading_model_error_deg": "model_error.heading_deg",
    "rate_model_error_s": "model_error.rate_s",
    "use_mag": "mag.enabled",
    "mag_field_ned_gauss": "mag.field_ned_gauss",
    "mag_sigma_rad": "mag.sigma_rad",
    "mag_error_deg": "mag.error_deg",
    "mag_correlation_s": "mag.correlation_s",
    "heading_bias_error_deg": "mag.heading_bias_error_deg",
    "mag_norm_gate": "mag.norm_gate_fraction",
    "mag_dip_gate_deg": "mag.dip_gate_deg",
    "attitude_sigma_deg": "attitude.sigma_deg",
    "zenoh_listen": "zenoh.listen",
    "zenoh_connect": "zenoh.connect",
    "bias.motion_tilt_noise_deg": "accel.lowpass_error_deg",
}
"""Keys that moved, by their old path below ``fuser`` (the flat keys of the configuration before it was grouped,
``group.key`` for one that moved between groups), and where each one lives now."""
_SWITCHES = {
    "bias_time_constant_s": "bias.feedback_enabled = false switches the feedback off",
    "rest_min_s": "rest.enabled = false switches rest detection off",
    "attitude_sigma_deg": 'attitude.mode = "always" fuses the attitude',
}
"""Old keys whose 0 or None used to switch a feature: the flag that does it now."""


def _build(cls: type, table: Mapping[str, Any], section: str) -> Any:
    """``cls`` from a TOML table: nested tables build the groups; unknown and moved keys are errors naming the key."""
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key not in fields:
            old = key if section == "fuser" else f"{section.removeprefix('fuser.')}.{key}"
            if old in MOVED:
                group, _, name = MOVED[old].partition(".")
                note = f" ({_SWITCHES[old]})" if old in _SWITCHES else ""
                raise ValueError(f"{section}.{key} has moved: set {name} under [fuser.{group}]{note}")
            near = difflib.get_close_matches(key, list(fields), n=1)
            raise ValueError(f"{section}.{key} is not a setting" + (f" (did you mean {near[0]}?)" if near else ""))
        default = fields[key].default
        if dataclasses.is_dataclass(default):
            if not isinstance(value, Mapping):
                raise ValueError(f"{section}.{key} must be a table [{section}.{key}], got {value!r}")
            value = _build(type(default), value, f"{section}.{key}")
        elif isinstance(value, list):  # TOML arrays: every group's sequences are tuples (frozen, comparable)
            value = tuple(value)
        values[key] = value
    return cls(**values)


def _merge(base: dict[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in changes.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            value = _merge(out[key], value)
        out[key] = value
    return out


def _nested(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted keys (``"mag.enabled"``) as nested tables; None values (a flag not given) dropped."""
    out: dict[str, Any] = {}
    for key, value in overrides.items():
        if value is None:
            continue
        *groups, name = key.split(".")
        table = out
        for g in groups:
            table = table.setdefault(g, {})
        table[name] = value
    return out


def load_config(path: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> FuserConfig:
    """Defaults, then the TOML file's ``[fuser]`` table (or its top level), then ``overrides``.

    ``overrides`` holds general keys and dotted group keys (``{"rate_hz": 50,
    "mag.enabled": False}``; None means "not given"). Every value is checked as
    if it came from the file; unknown keys, keys of the old flat layout and
    wrong types are errors naming the key.
    """
    table: dict[str, Any] = {}
    try:
        if path is not None:
            with open(path, "rb") as f:
                text = f.read(MAX_CONFIG_BYTES + 1)
            if len(text) > MAX_CONFIG_BYTES:
                raise ValueError(f"more than {MAX_CONFIG_BYTES // 1024} KiB: not a settings file")
            data = tomllib.loads(text.decode())  # a TOML syntax error, or bytes that are not UTF-8, is a ValueError too
            table = data.get("fuser", data)
            if not isinstance(table, dict):
                raise ValueError(f"fuser must be a table of settings ([fuser]), got {table!r}")
        return _build(FuserConfig, _merge(table, _nested(overrides or {})), "fuser")
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}" if path is not None else str(exc)) from None
