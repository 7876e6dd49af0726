"""The attitude update: an autopilot's own attitude estimate as an identity measurement.

``z = x (x) v`` with isotropic noise ``v`` (per-axis sigma ``attitude.sigma_deg``):
the likelihood is a Bingham in ``x`` and the update an exact product
(unscented paper, sec. IV-B; :func:`core.filters.identity_likelihood`).
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

__all__ = ["AttitudeReading", "update_attitude"]


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
