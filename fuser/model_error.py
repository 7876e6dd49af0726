"""The published uncertainty's account of what the filter cannot see: the model error.

The filter's posterior only knows the errors its innovations reveal. Errors
correlated for longer than it can average (the reference field's local
distortion, accelerometer bias and misalignment, gyro scale and
misalignment, time-stamp and synchronisation errors) make it too sure. The
published state is the filter's composed with an independent world-frame
rotation error whose size is set per tick from what the fuser observes
(:func:`model_error_variances`), a consider term: the filter's own state and gains are
unchanged.

Measured on BROAD (Laidig et al., Data 2021, CC-BY-4.0; see
``benchmarks/RESULTS.md``): the per-axis tilt error the filter does not
account for grows in proportion to the recent rotation rate (0.2 deg at
50 deg/s, 1.1-1.4 deg at 400-500 deg/s), the heading error has a floor of
about 1.3 deg with a magnetometer, and the magnetometer's norm and dip
deviations from the reference do not predict the heading error (their
offsets are dominated by the sensor's own calibration; a disturbance that
keeps norm and dip, as on the phone-vibration trial, is invisible to them),
so they are not used. Since the published state also carries the tilt the
corrections absorbed from the accelerometer (:func:`fuser.model.unaided.absorbed`:
in fast motion the hand's accelerations are most of that rate-proportional
error), the fit sets the tilt floor and the rate term to zero and the heading
floor to 2.5 deg (``fuser.config.ModelErrorSettings``); both terms stay for
sensors that need them.

The per-tick functions are compiled (numba) for the tick
(:func:`fuser.model.fusion.tick`): the rate is the state record's
``model_error`` part (:data:`fuser.model.state.MODEL_ERROR`), a Bingham its
``(M, Z)``. :func:`model_error_variances` and :func:`widened_concentrations`
also score stacks of states for ``benchmarks/fit_model_error.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core import quaternion as quat
from core.bingham_kernels import down_alignment_sq, sorted_concentrations

__all__ = ["model_error_variances", "observe_rate", "published", "widened_concentrations", "with_model_error"]

_DOWN_PURE = np.array([0.0, 0.0, 0.0, 1.0])  # world down (NED z) as a pure quaternion


def widened_concentrations(M: np.ndarray, Z: np.ndarray, tilt_variance, heading_variance) -> np.ndarray:
    """The first three concentrations of the Bingham ``(M, Z)`` with a world-frame model error added.

    Works on one state (``M`` 4x4, ``Z`` 4, scalar variances) or a stack (``M``
    n x 4 x 4, ``Z`` n x 4, variances scalars or n x 1); see :func:`with_model_error`.
    """
    # cosine between the body axis vec(mode^* m_i) of each principal direction and world down in
    # the body, vec(mode^* k mode): left-multiplying by mode^* is orthogonal, so it is m_i . (k mode)
    down_mode = quat.multiply(_DOWN_PURE, M[..., :, 3])
    along_down = ((down_mode[..., None, :] @ M[..., :, :3])[..., 0, :]) ** 2
    variance = 0.25 * (tilt_variance + (heading_variance - tilt_variance) * along_down)
    return Z[..., :3] / (1.0 + 2.0 * np.abs(Z[..., :3]) * variance)


@njit(cache=True, nogil=True)
def _widened_one(M: np.ndarray, Z: np.ndarray, tilt_variance: float, heading_variance: float) -> np.ndarray:
    """:func:`widened_concentrations` of one state, compiled (the per-tick case)."""
    along_down = down_alignment_sq(M)
    out = np.empty(3)
    for i in range(3):
        variance = 0.25 * (tilt_variance + (heading_variance - tilt_variance) * along_down[i])
        out[i] = Z[i] / (1.0 + 2.0 * abs(Z[i]) * variance)
    return out


@njit(cache=True, nogil=True)
def with_model_error(M: np.ndarray, Z: np.ndarray, tilt_variance: float, heading_variance: float) -> tuple:
    """``(M, Z)``: the Bingham ``(M, Z)`` composed with an independent world-frame error of the model (a consider term).

    Treating the errors the filter cannot see as an independent rotation
    error ``e`` with per-axis angle variances ``tilt_variance`` (about the
    horizontal axes) and ``heading_variance`` (about world down), the
    published attitude is ``e (x) x``: in the tangent space of the mode
    covariances add (a Schmidt consider update, Maybeck, *Stochastic Models,
    Estimation and Control*, vol. 1, sec. 6.8, without the cross terms). For
    a Bingham, ``E[y_i^2] = 1/(2|z_i|)`` along its principal directions and a
    quarter of the angle variance along the body axis ``vec(mode^-1 (x) m_i)``
    is added there; the principal directions are kept (the projection drops
    the model error's small off-diagonal part), so no eigendecomposition is
    needed (the columns re-sorted by concentration). An unknown axis (``z_i = 0``) stays unknown.
    """
    widened_M, widened_Z, _ = sorted_concentrations(M, _widened_one(M, Z, tilt_variance, heading_variance))
    return widened_M, widened_Z


@njit(cache=True, nogil=True)
def observe_rate(model_error: np.record, rate_rad_s: float, dt_s: float, window_s: float) -> None:
    """One tick's bias-corrected rotation rate over ``dt_s`` into ``model_error`` (the state's part, in place),
    low-passed over ``window_s`` (the tilt correction time ``fuser.accel.lowpass_s``: the window of the rate that
    matters, see :func:`model_error_variances`). Its RMS rate is ``sqrt(model_error.rate_sq)``."""
    a = min(1.0, dt_s / window_s)
    model_error.rate_sq = model_error.rate_sq + a * (rate_rad_s * rate_rad_s - model_error.rate_sq)


@njit(cache=True, nogil=True)
def model_error_variances(params_model_error: np.record, rate_sq, heading_floor: bool) -> tuple:
    """Per-axis angle variances (rad^2), tilt and heading, at a mean squared rotation rate ``rate_sq``
    ((rad/s)^2; a float, or an array for a stack of states); the heading floor only with a magnetometer
    (``heading_floor``). ``params_model_error``: the ``model_error`` group of :mod:`fuser.model.params`.

    Two terms, added as variances (independent causes):

    * a **floor** (``tilt_deg``, ``heading_deg``): accelerometer bias and
      misalignment, the reference field's local distortion;
    * a **rotation-rate term** ``rate_s * rate`` on every axis, ``rate`` the
      RMS of the bias-corrected rotation rate low-passed over the tilt
      correction time (:func:`observe_rate`). Any error proportional to the
      rotation rate lands here: a time-stamp or synchronisation error ``dt``
      turns the attitude by ``rate * dt`` along the rotation axis; a gyro
      scale or misalignment error ``s`` builds up ``s * rate * T`` over the
      time ``T`` the corrections need to remove it. The constant is thus a
      time (``dt + s T``). The filter's own process noise counts scale error
      only as white noise per tick, which its corrections average away, so it
      does not see this.
    """
    rate = (params_model_error.rate_s * params_model_error.rate_s) * rate_sq
    heading = math.radians(params_model_error.heading_deg)
    floor = heading * heading if heading_floor else 0.0
    tilt = math.radians(params_model_error.tilt_deg)
    return tilt * tilt + rate, floor + rate


@njit(cache=True, nogil=True)
def published(params_model_error: np.record, M: np.ndarray, Z: np.ndarray, rate_sq: float, heading_floor: bool, isotropic_rad2: float,
              unseen_tilt_rad2: float, unseen_heading_rad2: float) -> tuple:
    """``(M, Z)`` of the published state: the Bingham ``(M, Z)`` with the model error at ``rate_sq``
    (:func:`with_model_error`), a further independent error of per-axis variance ``isotropic_rad2`` on every axis
    (the held gyro rate's, for one) and ``unseen_tilt_rad2``, ``unseen_heading_rad2`` of what the filter's state does
    not carry (an acceleration it cannot see, :mod:`fuser.model.unaided`; the heading's, also a bias error held while
    the heading is not corrected, :func:`fuser.model.bias.held_heading_variance_rad2`); ``M`` and ``Z`` themselves when
    there is none."""
    tilt, heading = model_error_variances(params_model_error, rate_sq, heading_floor)
    tilt, heading = tilt + isotropic_rad2 + unseen_tilt_rad2, heading + isotropic_rad2 + unseen_heading_rad2
    if tilt == 0.0 and heading == 0.0:
        return M, Z
    return with_model_error(M, Z, tilt, heading)
