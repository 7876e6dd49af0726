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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from core import quaternion as quat
from core.bingham import Bingham
from core.bingham_kernels import down_alignment_sq
from fuser.config import ModelErrorSettings

__all__ = ["ModelErrorState", "model_error_variances", "observe_rate", "published", "widened_concentrations", "with_model_error"]

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


def with_model_error(state: Bingham, tilt_variance: float, heading_variance: float) -> Bingham:
    """``state`` composed with an independent world-frame error of the model (a consider term).

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
    needed. An unknown axis (``z_i = 0``) stays unknown.
    """
    return state.with_concentrations(_widened_one(state.M, state.Z, float(tilt_variance), float(heading_variance)))


@dataclass(frozen=True, slots=True)
class ModelErrorState:
    """The recent rotation rate the rate term scales with."""

    rate_sq: float = 0.0
    """Low-passed squared bias-corrected rotation rate, (rad/s)^2."""

    @property
    def recent_rate_rad_s(self) -> float:
        """RMS of the bias-corrected rotation rate over the low-pass window (rad/s)."""
        return math.sqrt(self.rate_sq)


def observe_rate(state: ModelErrorState, rate_rad_s: float, dt_s: float, window_s: float) -> ModelErrorState:
    """``state`` after one tick's bias-corrected rotation rate over ``dt_s``, low-passed over ``window_s``
    (the tilt correction time ``fuser.accel.lowpass_s``: the window of the rate that matters, see below)."""
    a = min(1.0, dt_s / window_s)
    return ModelErrorState(state.rate_sq + a * (rate_rad_s * rate_rad_s - state.rate_sq))


def model_error_variances(
    params: ModelErrorSettings, rate_sq: float | np.ndarray, heading_floor: bool
) -> tuple[float | np.ndarray, float | np.ndarray]:
    """Per-axis angle variances (rad^2), tilt and heading, at a mean squared rotation rate ``rate_sq``
    ((rad/s)^2; a scalar or an array); the heading floor only with a magnetometer (``heading_floor``).

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
    rate = (params.rate_s**2) * rate_sq
    floor = math.radians(params.heading_deg) ** 2 if heading_floor else 0.0
    return math.radians(params.tilt_deg) ** 2 + rate, floor + rate


def published(params: ModelErrorSettings, state: Bingham, rate_sq: float, heading_floor: bool, isotropic_rad2: float = 0.0,
              unseen_rad2: tuple[float, float] = (0.0, 0.0)) -> Bingham:
    """The published state: ``state`` with the model error at ``rate_sq`` (:func:`with_model_error`), a further
    independent error of per-axis variance ``isotropic_rad2`` on every axis (the held gyro rate's, for one) and
    ``unseen_rad2`` (tilt, heading) of an acceleration the filter cannot see (:mod:`fuser.model.unaided`)."""
    tilt, heading = model_error_variances(params, rate_sq, heading_floor)
    tilt, heading = tilt + isotropic_rad2 + unseen_rad2[0], heading + isotropic_rad2 + unseen_rad2[1]
    if tilt == 0.0 and heading == 0.0:
        return state
    return with_model_error(state, tilt, heading)
