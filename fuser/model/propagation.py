"""Prediction: the gyro integrated over the whole tick, then ``x_k = x_(k-1) (x) u (x) w`` in closed form.

**Integration over the whole tick, at any IMU rate.** Every IMU of the
vehicle samples the same body rate, so their samples, placed on the loop's
timeline, form one stream. The attitude is carried from the end of the
previous tick to the end of this one:

* between two samples the rate is their mean (trapezoidal rule: holding the
  new rate over the preceding interval would lag the attitude by half a
  sample period, a degree at 600 deg/s and 286 Hz);
* after the last sample the rate is held (the best estimate of the rate
  until the next sample), for at most ``gyro.max_interval_s``;
* when the next sample arrives the interval is integrated by the trapezoidal
  rule and what the hold already applied is taken back, so an interval
  spanning several ticks is spread over them and the turn is complete.

**Process noise** (per-axis angle variance; :func:`predict`): the gyro's
white noise, the residual bias as a correlated error, the scale error at
the tick's rate; the rate's own uncertainty between samples from a random
walk of the rate with intensity ``gyro.rate_walk_rad_s_rt_s`` (``s_a``):
interpolating an interval ``h`` between two samples leaves an error of
variance ``s_a^2 h^3 / 12`` (the integral of a Brownian bridge), holding the
rate for ``h`` one of ``s_a^2 h^3 / 3``. The first enters the state when an
interval is closed; the second only the published estimate while the hold
lasts (:attr:`Motion.hold_variance_rad2`), since the next sample corrects
what the hold applied, unless the hold runs out (then it enters the state,
and the rest of the gap counts at ``gyro.gap_rate_rad_s``).

**Saturation.** A sample at or beyond ``gyro.saturation_fraction`` of the
range on any axis says only that the rate is out of range (or the sensor
failed): from the last good sample to the next one the rate is unknown, the
attitude is not turned, and the uncertainty grows at ``gyro.range_rad_s``.

The rotation ``u`` and the noise ``w`` (isotropic) then give the prediction
in closed form (progressive paper, Alg. 1: ``M`` rotated by ``u`` on the
right, eq. 6; composition with ``w`` by moment matching, QBF paper, A.9).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from core.normalization import Method
from drivers.samples import ImuSample, Vec3
from fuser.config import BiasSettings, GyroSettings
from fuser.model.state import BiasState, GyroTrack

__all__ = ["Motion", "Prediction", "integrate_gyro", "predict", "process_noise", "rotation_noise", "saturated"]


@dataclass(frozen=True, slots=True)
class Motion:
    """What the gyro says about one tick."""

    raw_rotation_rad: np.ndarray
    """Rotation vector integrated over the tick, bias not removed."""
    known_s: float
    """Seconds of the tick whose rate is known (sampled or held); the rest is a gap."""
    closed_variance_rad2: float
    """Interpolation error of the intervals closed in this tick, and the held rotation of a hold that ran out."""
    gap_s: float
    """Seconds of the tick without any rate (no sample yet, or the hold ran out)."""
    saturated_s: float
    """Seconds of the tick after a saturated sample: the rate is beyond the range or unknown."""
    saturated_samples: int
    hold_variance_rad2: float
    """Error of the rate held at the tick's end: published, not in the state (corrected by the next sample)."""
    gaps: int
    """Intervals longer than ``gyro.max_interval_s``: not integrated."""
    held: bool
    """No sample in the tick: its rotation is the held rate's."""

    @property
    def raw_rate_rad_s(self) -> np.ndarray | None:
        """Mean raw rate over the known part of the tick, None without one."""
        return self.raw_rotation_rad / self.known_s if self.known_s > 0.0 else None


def saturated(params: GyroSettings, rate: Vec3) -> bool:
    """A gyro sample at or beyond ``saturation_fraction`` of the range on any axis (module docstring)."""
    limit = params.saturation_fraction * params.range_rad_s
    return abs(rate[0]) >= limit or abs(rate[1]) >= limit or abs(rate[2]) >= limit


def _merged(params: GyroSettings, samples: Sequence[ImuSample], placed_ns: Sequence[int]) -> list[tuple[int, Vec3, bool]]:
    """The tick's gyro samples as one stream in time order, saturated or not; samples of several IMUs at one
    instant averaged (the unsaturated ones, if any)."""
    if all(a < b for a, b in zip(placed_ns, placed_ns[1:])):  # the common case, one IMU: every sample its own instant, in order
        return [(t, s.gyro_rad_s, saturated(params, s.gyro_rad_s)) for s, t in zip(samples, placed_ns)]
    by_time: dict[int, list[Vec3]] = {}
    for s, t in zip(samples, placed_ns):
        by_time.setdefault(t, []).append(s.gyro_rad_s)
    out = []
    for t in sorted(by_time):
        rates = [r for r in by_time[t] if not saturated(params, r)]
        if not rates:
            out.append((t, by_time[t][0], True))
        else:
            out.append((t, rates[0] if len(rates) == 1 else tuple(sum(r[i] for r in rates) / len(rates) for i in range(3)), False))  # type: ignore[arg-type]
    return out


def integrate_gyro(params: GyroSettings, track: GyroTrack | None, samples: Sequence[ImuSample], placed_ns: Sequence[int],
                   tick_start_ns: int, tick_end_ns: int) -> tuple[GyroTrack | None, Motion]:
    """The gyro stream carried from ``tick_start_ns`` to ``tick_end_ns`` (the loop's timeline) with this tick's
    samples (each at its placed time in the tick); the track after it (module docstring)."""
    max_ns = round(params.max_interval_s * 1e9)
    walk2 = params.rate_walk_rad_s_rt_s**2
    x = y = z = known_ns = gap_ns = saturated_ns = 0.0
    closed = 0.0
    gaps = saturated_samples = 0
    # the track's fields as locals through the samples (a GyroTrack per sample cost more than the arithmetic)
    started = track is not None
    if track is not None:
        last_ns, last_rate, covered_ns, held, interval_s, last_saturated = (
            track.last_ns, track.last_rate_rad_s, track.covered_ns, track.held_rad, track.interval_s, track.saturated)
    for t, rate, saturated in _merged(params, samples, placed_ns):
        saturated_samples += saturated
        if not started:  # the first sample ever: nothing before it is known
            gap_ns += t - tick_start_ns
            started = True
            last_ns, last_rate, covered_ns, held, interval_s, last_saturated = t, rate, t, (0.0, 0.0, 0.0), None, saturated
            continue
        h_ns = t - last_ns
        h_s = h_ns * 1e-9
        interval = h_s if interval_s is None else interval_s + min(1.0, h_s / params.rate_window_s) * (h_s - interval_s)
        if saturated or last_saturated:  # no rate from the last good sample to the next: what a hold applied stays
            saturated_ns += t - covered_ns
            if not last_saturated and covered_ns < last_ns + max_ns:
                closed += walk2 * ((covered_ns - last_ns) * 1e-9) ** 3 / 3.0
        elif h_ns <= max_ns:
            h = h_ns * 1e-9
            half = 0.5 * h
            x += half * (rate[0] + last_rate[0]) - held[0]
            y += half * (rate[1] + last_rate[1]) - held[1]
            z += half * (rate[2] + last_rate[2]) - held[2]
            known_ns += t - covered_ns
            closed += walk2 * h**3 / 12.0
        else:  # a gap: the rate is held to max_interval after the last sample (what it applied stays), then unknown
            gaps += 1
            hold_end = last_ns + max_ns
            if covered_ns < hold_end:  # the hold runs out in this tick
                dt_hold = (hold_end - covered_ns) * 1e-9
                x += last_rate[0] * dt_hold
                y += last_rate[1] * dt_hold
                z += last_rate[2] * dt_hold
                known_ns += hold_end - covered_ns
                closed += walk2 * params.max_interval_s**3 / 3.0
            gap_ns += t - max(covered_ns, hold_end)
        last_ns, last_rate, covered_ns, held, interval_s, last_saturated = t, rate, t, (0.0, 0.0, 0.0), interval, saturated
    if not started:
        return None, Motion(np.zeros(3), known_s=0.0, closed_variance_rad2=0.0, gap_s=(tick_end_ns - tick_start_ns) * 1e-9,
                            saturated_s=0.0, saturated_samples=0, hold_variance_rad2=0.0, gaps=0, held=False)
    if last_saturated:
        saturated_ns += tick_end_ns - covered_ns
        track = GyroTrack(last_ns, last_rate, tick_end_ns, (0.0, 0.0, 0.0), interval_s, True)
        motion = Motion(np.array([x, y, z]), known_ns * 1e-9, closed, gap_ns * 1e-9, saturated_ns * 1e-9, saturated_samples, 0.0, gaps,
                        not samples)
        return track, motion
    # hold the last rate to the tick's end, for at most max_interval after the sample
    hold_end = min(tick_end_ns, last_ns + max_ns)
    start = covered_ns
    dt_hold = max(0, hold_end - start) * 1e-9
    hx, hy, hz = last_rate[0] * dt_hold, last_rate[1] * dt_hold, last_rate[2] * dt_hold
    track = GyroTrack(last_ns, last_rate, tick_end_ns, (held[0] + hx, held[1] + hy, held[2] + hz), interval_s, False)
    known_ns += max(0, hold_end - start)
    gap_ns += tick_end_ns - max(hold_end, start)
    age_s = (tick_end_ns - last_ns) * 1e-9
    if tick_end_ns - last_ns >= max_ns:
        if start < last_ns + max_ns:  # the hold runs out in this tick: what it applied stays unverified
            closed += walk2 * params.max_interval_s**3 / 3.0
        hold_variance = 0.0
    else:
        hold_variance = walk2 * age_s**3 / 3.0
    motion = Motion(np.array([x + hx, y + hy, z + hz]), known_ns * 1e-9, closed, gap_ns * 1e-9, saturated_ns * 1e-9, saturated_samples,
                    hold_variance, gaps, not samples)
    return track, motion


def rotation_noise(variance_rad2: float) -> Bingham:
    """Isotropic rotation noise whose per-axis angle variance is ``variance_rad2``.

    The vector part of a small rotation is half its angle, and a Bingham's
    ``E[y_i^2] -> 1/(2|z_i|)``, so ``z = -2 / variance``.
    """
    z = -2.0 / variance_rad2
    return Bingham.from_mode(quat.IDENTITY, [z, z, z])


@lru_cache(maxsize=4096)
def _noise_step(key: int) -> Bingham:
    return rotation_noise(math.exp(key / 20.0))


def process_noise(variance_rad2: float, floor_rad2: float) -> Bingham:
    """The process noise for a variance, in steps of 5% (``exp(k / 20)``): ticks repeat their length and the
    bias variance settles, so few distinct values occur and their moments are computed once."""
    return _noise_step(round(math.log(max(variance_rad2, floor_rad2)) * 20))


@dataclass(frozen=True, slots=True)
class Prediction:
    """The predicted attitude and what the updates need to know about how it was predicted."""

    attitude: Bingham
    rotation: np.ndarray | None
    """The tick's rotation ``u`` (None when no rate was known)."""
    rate_rad_s: float | None
    """Norm of the bias-corrected rate (None when no rate was known)."""
    variance_rad2: float
    """Per-axis angle variance of the tick's process noise."""


def predict(gyro: GyroSettings, bias_params: BiasSettings, attitude: Bingham, bias: BiasState, motion: Motion, dt_s: float,
            method: Method) -> Prediction:
    """``attitude`` carried over the tick by the bias-corrected rotation, with the tick's process noise.

    A residual bias error ``e`` persists: over its correlation time ``tau``
    it turns the attitude by ``e tau``, the same as white noise of variance
    ``e^2 tau dt`` per tick; ``(e dt)^2`` would understate it by ``tau/dt``
    and make the filter overconfident (and the bias loop underdamped).
    """
    correlation_s = bias_params.time_constant_s if bias_params.feedback_enabled else bias_params.correlation_without_feedback_s
    variance = gyro.noise_rad_s_rt_hz**2 * dt_s + bias.variance_rad2_s2 * correlation_s * dt_s
    variance += motion.closed_variance_rad2 + (gyro.gap_rate_rad_s * motion.gap_s) ** 2 + (gyro.range_rad_s * motion.saturated_s) ** 2
    u = rate_norm = None
    if motion.known_s > 0.0:
        rotvec = motion.raw_rotation_rad - bias.estimate_rad_s * motion.known_s
        angle = math.sqrt(float(rotvec @ rotvec))
        rate_norm = angle / motion.known_s
        u = quat.from_rotvec(rotvec)
        variance += (gyro.scale_error_fraction * angle) ** 2
    rotated = attitude if u is None else attitude.rotate_right(u)
    return Prediction(rotated.compose(process_noise(variance, gyro.min_process_variance_rad2), method), u, rate_norm, variance)
