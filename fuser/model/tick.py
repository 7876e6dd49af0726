"""What goes into one tick of the model, what is passed between its steps, and what comes out.

The loop (:mod:`fuser.loop`) owns the timeline: it chooses the tick times,
buffers the samples by time, computes each stream's clock offset and picks
the reference IMU, and hands the model a :class:`TickInput`. The model
returns a :class:`TickResult`, plain values; the loop builds the wire
:class:`fuser.codec.Estimate` from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from core.bingham import Bingham
from drivers.samples import Sample
from fuser.model.diagnostics import UpdateDiagnostic

__all__ = ["GNSS_INPUT", "IMU_INPUT", "TICK_OUTPUT", "GravityReading", "HeadingReading", "Lead", "Motion", "Prediction", "TickContext",
           "TickInput", "TickResult", "VelocityTrack"]

IMU_INPUT = np.dtype([
    ("placed_ns", "i8"),  # on the loop's timeline
    ("gyro_rad_s", "f8", (3,)),
    ("accel_m_s2", "f8", (3,)),
    ("has_mag", "?"),
    ("mag_gauss", "f8", (3,)),
    ("slot", "i8"),  # its IMU's slot in the state (FilterState.imu_slots)
], align=True)
"""The tick's IMU samples as the compiled tick reads them (:class:`drivers.samples.ImuSample`), in the tick's order."""

GNSS_INPUT = np.dtype([
    ("placed_ns", "i8"),
    ("fix_type", "i8"),
    ("has_velocity", "?"),
    ("vel_ned_m_s", "f8", (3,)),
    ("vertical_velocity", "?"),
    ("has_speed_accuracy", "?"),
    ("speed_accuracy_m_s", "f8"),
    ("filtered", "?"),
    ("slot", "i8"),  # its stream's slot in the state (FilterState.gnss_slots)
], align=True)
"""The tick's GNSS fixes (:class:`drivers.samples.GnssSample`; the position is read by :mod:`fuser.model.field`)."""

TICK_OUTPUT = np.dtype([
    ("published_M", "f8", (4, 4)),
    ("published_Z", "f8", (4,)),
    ("has_lead_rotation", "?"),
    ("lead_rotation", "f8", (4,)),  # the body rotation the lead applied, which the output predictor takes back
    ("imu_fault", "?"),  # an IMU kept out lately: the output predictor does not start from this tick
    ("counted_until_ns", "i8"),  # the published variance counts the held rate's error up to here (the tick plus its carry)
], align=True)
"""What the compiled tick leaves for the output predictor (:func:`fuser.model.output.started`): the published
distribution, the lead, whether an IMU was kept out, and up to when the published variance counts the held rate."""


@dataclass(frozen=True, slots=True)
class TickInput:
    """One tick as the loop hands it over."""

    t_ns: int
    """Tick time on the loop's timeline (ns)."""
    dt_ns: int
    """Length of the tick: time since the previous tick (ns)."""
    samples: Sequence[Sample]
    """Every sample placed in the tick."""
    placed_ns: Sequence[int] | None = None
    """Each sample's time on the loop's timeline (its own time plus its stream's clock offset), in
    ``(t_ns - dt_ns, t_ns]``; None: the samples' own times are on the loop's clock."""


class TickContext(NamedTuple):
    """Per-tick values the prediction hands to every update (passed explicitly, never kept on the model)."""

    dt_s: float
    process_variance_rad2: float
    """Per-axis angle variance of the tick's process noise (the updates' correction time constants scale with it)."""
    prior_doubt_deg: float
    """RMS uncertainty of the predicted state: the state's share of every innovation gate."""
    prior_tilt_doubt_deg: float
    """Its tilt's alone (:func:`fuser.model.velocity.tilt_doubt_deg`): the gravity update's convergence and checks,
    the gains of the tilt corrections the bias learns from."""


class Motion(NamedTuple):
    """What the gyro says about one tick (:func:`fuser.model.propagation.integrate_gyro`)."""

    raw_rotation_rad: tuple
    """Rotation vector integrated over the tick, bias not removed."""
    known_s: float
    """Seconds of the tick whose rate is known (sampled or held); the rest is a gap. The mean raw rate over the
    known part is ``raw_rotation_rad / known_s`` when this is positive."""
    closed_variance_rad2: float
    """Interpolation error of the intervals closed in this tick, and the held rotation of a hold that ran out."""
    gap_s: float
    """Seconds of the tick without any rate (no sample yet, or the hold ran out)."""
    saturated_s: float
    """Seconds of the tick after a saturated sample: the rate is beyond the range or unknown."""
    saturated_samples: int
    hold_variance_rad2: float
    """Error of the rate held at the tick's end: published, not in the state (corrected by the next sample)."""
    gaps: int
    """Intervals longer than ``gyro.max_interval_s``: not integrated."""
    held: bool
    """No sample in the tick: its rotation is the held rate's."""


class Prediction(NamedTuple):
    """The predicted attitude and what the updates need to know about how it was predicted
    (:func:`fuser.model.propagation.predict`)."""

    M: np.ndarray
    Z: np.ndarray
    moments: np.ndarray
    """The predicted Bingham's parameters and its moments ``E[(M^T x)_i^2]``."""
    has_rotation: bool
    rotation: tuple
    """The tick's rotation ``u`` (identity when no rate was known)."""
    has_rate: bool
    rate_rad_s: float
    """Norm of the bias-corrected rate (when a rate was known)."""
    variance_rad2: float
    """Per-axis angle variance of the tick's process noise."""


class VelocityTrack(NamedTuple):
    """One tick of the GNSS side (:func:`fuser.model.velocity.track_velocity`): whether it aids, and how."""

    active: bool
    """Aiding is on: the gravity update is the aided one, not the plain one."""
    fused: bool
    """The aided update has a new reading: a pair entered the low-pass in this tick, or in ticks since the last one with
    an IMU sample."""
    interval_s: float
    """Seconds since the previous tick that had a new reading (the aided readings' spacing)."""
    moving: bool
    """A fix within ``max_age_s`` is faster than ``gnss.moving_speed_m_s``: the vehicle is not at rest."""
    lost: bool
    """The aiding ended this tick (the ``gnss_lost`` event)."""


class GravityReading(NamedTuple):
    """One tick's gravity update (:mod:`fuser.model.gravity`, or its GNSS-aided variant in :mod:`fuser.model.velocity`)."""

    fused: bool
    """``exponent`` is a likelihood to multiply into the state (False: nothing fused, ``exponent`` zeros)."""
    exponent: np.ndarray
    apply_now: bool
    """The first tilt ever measured: apply it before the heading update, which needs to know which way is down."""
    trusted: bool
    """The accelerometer was converged and well inside its norm gate: the bias feedback may learn this tick."""
    diagnostic: object
    """:class:`fuser.model.diagnostics.Diagnostic` (not ``present``: no reading this tick, GNSS-aided between two fixes)."""
    has_tilt_bound: bool
    tilt_bound_rad: float
    """A GNSS-aided reading's bound on the prediction's tilt error: its innovation plus twice its noise."""
    restart: bool
    """The fast start runs again: the state had converged on raw readings the GNSS acceleration shows wrong."""


class HeadingReading(NamedTuple):
    """One tick's heading update (:func:`fuser.model.heading.update_heading`)."""

    fused: bool
    exponent: np.ndarray
    diagnostic: object
    """:class:`fuser.model.diagnostics.Diagnostic`."""


class Lead(NamedTuple):
    """The published state's rotation over the lead and the per-axis variance it adds (:func:`fuser.model.extrapolation.lead`)."""

    has_rotation: bool
    rotation: tuple
    """Body-frame rotation ``u`` (published ``x (x) u``; identity when not turned)."""
    variance_rad2: float


class TickResult(NamedTuple):
    """The model's answer for one tick. (A named tuple: the loop makes one for every estimate.)"""

    published: Bingham
    """The published attitude distribution: the filter's, carried ``ahead_ns`` past the tick
    (:mod:`fuser.model.extrapolation`) and widened by the model error (:mod:`fuser.model_error`)."""
    uncertainty_deg: float
    """RMS angular deviation of ``published`` from its mode."""
    diagnostics: tuple[UpdateDiagnostic, ...]
    """What each update that ran did (:mod:`fuser.model.diagnostics`)."""
    counters: Mapping[str, int]
    """The model's event counters so far (gated readings, gaps, rest ticks, ...)."""
    ahead_ns: int = 0
    """``published`` is the attitude at the tick time plus this (ns): the estimate's stamp."""

    @property
    def q_wxyz(self) -> np.ndarray:
        """Mode of ``published``: body FRD -> world NED, w >= 0."""
        return self.published.mode
