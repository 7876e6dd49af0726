"""Rest detection and the gyro bias measured at rest (VQF's rest detection and rest bias estimation).

The body-frame gyro and accelerometer are low-passed over ``filter_s``; the
sensor is at rest once neither has left its low-pass by more than its
threshold (and the low-passed rate is below the gyro threshold, so that a
slow steady turn is not taken for a bias) for ``min_s``. At rest the
low-passed gyro reads the bias directly: a Kalman update of the bias with
it, whose noise is counted once per ``filter_s`` (consecutive low-passed
readings are correlated, not independent).
"""

from __future__ import annotations

import math

import numpy as np

from fuser.config import RestSettings
from fuser.model.state import BiasState, RestState

__all__ = ["detect_rest", "measure_bias"]


def _norm(v: np.ndarray) -> float:
    return math.sqrt(float(v @ v))


def detect_rest(params: RestSettings, state: RestState, raw_rate_rad_s: np.ndarray, accel_m_s2: np.ndarray, dt_s: float) -> RestState:
    """The detector after one tick's mean raw gyro rate and specific force (body frame), ``dt_s`` after the
    previous readings."""
    gyro_lp = raw_rate_rad_s.copy() if state.gyro_lp_rad_s is None else state.gyro_lp_rad_s
    accel_lp = accel_m_s2.copy() if state.accel_lp_m_s2 is None else state.accel_lp_m_s2
    a = min(1.0, dt_s / params.filter_s)
    gyro_lp = gyro_lp + a * (raw_rate_rad_s - gyro_lp)
    accel_lp = accel_lp + a * (accel_m_s2 - accel_lp)
    still = (
        _norm(raw_rate_rad_s - gyro_lp) < params.gyro_rad_s
        and _norm(gyro_lp) < params.gyro_rad_s
        and _norm(accel_m_s2 - accel_lp) < params.accel_m_s2
    )
    still_s = state.still_s + dt_s if still else 0.0
    return RestState(gyro_lp, accel_lp, still_s, still_s >= params.min_s)


def measure_bias(params: RestSettings, rest: RestState, bias: BiasState, dt_s: float) -> BiasState:
    """Kalman update of the bias with the low-passed gyro, whose noise is ``bias_sigma_rad_s`` on each axis counted
    once per ``filter_s`` (readings every ``dt_s``); call only at rest."""
    assert rest.gyro_lp_rad_s is not None
    noise = params.bias_sigma_rad_s**2 * max(params.filter_s / dt_s, 1.0)
    covariance = bias.covariance_rad2_s2
    gain = covariance @ np.linalg.inv(covariance + noise * np.eye(3))
    estimate = bias.estimate_rad_s + gain @ (rest.gyro_lp_rad_s - bias.estimate_rad_s)
    covariance = (np.eye(3) - gain) @ covariance
    return bias.with_estimate(estimate, 0.5 * (covariance + covariance.T))
