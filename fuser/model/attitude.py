"""The attitude update: an autopilot's own attitude estimate as an identity measurement.

``z = x (x) v`` with isotropic noise ``v`` (per-axis sigma ``attitude.sigma_deg``):
the likelihood is a Bingham in ``x`` and the update an exact product
(unscented paper, sec. IV-B; :func:`core.filters.identity_likelihood`).

**Policy** (``attitude.mode``, :func:`attitude_in_use`). Over a telemetry radio
an autopilot sends its IMUs at 2-10 Hz each and its ATTITUDE at 3-4 Hz: the
gyro alone cannot carry the attitude between so few samples, and the
autopilot's estimate (from its IMU at hundreds of hertz) is the better
measurement. Wired (a companion computer, 50-400 Hz) the IMU carries the
attitude, and fusing the autopilot's estimate would only pull ours onto
its. So by default (``"auto"``) the attitude is fused while the measured
IMU rate is below ``attitude.auto_below_imu_hz`` or there is no IMU at all,
with the stated noise ``sigma_deg``; the gyro carries the estimate between
the attitude samples (:mod:`fuser.model.propagation`). ``"always"`` fuses it
whatever the IMU rate (``--attitude-sigma``), ``"off"`` never (``--no-attitude``).

**Jumps.** An autopilot's estimate can jump (a reset, a fault). A sample
outside the innovation gate is fused only if the accelerometer sides with it
against the state (:func:`update_attitude`); otherwise it is kept out and
counted, and the estimate runs on the gyro and the other sensors, its
uncertainty growing, until the source agrees again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from core import quaternion as quat
from core.filters import identity_likelihood
from drivers.samples import AttitudeSample
from fuser.config import AttitudeSettings, UpdateSettings
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.propagation import rotation_noise
from fuser.model.state import AttitudeState, GyroTrack
from fuser.model.tick import TickContext

__all__ = ["AttitudeReading", "attitude_in_use", "update_attitude"]


def attitude_in_use(params: AttitudeSettings, track: GyroTrack | None, now_ns: int) -> bool:
    """Whether the policy (module docstring) fuses the autopilot's attitude at ``now_ns``."""
    if params.mode != "auto":
        return params.mode == "always"
    return track is None or track.rate_hz(now_ns) < params.auto_below_imu_hz


@dataclass(frozen=True, slots=True)
class AttitudeReading:
    state: AttitudeState
    exponents: tuple[np.ndarray, ...]
    diagnostics: tuple[UpdateDiagnostic, ...]


_rotation_noise = lru_cache(maxsize=8)(rotation_noise)
"""The likelihood's noise for a sigma (computed once per ``attitude.sigma_deg``; a Bingham is immutable)."""


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.acos(max(-1.0, min(1.0, float(a @ b))))


def update_attitude(params: AttitudeSettings, updates: UpdateSettings, state: AttitudeState, samples: Sequence[AttitudeSample],
                    current_q: np.ndarray, measured_down: np.ndarray | None, tick: TickContext) -> AttitudeReading:
    """Every attitude sample of the tick as an identity measurement against the current estimate.

    A sample outside the innovation gate is a jump of the source or an error
    of the state. The accelerometer's down (``measured_down``, body frame)
    tells which for the tilt: if the sample's tilt agrees with it and the
    state's does not, the state went wrong and the sample is fused at once
    (re-anchored); otherwise the sample is kept out (``jump``) until the
    source has disagreed for ``attitude.reanchor_after_s``.
    """
    sigma = math.radians(params.sigma_deg)
    likelihood_noise = _rotation_noise(sigma * sigma)
    gate = updates.innovation_gate_sigma * math.hypot(sigma, math.radians(tick.prior_doubt_deg))
    gated_s = state.gated_s
    exponents, diagnostics = [], []
    for s in samples:
        z = quat.normalize(s.q_wxyz)
        innovation = float(quat.angular_distance(current_q, z))
        ratio = (innovation / gate) ** 2
        outcome, reason = "fused", ""
        if innovation > gate:
            limit = math.radians(params.tilt_check_deg)
            state_wrong = (measured_down is not None and _angle(quat.to_matrix(z)[2], measured_down) <= limit
                           and _angle(quat.to_matrix(current_q)[2], measured_down) > limit)
            if state_wrong or gated_s + tick.dt_s >= params.reanchor_after_s:
                outcome = "reanchored"
            else:
                outcome, reason = "gated", "jump"
        diagnostics.append(UpdateDiagnostic.of("attitude", outcome, reason, innovation, sigma, ratio))  # type: ignore[arg-type]
        if outcome != "gated":
            exponents.append(identity_likelihood(z, likelihood_noise).C)
    if any(d.outcome == "gated" for d in diagnostics):
        gated_s += tick.dt_s
    elif diagnostics:
        gated_s = 0.0
    return AttitudeReading(AttitudeState(gated_s, state.last_fused_ns), tuple(exponents), tuple(diagnostics))
