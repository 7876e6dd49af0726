"""The published orientation covariance against the published RMS angle, for the outputs that carry both."""

from __future__ import annotations

import math

import numpy as np


def assert_covariance_matches_rms(covariance_rad2: np.ndarray, uncertainty_deg: float) -> None:
    """The covariance is the tangent space's, ``4 E[sin^2(theta/2)] = E[theta^2 - theta^4/12 + ...]``, the
    uncertainty the RMS angle's: equal while small, the covariance's smaller by about ``u^2/14`` (``u`` the RMS
    angle in rad; Gaussian 3-D errors, ``E[theta^4] = 5/3 E[theta^2]^2``), 2 % at a cold start's 40 deg."""
    u = math.radians(uncertainty_deg)
    rms = math.sqrt(float(np.trace(covariance_rad2)))
    assert u * (1.0 - u * u / 12.0) - 1e-9 <= rms <= u * 1.001 + 1e-9, (math.degrees(rms), uncertainty_deg)
