"""The published uncertainty's account of what the filter cannot see: the model error.

The filter's posterior only knows the errors its innovations reveal. Errors
correlated for longer than it can average (the reference field's local
distortion, accelerometer bias and misalignment, gyro scale and
misalignment, time-stamp and synchronisation errors) make it too sure. The
published state is the filter's composed with an independent world-frame
rotation error whose size is set per tick from what the fuser observes
(:class:`ModelError`), a consider term: the filter's own state and gains are
unchanged.

Measured on BROAD (Laidig et al., Data 2021, CC-BY-4.0; see
``benchmarks/RESULTS.md``): the per-axis tilt error the filter does not
account for grows in proportion to the recent rotation rate (0.2 deg at
50 deg/s, 1.1-1.4 deg at 400-500 deg/s), the heading error has a floor of
about 1.3 deg with a magnetometer, and the magnetometer's norm and dip
deviations from the reference do not predict the heading error (their
offsets are dominated by the sensor's own calibration; a disturbance that
keeps norm and dip, as on the phone-vibration trial, is invisible to them),
so they are not used.
"""

from __future__ import annotations

import math

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from fuser.config import FuserConfig

__all__ = ["ModelError", "model_error_variances", "widened_concentrations", "with_model_error"]

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
    return state.with_concentrations(widened_concentrations(state.M, state.Z, tilt_variance, heading_variance))


def model_error_variances(config: FuserConfig, rate_sq: float | np.ndarray) -> tuple[float | np.ndarray, float | np.ndarray]:
    """Per-axis angle variances (rad^2), tilt and heading, of :class:`ModelError` at a mean squared
    rotation rate ``rate_sq`` ((rad/s)^2; a scalar or an array)."""
    rate = (config.rate_model_error_s**2) * rate_sq
    heading_floor = math.radians(config.heading_model_error_deg) ** 2 if config.use_mag else 0.0
    return math.radians(config.tilt_model_error_deg) ** 2 + rate, heading_floor + rate


class ModelError:
    """Per-tick size of the model error, from the conditions the filter observes.

    Two terms, added as variances (independent causes):

    * a **floor** (``tilt_model_error_deg``, ``heading_model_error_deg``):
      accelerometer bias and misalignment, the reference field's local
      distortion; the heading floor only with a magnetometer;
    * a **rotation-rate term** ``rate_model_error_s * rate`` on every axis,
      ``rate`` the RMS of the bias-corrected rotation rate low-passed over
      the tilt correction time ``accel_lowpass_s``. Any error proportional to
      the rotation rate lands here: a time-stamp or synchronisation error
      ``dt`` turns the attitude by ``rate * dt`` along the rotation axis; a
      gyro scale or misalignment error ``s`` builds up ``s * rate * T`` over the
      time ``T`` the corrections need to remove it. The constant is thus a time
      (``dt + s T``); the corrections act over ``accel_lowpass_s``, so that is
      the window of the rate that matters. The filter's own process noise
      counts scale error only as white noise per tick, which its
      corrections average away, so it does not see this.
    """

    def __init__(self, config: FuserConfig) -> None:
        self.config = config
        self._rate_sq = 0.0  # low-passed squared rotation rate, (rad/s)^2

    def observe_rate(self, rate_rad_s: float, dt: float) -> None:
        """One tick's bias-corrected rotation rate (rad/s) over ``dt`` seconds."""
        a = min(1.0, dt / self.config.accel_lowpass_s) if self.config.accel_lowpass_s > 0 else 1.0
        self._rate_sq += a * (rate_rad_s * rate_rad_s - self._rate_sq)

    @property
    def recent_rate_rad_s(self) -> float:
        """RMS of the bias-corrected rotation rate over the last ``accel_lowpass_s`` (rad/s)."""
        return math.sqrt(self._rate_sq)

    def variances(self) -> tuple[float, float]:
        """Per-axis angle variances (rad^2): tilt (horizontal axes) and heading (about down)."""
        return model_error_variances(self.config, self._rate_sq)

    def apply(self, state: Bingham) -> Bingham:
        """The published state: ``state`` with this tick's model error (:func:`with_model_error`)."""
        tilt, heading = self.variances()
        if tilt == 0.0 and heading == 0.0:
            return state
        return with_model_error(state, tilt, heading)
