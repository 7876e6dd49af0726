"""The output predictor: an estimate at every sample of the reference IMU, between the ticks.

The filter runs at the loop's rate (100 Hz by default); a real-time consumer
that reads the latest estimate at the IMU's rate otherwise holds each one for
a whole tick period (and the wait for samples in flight), and at BROAD's 600
deg/s the attitude turns by degrees meanwhile: with ``extrapolation.to =
"hold_midpoint"`` the held estimate's error is ``w T / sqrt(12)`` RMS over
the hold (issue 15: inclination 1.27 times VQF's held against 1.03 at the
tick times). PX4 EKF2 separates the two rates the same way: its filter fuses
on a delayed horizon at about 100 Hz while an output predictor integrates
every IMU sample from the filter's latest state and publishes at the IMU's
rate (EKF2 ``calculateOutputStates``).

Here, with ``extrapolation.every_imu_sample``, the tick's published
distribution with its lead taken back (the state at the tick, widened by the
model error; :mod:`fuser.model.extrapolation`) is turned by the bias-corrected
gyro through every sample of the reference IMU after the tick, by the same
trapezoidal rule as the tick's integration (what the tick's hold applied
after its last sample taken back, :mod:`fuser.model.propagation`), then
carried at the newest sample's rate to the instant it is published: its
arrival, the sample describing the motion ``extrapolation.imu_delay_ms``
before it. A right rotation of a Bingham is exact (progressive paper, eq. 6):
the concentrations stay the tick's, whose lead variance already covers half a
tick of held rate; the rate's random walk over one tick period more (``s^2
h^3 / 3``, 1e-7 rad^2 at 15 ms) is left out. A gap longer than
``gyro.max_interval_s`` or a saturated sample ends the prediction until the
next tick, as does a tick without a gyro track, or one while the IMU check
keeps an IMU out (:mod:`fuser.model.imu_check`: between ticks it is not known
which IMU is wrong). The filter's state is never
touched: the next tick starts from its own posterior, not from a prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from drivers.samples import Vec3
from fuser.config import GyroSettings
from fuser.model.propagation import saturated
from fuser.model.state import GyroTrack

__all__ = ["OutputState", "advanced", "at", "started"]


@dataclass(frozen=True, slots=True)
class OutputState:
    """The predictor between two ticks."""

    base: Bingham
    """The tick's published distribution at the tick (its lead taken back)."""
    turned_wxyz: tuple[float, float, float, float]
    """Body rotation from the tick to the last sample integrated (bias removed)."""
    last_ns: int
    """The last gyro sample integrated (loop timeline)."""
    last_rate_rad_s: Vec3
    """Its raw rate."""
    covered_ns: int
    """The rotation covers up to here: the tick's time until a sample after it closes the first interval."""
    held_rad: Vec3
    """Raw rotation the tick's hold applied after ``last_ns``: taken back by the first interval."""
    bias_rad_s: Vec3


def started(published: Bingham, lead_rotation: np.ndarray | None, track: GyroTrack | None, bias_rad_s: np.ndarray) -> OutputState | None:
    """The predictor after a tick: its published distribution, the body rotation its lead applied (None: none), the
    gyro track and bias after it. None without a usable rate (no gyro yet, or the last sample saturated)."""
    if track is None or track.saturated:
        return None
    base = published if lead_rotation is None else published.rotate_right(quat.conjugate(lead_rotation))
    return OutputState(base, (1.0, 0.0, 0.0, 0.0), track.last_ns, track.last_rate_rad_s, track.covered_ns, track.held_rad,
                       tuple(bias_rad_s.tolist()))  # type: ignore[arg-type]


def advanced(params: GyroSettings, state: OutputState, rate_rad_s: Vec3, placed_ns: int) -> OutputState | None:
    """``state`` turned through one more sample of the reference IMU (``placed_ns`` on the loop's timeline); None
    after a gap or a saturated sample (the prediction waits for the next tick); unchanged for a sample not after
    the rotation's end (out of order). In plain floats: it runs once per IMU sample."""
    if placed_ns <= state.covered_ns:
        return state
    h_ns = placed_ns - state.last_ns
    if h_ns > round(params.max_interval_s * 1e9) or saturated(params, rate_rad_s):
        return None
    half, covered = 0.5 * h_ns * 1e-9, (placed_ns - state.covered_ns) * 1e-9
    rotvec = [half * (r + p) - held - b * covered for r, p, held, b in zip(rate_rad_s, state.last_rate_rad_s, state.held_rad, state.bias_rad_s)]
    return OutputState(state.base, quat.turned_by(state.turned_wxyz, rotvec), placed_ns, rate_rad_s, placed_ns, (0.0, 0.0, 0.0),
                       state.bias_rad_s)


def at(state: OutputState, stamp_ns: int, imu_delay_ns: int) -> Bingham:
    """The predicted distribution at ``stamp_ns``: the last sample's rate (bias removed) held from the instant it
    describes, ``imu_delay_ns`` before it, to the stamp."""
    carry_s = max(0, stamp_ns - state.covered_ns + imu_delay_ns) * 1e-9
    turned = quat.turned_by(state.turned_wxyz, [(r - b) * carry_s for r, b in zip(state.last_rate_rad_s, state.bias_rad_s)])
    return state.base.rotate_right(np.array(turned))
