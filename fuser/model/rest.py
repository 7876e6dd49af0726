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


import numpy as np

from fuser.config import RestSettings
from fuser.model import vec3
from fuser.model.state import BiasState, RestState

__all__ = ["detect_rest", "measure_bias"]


def detect_rest(params: RestSettings, state: RestState, raw_rate_rad_s: np.ndarray, accel_m_s2: np.ndarray, dt_s: float) -> RestState:
    """The detector after one tick's mean raw gyro rate and specific force (body frame), ``dt_s`` after the
    previous readings."""
    # 3-vectors in plain floats: numpy's per-call cost would dominate
    gyro, accel = raw_rate_rad_s.tolist(), accel_m_s2.tolist()
    gyro_lp = gyro if state.gyro_lp_rad_s is None else state.gyro_lp_rad_s.tolist()
    accel_lp = accel if state.accel_lp_m_s2 is None else state.accel_lp_m_s2.tolist()
    a = min(1.0, dt_s / params.filter_s)
    gyro_lp, accel_lp = vec3.toward(gyro_lp, gyro, a), vec3.toward(accel_lp, accel, a)
    still = (
        vec3.norm(vec3.sub(gyro, gyro_lp)) < params.gyro_rad_s
        and vec3.norm(gyro_lp) < params.gyro_rad_s
        and vec3.norm(vec3.sub(accel, accel_lp)) < params.accel_m_s2
    )
    still_s = state.still_s + dt_s if still else 0.0
    return RestState(np.array(gyro_lp), np.array(accel_lp), still_s, still_s >= params.min_s)


def measure_bias(params: RestSettings, rest: RestState, bias: BiasState, dt_s: float) -> BiasState:
    """Kalman update of the bias with the low-passed gyro, whose noise is ``bias_sigma_rad_s`` on each axis counted
    once per ``filter_s`` (readings every ``dt_s``); call only at rest."""
    assert rest.gyro_lp_rad_s is not None
    noise = params.bias_sigma_rad_s**2 * max(params.filter_s / dt_s, 1.0)
    # 3x3 in plain floats, the inverse in closed form (numpy's per-call cost and LAPACK's would dominate)
    covariance = bias.covariance_rad2_s2.tolist()
    innovation_covariance = [row[:] for row in covariance]
    for i in range(3):
        innovation_covariance[i][i] += noise
    gain = _product(covariance, _inverse(innovation_covariance))
    estimate = bias.estimate_rad_s.tolist()
    innovation = [g - b for g, b in zip(rest.gyro_lp_rad_s.tolist(), estimate)]
    estimate = [b + k0 * innovation[0] + k1 * innovation[1] + k2 * innovation[2] for b, (k0, k1, k2) in zip(estimate, gain)]
    kept = [[-k for k in row] for row in gain]  # I - gain
    for i in range(3):
        kept[i][i] += 1.0
    covariance = _product(kept, covariance)
    symmetric = [[0.5 * (covariance[i][j] + covariance[j][i]) for j in range(3)] for i in range(3)]
    return bias.with_estimate(np.array(estimate), np.array(symmetric))


def _product(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    """The matrix product ``a b`` of two 3x3 matrices given as rows of plain floats."""
    columns = list(zip(*b))
    return [[r0 * c0 + r1 * c1 + r2 * c2 for c0, c1, c2 in columns] for r0, r1, r2 in a]


def _inverse(m: list[list[float]]) -> list[list[float]]:
    """The inverse of a 3x3 matrix (here symmetric positive definite) in closed form: its adjugate over its determinant."""
    (a, b, c), (d, e, f), (g, h, i) = m
    co_a, co_b, co_c = e * i - f * h, f * g - d * i, d * h - e * g
    scale = 1.0 / (a * co_a + b * co_b + c * co_c)
    return [[co_a * scale, (c * h - b * i) * scale, (b * f - c * e) * scale],
            [co_b * scale, (a * i - c * g) * scale, (c * d - a * f) * scale],
            [co_c * scale, (b * g - a * h) * scale, (a * e - b * d) * scale]]
