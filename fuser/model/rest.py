"""Rest detection and the gyro bias measured at rest (VQF's rest detection and rest bias estimation).

The body-frame gyro and accelerometer are low-passed over ``filter_s``; the
sensor is at rest once neither has left its low-pass by more than its
threshold (and the low-passed rate is below the gyro threshold, so that a
slow steady turn is not taken for a bias) for ``min_s``. At rest the
low-passed gyro reads the bias directly: a Kalman update of the bias with
it, whose noise is counted once per ``filter_s`` (consecutive low-passed
readings are correlated, not independent).

Compiled (numba) for the tick (:mod:`fuser.model.fusion`): the detector is the
``rest`` part of the state record (:data:`fuser.model.state.REST`), the bias
its ``bias`` part, each changed in place; ``params`` is the ``rest`` group of
:mod:`fuser.model.params`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fuser.model import vec3

__all__ = ["detect_rest", "measure_bias", "reset"]


@njit(cache=True, nogil=True)
def reset(rest: np.record) -> None:
    """The detector back to its start: nothing low-passed, not still, not at rest."""
    rest.has_lp = False
    vec3.store(rest.gyro_lp_rad_s, vec3.ZERO)
    vec3.store(rest.accel_lp_m_s2, vec3.ZERO)
    rest.still_s = 0.0
    rest.at_rest = False


@njit(cache=True, nogil=True)
def detect_rest(params: np.record, rest: np.record, raw_rate_rad_s: tuple, accel_m_s2: tuple, dt_s: float) -> None:
    """The detector after one tick's mean raw gyro rate and specific force (body frame), ``dt_s`` after the
    previous readings."""
    gyro, accel = raw_rate_rad_s, accel_m_s2
    gyro_lp = vec3.load(rest.gyro_lp_rad_s) if rest.has_lp else gyro
    accel_lp = vec3.load(rest.accel_lp_m_s2) if rest.has_lp else accel
    a = min(1.0, dt_s / params.filter_s)
    gyro_lp, accel_lp = vec3.toward(gyro_lp, gyro, a), vec3.toward(accel_lp, accel, a)
    still = (
        vec3.norm(vec3.sub(gyro, gyro_lp)) < params.gyro_rad_s
        and vec3.norm(gyro_lp) < params.gyro_rad_s
        and vec3.norm(vec3.sub(accel, accel_lp)) < params.accel_m_s2
    )
    still_s = rest.still_s + dt_s if still else 0.0
    rest.has_lp = True
    vec3.store(rest.gyro_lp_rad_s, gyro_lp)
    vec3.store(rest.accel_lp_m_s2, accel_lp)
    rest.still_s = still_s
    rest.at_rest = still_s >= params.min_s


@njit(cache=True, nogil=True)
def measure_bias(params: np.record, rest: np.record, bias: np.record, dt_s: float) -> None:
    """Kalman update of the bias (the state's ``bias`` part, in place) with the low-passed gyro, whose noise is
    ``bias_sigma_rad_s`` on each axis counted once per ``filter_s`` (readings every ``dt_s``); call only at rest."""
    noise = params.bias_sigma_rad_s * params.bias_sigma_rad_s * max(params.filter_s / dt_s, 1.0)
    # 3x3 as rows of tuples, the inverse in closed form (no arrays, no LAPACK)
    c = bias.covariance_rad2_s2
    covariance = ((c[0, 0], c[0, 1], c[0, 2]), (c[1, 0], c[1, 1], c[1, 2]), (c[2, 0], c[2, 1], c[2, 2]))
    innovation_covariance = ((c[0, 0] + noise, c[0, 1], c[0, 2]), (c[1, 0], c[1, 1] + noise, c[1, 2]), (c[2, 0], c[2, 1], c[2, 2] + noise))
    gain = _product(covariance, _inverse(innovation_covariance))
    b0, b1, b2 = vec3.load(bias.estimate_rad_s)
    g0, g1, g2 = vec3.load(rest.gyro_lp_rad_s)
    i0, i1, i2 = g0 - b0, g1 - b1, g2 - b2
    k0, k1, k2 = gain
    vec3.store(bias.estimate_rad_s, (b0 + k0[0] * i0 + k0[1] * i1 + k0[2] * i2,
                                     b1 + k1[0] * i0 + k1[1] * i1 + k1[2] * i2,
                                     b2 + k2[0] * i0 + k2[1] * i1 + k2[2] * i2))
    kept = ((1.0 - k0[0], -k0[1], -k0[2]), (-k1[0], 1.0 - k1[1], -k1[2]), (-k2[0], -k2[1], 1.0 - k2[2]))  # I - gain
    p = _product(kept, covariance)
    for i in range(3):
        for j in range(3):
            c[i, j] = 0.5 * (p[i][j] + p[j][i])


@njit(cache=True, nogil=True)
def _product(a: tuple, b: tuple) -> tuple:
    """The matrix product ``a b`` of two 3x3 matrices given as rows of floats."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return ((a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21, a00 * b02 + a01 * b12 + a02 * b22),
            (a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21, a10 * b02 + a11 * b12 + a12 * b22),
            (a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21, a20 * b02 + a21 * b12 + a22 * b22))


@njit(cache=True, nogil=True)
def _inverse(m: tuple) -> tuple:
    """The inverse of a 3x3 matrix (here symmetric positive definite) in closed form: its adjugate over its determinant."""
    (a, b, c), (d, e, f), (g, h, i) = m
    co_a, co_b, co_c = e * i - f * h, f * g - d * i, d * h - e * g
    scale = 1.0 / (a * co_a + b * co_b + c * co_c)
    return ((co_a * scale, (c * h - b * i) * scale, (b * f - c * e) * scale),
            (co_b * scale, (a * i - c * g) * scale, (c * d - a * f) * scale),
            (co_c * scale, (b * g - a * h) * scale, (a * e - b * d) * scale))
