"""What goes into one tick of the model, what is passed between its steps, and what comes out.

The loop (:mod:`fuser.loop`) owns the timeline: it chooses the tick times,
buffers the samples by time, computes each stream's clock offset and picks
the reference IMU, and hands the model a :class:`TickInput`. The model
returns a :class:`TickResult`, plain values; the loop builds the wire
:class:`fuser.codec.Estimate` from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from core.bingham import Bingham
from drivers.samples import Sample
from fuser.model.diagnostics import UpdateDiagnostic

__all__ = ["TickContext", "TickInput", "TickResult"]


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


@dataclass(frozen=True, slots=True)
class TickContext:
    """Per-tick values the prediction hands to every update (passed explicitly, never kept on the model)."""

    dt_s: float
    process_variance_rad2: float
    """Per-axis angle variance of the tick's process noise (the updates' correction time constants scale with it)."""
    prior_doubt_deg: float
    """RMS uncertainty of the predicted state: the state's share of every innovation gate."""
    prior_tilt_doubt_deg: float
    """Its tilt's alone (:func:`fuser.model.velocity.tilt_doubt_deg`): the gravity update's convergence and checks,
    the gains of the tilt corrections the bias learns from."""


@dataclass(frozen=True, slots=True)
class TickResult:
    """The model's answer for one tick."""

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
    lead_rotation: np.ndarray | None = None
    """The body rotation ``published`` was carried by over the lead (None: not turned); the output predictor
    (:mod:`fuser.model.output`) takes it back."""
    imu_fault: bool = False
    """An IMU was kept out within ``imu_check.compare_within_s``: which IMU is wrong is not known between ticks, so
    the output predictor does not turn this state by the reference IMU."""

    @property
    def q_wxyz(self) -> np.ndarray:
        """Mode of ``published``: body FRD -> world NED, w >= 0."""
        return self.published.mode
