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

Compiled (numba) for the tick (:func:`fuser.model.fusion.tick`): the source's
memory is the state record's ``attitude_source`` part
(:data:`fuser.model.state.ATTITUDE_SOURCE`), changed in place.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.quaternion_kernels import angular_distance, normalize, rotation_rows
from fuser.model import propagation, vec3
from fuser.model.diagnostics import ATTITUDE, FUSED, GATED, JUMP, NO_REASON, NOT_AIDED, REANCHORED, emit, of
from fuser.model.params import MODE_ALWAYS, MODE_AUTO
from fuser.model.tick import TickContext

__all__ = ["attitude_in_use", "update_attitude"]

@njit(cache=True, nogil=True)
def attitude_in_use(params_attitude: np.record, gyro: np.record, now_ns: int) -> bool:
    """Whether the policy (module docstring) fuses the autopilot's attitude at ``now_ns``; ``gyro`` the state's
    ``gyro`` part (its track's measured rate, :func:`fuser.model.propagation.rate_hz`)."""
    if params_attitude.mode != MODE_AUTO:
        return params_attitude.mode == MODE_ALWAYS
    return not gyro.has_track or propagation.rate_hz(gyro.track, now_ns) < params_attitude.auto_below_imu_hz


@njit(cache=True, nogil=True)
def _add_identity_exponent(out: np.ndarray, z: tuple, noise_M: np.ndarray, noise_Z: np.ndarray) -> None:
    """Add to ``out`` the exponent ``C`` of :func:`core.filters.identity_likelihood` of the unit quaternion ``z``
    with the noise Bingham ``(noise_M, noise_Z)``: ``x^-1 (x) z = R(z) J x`` (``J`` conjugates), so the likelihood's
    principal directions are ``M' = J R(z)^T M_noise`` and ``C = M' diag(Z) M'^T`` (unscented paper, sec. IV-B).

    ``R(z)`` (``R(z) p = p (x) z``) written out: its rows are ``(w, -x, -y, -z)``, ``(x, w, z, -y)``,
    ``(y, -z, w, x)``, ``(z, y, -x, w)``."""
    w, x, y, zz = z
    R = ((w, -x, -y, -zz), (x, w, zz, -y), (y, -zz, w, x), (zz, y, -x, w))
    m = np.empty((4, 4))
    for k in range(4):
        for c in range(4):  # (R^T M)[c, k] = sum_r R[r][c] M[r, k], then J
            s = R[0][c] * noise_M[0, k] + R[1][c] * noise_M[1, k] + R[2][c] * noise_M[2, k] + R[3][c] * noise_M[3, k]
            m[c, k] = s if c == 0 else -s
    for i in range(4):
        for j in range(4):
            out[i, j] += ((m[i, 0] * noise_Z[0]) * m[j, 0] + (m[i, 1] * noise_Z[1]) * m[j, 1] + (m[i, 2] * noise_Z[2]) * m[j, 2]
                          + (m[i, 3] * noise_Z[3]) * m[j, 3])


@njit(cache=True, nogil=True)
def update_attitude(params_attitude: np.record, params_updates: np.record, source: np.record, samples: np.ndarray, current_q: tuple,
                    tilt_known: bool, measured_down: tuple, tick: TickContext, exponent: np.ndarray, diagnostics: np.ndarray,
                    n_diag: int) -> tuple:
    """Every attitude sample of the tick (``samples``, ``(n, 4)`` quaternions) as an identity measurement against the
    current estimate; ``(n_diag, fused)``: each sample's diagnostic is written into ``diagnostics`` from index
    ``n_diag`` on (:func:`fuser.model.diagnostics.emit`), each fused sample's likelihood exponent added into
    ``exponent`` in sample order, and ``fused`` counts them. ``source`` (the state's ``attitude_source`` part) keeps
    its ``gated_s``, changed in place.

    A sample outside the innovation gate is a jump of the source or an error
    of the state. The accelerometer's down (``measured_down``, body frame, when
    ``tilt_known``) tells which for the tilt: if the sample's tilt agrees with it and the
    state's does not, the state went wrong and the sample is fused at once
    (re-anchored); otherwise the sample is kept out (``jump``) until the
    source has disagreed for ``attitude.reanchor_after_s``.
    """
    sigma = math.radians(params_attitude.sigma_deg)
    noise_M, noise_Z = propagation.isotropic_noise(sigma * sigma)
    gate = params_updates.innovation_gate_sigma * math.hypot(sigma, math.radians(tick.prior_doubt_deg))
    limit = math.radians(params_attitude.tilt_check_deg)
    gated_s = source.gated_s
    any_gated = False
    fused = 0
    for k in range(samples.shape[0]):
        z = normalize((samples[k, 0], samples[k, 1], samples[k, 2], samples[k, 3]))
        innovation = angular_distance(current_q, z)
        ratio = (innovation / gate) * (innovation / gate)
        outcome, reason = FUSED, NO_REASON
        if innovation > gate:
            state_wrong = (tilt_known and vec3.angle_rad(vec3.dot(rotation_rows(z)[2], measured_down)) <= limit
                           and vec3.angle_rad(vec3.dot(rotation_rows(current_q)[2], measured_down)) > limit)
            if state_wrong or gated_s + tick.dt_s >= params_attitude.reanchor_after_s:
                outcome = REANCHORED
            else:
                outcome, reason = GATED, JUMP
        n_diag = emit(diagnostics, n_diag, of(ATTITUDE, outcome, reason, innovation, sigma, ratio, NOT_AIDED))
        if outcome == GATED:
            any_gated = True
        else:
            _add_identity_exponent(exponent, z, noise_M, noise_Z)
            fused += 1
    if any_gated:
        source.gated_s = gated_s + tick.dt_s
    elif samples.shape[0] > 0:
        source.gated_s = 0.0
    return n_diag, fused
