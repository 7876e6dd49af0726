"""Prediction: each IMU's gyro integrated over the tick, then ``x_k = x_(k-1) (x) u (x) w`` in closed form.

The rotation ``u`` is the bias-corrected mean rate over the tick; the
process noise ``w`` is isotropic (progressive paper, Alg. 1: rotate ``M`` by
``u`` on the right, eq. 6; compose with ``w`` by moment matching, QBF paper,
A.9), its per-axis angle variance the sum of the gyro's white noise, the
residual bias as a correlated error, the scale error at the tick's rate, or
the gap rate when no gyro arrived.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from core.normalization import Method
from drivers.samples import ImuSample, SourceId, Vec3
from fuser.config import BiasSettings, GyroSettings
from fuser.model.state import BiasState, GyroState

__all__ = ["Motion", "Prediction", "ProcessNoise", "integrate_gyro", "predict", "rotation_noise"]


@dataclass(frozen=True, slots=True)
class Motion:
    """What the tick's gyro samples say: the mean raw rate and how many intervals were gaps."""

    raw_rate_rad_s: np.ndarray | None
    """Mean rate over the tick, averaged over the IMUs, bias not removed; None without a usable interval."""
    gaps: int
    """Sample intervals longer than ``gyro.max_interval_s`` (or not after the previous sample): not integrated."""


@dataclass(frozen=True, slots=True)
class Prediction:
    """The predicted attitude and what the updates need to know about how it was predicted."""

    attitude: Bingham
    rotation: np.ndarray | None
    """The tick's rotation ``u`` (None without gyro)."""
    rate_rad_s: float | None
    """Norm of the bias-corrected rate (None without gyro)."""
    variance_rad2: float
    """Per-axis angle variance of the tick's process noise."""


def _trapezoid(params: GyroSettings, last: dict[SourceId, tuple[int, Vec3]], samples: Sequence[ImuSample]) -> tuple[np.ndarray, float, int]:
    """Rotation vector and seconds covered by one IMU's samples (time order), and the gaps skipped;
    ``last`` (each IMU's previous sample) is updated.

    Each sample is the rate at its time stamp, so the rate between two
    samples is their mean (trapezoidal rule): holding the new rate over the
    preceding interval would lag the attitude by half a sample period, a
    degree at 600 deg/s and 286 Hz.
    """
    x = y = z = covered = 0.0  # plain floats: a tick holds a handful of samples
    gaps = 0
    for s in samples:
        rate = s.gyro_rad_s
        previous = last.get(s.source)
        last[s.source] = (s.t_ns, rate)
        if previous is None:
            continue
        dt = (s.t_ns - previous[0]) * 1e-9
        if not 0.0 < dt <= params.max_interval_s:
            gaps += 1
            continue
        half = 0.5 * dt
        x += half * (rate[0] + previous[1][0])
        y += half * (rate[1] + previous[1][1])
        z += half * (rate[2] + previous[1][2])
        covered += dt
    return np.array([x, y, z]), covered, gaps


def integrate_gyro(params: GyroSettings, state: GyroState, imu: Sequence[ImuSample]) -> tuple[dict[SourceId, tuple[int, Vec3]], Motion]:
    """Each IMU's samples integrated on its own (its own clock), their mean rates averaged; the new last samples."""
    last = dict(state.last)
    rates = []
    gaps = 0
    sources = {s.source for s in imu}
    for source in sorted(sources):
        mine = imu if len(sources) == 1 else [s for s in imu if s.source == source]
        rotvec, covered, skipped = _trapezoid(params, last, sorted(mine, key=lambda s: s.t_ns))
        gaps += skipped
        if covered > 0.0:
            rates.append(rotvec / covered)
    return last, Motion((sum(rates) / len(rates)) if rates else None, gaps)


def rotation_noise(variance_rad2: float) -> Bingham:
    """Isotropic rotation noise whose per-axis angle variance is ``variance_rad2``.

    The vector part of a small rotation is half its angle, and a Bingham's
    ``E[y_i^2] -> 1/(2|z_i|)``, so ``z = -2 / variance``.
    """
    z = -2.0 / variance_rad2
    return Bingham.from_mode(quat.IDENTITY, [z, z, z])


class ProcessNoise:
    """The process noise by per-axis angle variance (floored at ``gyro.min_process_variance_rad2``),
    memoised in 5% steps: ticks repeat their length and the bias variance settles, so few distinct values occur."""

    def __init__(self, min_variance_rad2: float) -> None:
        self.min_variance_rad2 = min_variance_rad2
        self._memo: dict[int, Bingham] = {}

    def __call__(self, variance_rad2: float) -> Bingham:
        key = round(math.log(variance_rad2) * 20)
        if key not in self._memo:
            self._memo[key] = rotation_noise(max(variance_rad2, self.min_variance_rad2))
        return self._memo[key]


def predict(gyro: GyroSettings, bias_params: BiasSettings, attitude: Bingham, bias: BiasState, raw_rate_rad_s: np.ndarray | None,
            dt_s: float, noise: ProcessNoise, method: Method) -> Prediction:
    """``attitude`` carried over the tick by the bias-corrected rate, with the tick's process noise.

    A residual bias error ``e`` persists: over its correlation time ``tau``
    it turns the attitude by ``e tau``, the same as white noise of variance
    ``e^2 tau dt`` per tick; ``(e dt)^2`` would understate it by ``tau/dt``
    and make the filter overconfident (and the bias loop underdamped).
    """
    correlation_s = bias_params.time_constant_s if bias_params.feedback_enabled else bias_params.correlation_without_feedback_s
    variance = gyro.noise_rad_s_rt_hz**2 * dt_s + bias.variance_rad2_s2 * correlation_s * dt_s
    u = rate_norm = None
    if raw_rate_rad_s is not None:
        rate = raw_rate_rad_s - bias.estimate_rad_s
        rate_norm = math.sqrt(float(rate @ rate))
        u = quat.from_rotvec(rate * dt_s)
        variance += (gyro.scale_error_fraction * rate_norm * dt_s) ** 2
    else:
        variance += (gyro.gap_rate_rad_s * dt_s) ** 2
    rotated = attitude if u is None else attitude.rotate_right(u)
    return Prediction(rotated.compose(noise(variance), method), u, rate_norm, variance)
