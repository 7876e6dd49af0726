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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from core import quaternion as quat
from core.filters import identity_likelihood
from drivers.samples import AttitudeSample
from fuser.config import AttitudeSettings
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.propagation import rotation_noise
from fuser.model.state import GyroTrack

__all__ = ["AttitudeReading", "attitude_in_use", "update_attitude"]


def attitude_in_use(params: AttitudeSettings, track: GyroTrack | None, now_ns: int) -> bool:
    """Whether the policy (module docstring) fuses the autopilot's attitude at ``now_ns``."""
    if params.mode != "auto":
        return params.mode == "always"
    return track is None or track.rate_hz(now_ns) < params.auto_below_imu_hz


@dataclass(frozen=True, slots=True)
class AttitudeReading:
    exponents: tuple[np.ndarray, ...]
    diagnostics: tuple[UpdateDiagnostic, ...]


def update_attitude(params: AttitudeSettings, samples: Sequence[AttitudeSample], current_q: np.ndarray) -> AttitudeReading:
    """Every attitude sample of the tick as an identity measurement against the current estimate."""
    sigma = math.radians(params.sigma_deg)
    likelihood_noise = rotation_noise(sigma * sigma)
    exponents, diagnostics = [], []
    for s in samples:
        z = quat.normalize(s.q_wxyz)
        exponents.append(identity_likelihood(z, likelihood_noise).C)
        diagnostics.append(UpdateDiagnostic.of("attitude", "fused", innovation_rad=float(quat.angular_distance(current_q, z)), sigma_rad=sigma))
    return AttitudeReading(tuple(exponents), tuple(diagnostics))
