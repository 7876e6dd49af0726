"""The fusion model's persistent state: one record, read, set and reset as a whole.

After VQF's parameter / state / coefficient split (``VQFParams``,
``VQFState``, ``VQFCoefficients`` in dlaidig/vqf): the parameters are
:class:`fuser.config.FuserConfig` (laid out for the compiled tick by
:mod:`fuser.model.params`), the coefficients are derived from them once (the
process-noise table, :mod:`fuser.model.propagation`), and everything a tick
carries to the next is here.

Every number is in one numpy record of the nested dtype :data:`STATE`, one
part per update module (``state.gravity``, ``state.bias``, ...), so that the
compiled tick (:mod:`fuser.model.fusion`) reads and writes it at fixed
offsets; each module's functions change their own part. A value that may be
absent has a ``has_<name>`` flag beside it (the value is then zeros). Units
are in the names. Beside the record: the accelerometer's history for the
GNSS pairs (:mod:`fuser.model.velocity`, a ring whose size follows the loop
rate), the reference field with where it came from (:mod:`fuser.model.field`,
Python values, changed between ticks), and which IMU and which GNSS stream
each slot of the record holds.

:class:`FilterState` is a value to the model's user: :attr:`FusionModel.state
<fuser.model.FusionModel.state>` returns a copy, which stays valid after
further ticks and can be set into another model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from core.bingham import Bingham
from drivers.samples import SourceId
from fuser.config import FuserConfig, MagSettings
from fuser.model.diagnostics import UpdateDiagnostic

__all__ = ["ATTITUDE", "ATTITUDE_SOURCE", "BIAS", "FieldState", "FilterState", "GRAVITY", "GYRO", "GYRO_TRACK", "HEADING", "IMU_CHECK",
           "MAX_GNSS_STREAMS", "MAX_IMUS", "MODEL_ERROR", "REST", "STATE", "UNAIDED", "VELOCITY", "initial_state", "knot_capacity"]

MAX_IMUS = 16
"""IMUs of the one vehicle the IMU check compares (ArduPilot has up to 3, PX4 up to 4)."""
MAX_GNSS_STREAMS = 8
"""GNSS streams (a receiver's fix and an autopilot's solution per source) the velocity aiding keeps."""


def _record(*fields: tuple) -> np.dtype:
    return np.dtype(list(fields), align=True)


GYRO_TRACK = _record(
    ("last_ns", "i8"),  # time of the last gyro sample (ns, loop timeline)
    ("last_rate_rad_s", "f8", (3,)),  # its raw rate (bias not removed): the rate held until the next sample
    ("covered_ns", "i8"),  # the attitude has been carried up to here (the last tick's end)
    ("held_rad", "f8", (3,)),  # raw rotation the hold applied since last_ns: taken back when the next sample closes the interval
    ("has_interval_s", "?"),
    ("interval_s", "f8"),  # interval between samples, low-passed over gyro.rate_window_s (from the second sample)
    ("saturated", "?"),  # the last sample was saturated: the rate since it is unknown
    ("has_slope", "?"),  # the last interval was integrated: its slope is known
    ("slope_rad_s2", "f8", (3,)),  # (rate - previous rate) / h of the last integrated interval
    ("slope_h_s", "f8"),  # that interval's length h
    ("walk2_rad2_s3", "f8"),  # the rate walk's intensity^2 the roughest interval of the rate window showed (0: none)
    ("walk2_ns", "i8"),  # that interval's end
)
"""The vehicle's gyro stream (all its IMUs) on the loop's timeline (:mod:`fuser.model.propagation`)."""

GYRO = _record(
    ("has_track", "?"),  # False until the first gyro sample
    ("track", GYRO_TRACK),
    ("rate_rad_s", "f8"),  # norm of the last known bias-corrected rate: the bias feedback learns only below its threshold
    ("has_last_imu_tick_ns", "?"),
    ("last_imu_tick_ns", "i8"),  # the last tick that held IMU samples: gravity and rest count their readings per interval
)

BIAS = _record(
    ("estimate_rad_s", "f8", (3,)),  # body FRD
    ("covariance_rad2_s2", "f8", (3, 3)),  # of the estimate's error
    ("has_lp", "?"),
    ("rotation_lp", "f8", (3, 3, 3)),  # body -> world rotation low-passed: tilt stages 1 and 2, heading stage
    ("rotated_lp_rad_s", "f8", (3, 3)),  # the rotated estimate R b through the same stages
    ("tilt_aided", "?"),  # the tilt correction the stages follow is GNSS-aided, not the plain one
    ("tilt_settled_s", "f8"),  # seconds the stages have followed that same tilt correction
)
"""The gyro bias (rad/s), a Gaussian beside the attitude (:mod:`fuser.model.bias`)."""

REST = _record(
    ("has_lp", "?"),
    ("gyro_lp_rad_s", "f8", (3,)),
    ("accel_lp_m_s2", "f8", (3,)),
    ("still_s", "f8"),
    ("at_rest", "?"),
)
"""Rest detector (VQF, rest detection): low-passed gyro and accelerometer, seconds still, and the verdict (:mod:`fuser.model.rest`)."""

GRAVITY = _record(
    ("q_strapdown", "f8", (4,)),  # gyro-only attitude, never corrected: the almost-inertial frame of the low-pass
    ("has_accel_lp", "?"),
    ("accel_lp_m_s2", "f8", (3,)),  # low-passed specific force in that frame
    ("down_body", "f8", (3,)),  # last measured direction of down in the body frame: the magnetometer's dip reference
    ("converged", "?"),  # once converged the raw accelerometer is not trusted again (until a gyro gap breaks the frame)
    ("tilt_known", "?"),  # a gravity reading has been fused: the heading may be measured
    ("gated_s", "f8"),  # seconds of continuous gating by innovation
    ("disputed_rad", "f8"),  # how far the last reading that disagreed beyond its own error put down from the state (0: it agreed)
    ("has_raw_mean", "?"),
    ("raw_mean_m_s2", "f8", (3,)),  # mean of the raw readings fused before convergence, in the strapdown frame
    ("raw_s", "f8"),  # seconds of raw readings in that mean
    ("measured_body", "f8", (3,)),  # the last measured specific force's direction, negated, in the body frame
    ("gnss_checked", "?"),  # a raw reading has been compared with the first GNSS acceleration
    ("measured_world", "f8", (3,)),  # the world direction it was measured as (with measured_body: the dip gate's)
)
"""The gravity update's memory (:mod:`fuser.model.gravity`)."""

UNAIDED = _record(
    ("excess_m2_s4", "f8"),  # the low-passed specific force's signed |f|^2 - g^2, as far as the estimate followed it
    ("has_norm_mean", "?"),
    ("norm_mean_m_s2", "f8", (3,)),  # long-run mean of the specific force in the strapdown frame
    ("norm_mean_s", "f8"),
    ("absorbed_rad", "f8", (2,)),  # north and east of the tilt the plain corrections moved the estimate by, with a leak
)
"""What the unaided accelerometer cannot tell from gravity (:mod:`fuser.model.unaided`)."""

HEADING = _record(
    ("gated_s", "f8"),  # seconds of continuous gating by innovation
    ("has_last_reading_ns", "?"),
    ("last_reading_ns", "i8"),  # tick of the last magnetometer reading
    ("has_last_fused_ns", "?"),
    ("last_fused_ns", "i8"),  # tick of the last magnetometer reading fused
    ("vector_until_ns", "i8"),  # the field is a whole vector until this tick: a fast start with GNSS settling
)

ATTITUDE_SOURCE = _record(
    ("gated_s", "f8"),  # seconds the autopilot's attitude has been kept out as a jump
    ("has_last_fused_ns", "?"),
    ("last_fused_ns", "i8"),
)
"""The autopilot's attitude as a measurement (:mod:`fuser.model.attitude`)."""

IMU_CHECK = _record(
    ("seen", "u1", (MAX_IMUS,)),  # per IMU slot, 1: its latest sample below (u1: numba types no bool sub-arrays)
    ("t_ns", "i8", (MAX_IMUS,)),
    ("gyro_rad_s", "f8", (MAX_IMUS, 3)),
    ("accel_m_s2", "f8", (MAX_IMUS, 3)),
    ("roughness_rad2_s2", "f8", (MAX_IMUS,)),
    ("repeats", "i8", (MAX_IMUS, 3)),  # per IMU slot and gyro axis, how many samples in a row repeated the one before exactly
    ("has_last_fault_ns", "?"),
    ("last_fault_ns", "i8"),  # when a sample was last kept out
)
"""Each IMU's latest sample, for the cross-check (:mod:`fuser.model.imu_check`)."""

MODEL_ERROR = _record(("rate_sq", "f8"),)  # low-passed squared bias-corrected rotation rate, (rad/s)^2
"""The recent rotation rate the model error scales with (:mod:`fuser.model_error`)."""

VELOCITY = _record(
    ("stream_seen", "u1", (MAX_GNSS_STREAMS,)),  # per GNSS stream slot, 1: its last new fix below (u1, as IMU_CHECK.seen)
    ("stream_rank", "i8", (MAX_GNSS_STREAMS,)),  # the slots' order by (source, filtered), set by the model
    ("stream_measured_ns", "i8", (MAX_GNSS_STREAMS,)),  # when its velocity was measured (placed time minus the latency)
    ("stream_vel_ned_m_s", "f8", (MAX_GNSS_STREAMS, 3)),
    ("stream_vertical", "u1", (MAX_GNSS_STREAMS,)),  # 1: its down component was measured
    ("stream_noise_m_s", "f8", (MAX_GNSS_STREAMS,)),  # one-sigma velocity noise per axis
    ("stream_has_residual", "u1", (MAX_GNSS_STREAMS,)),  # 1: the residual below is its last pair's
    ("stream_residual_m_s", "f8", (MAX_GNSS_STREAMS, 3)),  # its last pair's velocity change less the accelerometer's
    ("stream_residual_vertical", "u1", (MAX_GNSS_STREAMS,)),  # 1: that residual's down component was measured
    ("stream_measured_var_m2_s2", "f8", (MAX_GNSS_STREAMS,)),  # the velocity noise variance its residuals show
    ("stream_residual_count", "i8", (MAX_GNSS_STREAMS,)),  # how many residual differences that average holds (capped)
    ("knots_first", "i8"),  # the accelerometer's history: the ring's first knot (FilterState.knots)
    ("knots_count", "i8"),
    ("has_lp", "?"),  # aiding: the two low-passes below
    ("body_lp_m_s2", "f8", (3,)),  # low-pass of the minus specific force over the GNSS intervals, strapdown frame
    ("world_lp_m_s2", "f8", (3,)),  # the same low-pass of g e_z - a (NED)
    ("lp_s", "f8"),  # seconds of pairs the two low-passes hold since they started (their running mean until tau)
    ("vertical", "?"),  # the last pair's vertical acceleration was measured
    ("noise_var_m2_s4", "f8"),  # variance per axis of the GNSS velocity noise left in the world low-pass
    ("noise_cov_m2_s3", "f8"),  # its covariance with the last fix's velocity noise
    ("has_last_fused_ns", "?"),
    ("last_fused_ns", "i8"),  # the tick that last gave the gravity update a new reading of the low-pass
    ("reading_due", "?"),  # a pair entered the low-pass in a tick without an IMU sample: the next one with one reads it
    ("has_recent", "?"),
    ("recent_world_m_s2", "f8", (3,)),  # g e_z - a of the pairs low-passed over gnss.raw_lowpass_s, aiding or not
    ("recent_ns", "i8"),  # when the newest pair in it was measured (the middle of its interval)
    ("recent_noise_var_m2_s4", "f8"),
    ("recent_noise_cov_m2_s3", "f8"),
    ("recent_s", "f8"),  # seconds of pairs that low-pass holds since it started (its running mean until raw_lowpass_s)
    ("has_residual_lp", "?"),  # the pairs' residuals against the estimate, low-passed in NED (fuser.model.velocity_check)
    ("residual_lp_m_s2", "f8", (3,)),  # their acceleration residual a - (R_est f + g e_z)
    ("residual_force_m_s2", "f8", (3,)),  # the specific force over the same pairs, rotated alike (NED), low-passed alike
    ("residual_noise_var_m2_s4", "f8"),  # variance per axis of the GNSS velocity noise left in that low-pass
    ("residual_noise_cov_m2_s3", "f8"),
    ("residual_s", "f8"),  # seconds of pairs that low-pass holds since it started
    ("residual_ns", "i8"),  # when its newest pair was measured
)
"""GNSS velocity aiding's memory (:mod:`fuser.model.velocity`)."""

ATTITUDE = _record(("M", "f8", (4, 4)), ("Z", "f8", (4,)))
"""The filter's Bingham over the attitude quaternion (body FRD -> world NED): :class:`core.bingham.Bingham`'s parameters."""

STATE = _record(
    ("attitude", ATTITUDE),
    ("bias", BIAS),
    ("gyro", GYRO),
    ("rest", REST),
    ("gravity", GRAVITY),
    ("heading", HEADING),
    ("attitude_source", ATTITUDE_SOURCE),
    ("imu_check", IMU_CHECK),
    ("model_error", MODEL_ERROR),
    ("velocity", VELOCITY),
    ("unaided", UNAIDED),
)
"""Everything numeric one tick hands to the next."""

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


def knot_capacity(config: FuserConfig) -> int:
    """The accelerometer history's ring size: the knots of ``gnss.max_age_s`` plus the fixes' latency and two
    ticks, at the loop's rate (:func:`fuser.model.velocity.track_velocity` keeps the last one before that horizon)."""
    horizon_s = config.gnss.max_age_s + max(config.gnss.latency_ms, config.gnss.filtered_latency_ms) * 1e-3
    return math.ceil(horizon_s * config.rate_hz) + 8


@dataclass(eq=False)
class FilterState:
    """Everything one tick hands to the next (module docstring). The parts of the record are read as attributes:
    ``state.gravity.converged``, ``state.bias.estimate_rad_s``; ``state.attitude`` is the Bingham."""

    record: np.ndarray
    """The numbers: a record array of length one, dtype :data:`STATE`."""
    knots_ns: np.ndarray
    """The accelerometer's history for the GNSS pairs: each knot's tick (ns), a ring of ``record["velocity"]``'s
    ``knots_first`` and ``knots_count`` (:mod:`fuser.model.velocity`)."""
    knots: np.ndarray
    """Each knot's integral of the specific force in the strapdown frame (m/s) and the tick's mean specific force
    there (m/s^2): ``(capacity, 6)``."""
    field: FieldState
    """The reference field in use (:mod:`fuser.model.field`)."""
    imu_slots: tuple[SourceId, ...] = ()
    """The IMU whose latest sample each slot of ``imu_check`` holds, in order of first arrival."""
    gnss_slots: tuple[tuple[SourceId, bool], ...] = ()
    """The GNSS stream (source, filtered) each stream slot of ``velocity`` holds, in order of first arrival."""

    def copy(self) -> FilterState:
        """An independent copy."""
        return FilterState(self.record.copy(), self.knots_ns.copy(), self.knots.copy(), self.field, self.imu_slots, self.gnss_slots)

    def _part(self, name: str) -> np.record:
        return self.record.view(np.recarray)[0][name]

    @property
    def attitude(self) -> Bingham:
        """The filter's Bingham over the attitude quaternion (body FRD -> world NED)."""
        part = self.record[0]["attitude"]
        return Bingham(part["M"], part["Z"])

    bias = property(lambda self: self._part("bias"), doc="The gyro bias (:data:`BIAS`).")
    gyro = property(lambda self: self._part("gyro"), doc="The gyro stream (:data:`GYRO`).")
    rest = property(lambda self: self._part("rest"), doc="The rest detector (:data:`REST`).")
    gravity = property(lambda self: self._part("gravity"), doc="The gravity update's memory (:data:`GRAVITY`).")
    heading = property(lambda self: self._part("heading"), doc="The heading update's (:data:`HEADING`).")
    attitude_source = property(lambda self: self._part("attitude_source"), doc="The autopilot's attitude's (:data:`ATTITUDE_SOURCE`).")
    imu_check = property(lambda self: self._part("imu_check"), doc="The IMU check's (:data:`IMU_CHECK`).")
    model_error = property(lambda self: self._part("model_error"), doc="The model error's (:data:`MODEL_ERROR`).")
    velocity = property(lambda self: self._part("velocity"), doc="GNSS velocity aiding's (:data:`VELOCITY`).")
    unaided = property(lambda self: self._part("unaided"), doc="The unaided accelerometer's (:data:`UNAIDED`).")


def initial_state(config: FuserConfig) -> FilterState:
    """The start: a uniform attitude (no prior knowledge needed), zero bias with its initial uncertainty, the
    configured reference field (or the fallback until a GNSS position)."""
    record = np.zeros(1, STATE)
    s = record[0]
    uniform = Bingham.uniform()
    s["attitude"]["M"], s["attitude"]["Z"] = uniform.M, uniform.Z
    s["bias"]["covariance_rad2_s2"] = config.bias.initial_sigma_rad_s**2 * np.eye(3)
    s["gravity"]["q_strapdown"] = (1.0, 0.0, 0.0, 0.0)
    s["gravity"]["down_body"] = s["gravity"]["measured_body"] = s["gravity"]["measured_world"] = (0.0, 0.0, 1.0)
    s["velocity"]["vertical"] = True
    capacity = knot_capacity(config)
    return FilterState(record, np.zeros(capacity, np.int64), np.zeros((capacity, 6)), FieldState.of(config.mag))
