"""Baseline attitude filters the papers compare the Bingham filters against.

- :class:`QuaternionUKF`: UKF in R^4 with the antipodal measurement fix and
  renormalization (unscented paper, sec. V-A; saddlepoint paper, sec. IV-B).
- :class:`QuaternionEKF`, :class:`SecondOrderQuaternionEKF`: LaViola-style
  EKFs as in the QBF paper (sec. 6, Table 1 and the ping-pong experiment).
- :class:`ParticleFilter`: importance resampling with 30, 300 or 10^4
  particles (unscented paper, sec. V-A).

Common interface: ``predict(g, noise)`` for ``x' = g(x) (x) w`` (``g`` acts on
arrays (..., 4), ``g(-x) = -g(x)``), ``update(z, noise)`` for ``z = x (x) v``,
``estimate`` (unit, w >= 0, MAVLink order w, x, y, z). Noises are
:class:`~core.bingham.Bingham` (the Gaussian filters convert them by sampled
moments, :func:`gaussian_from_bingham`) or :class:`Gaussian`.
"""

from core.baselines.ekf import QuaternionEKF, SecondOrderQuaternionEKF
from core.baselines.gaussian import Gaussian, gaussian_from_bingham
from core.baselines.particle import ParticleFilter, systematic_resample
from core.baselines.ukf import QuaternionUKF

__all__ = [
    "Gaussian",
    "ParticleFilter",
    "QuaternionEKF",
    "QuaternionUKF",
    "SecondOrderQuaternionEKF",
    "gaussian_from_bingham",
    "systematic_resample",
]
