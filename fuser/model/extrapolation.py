"""The published state carried from the tick's time to the time it is for: the gyro's held rate over the lead.

The loop runs tick ``T`` once its clock reaches ``T + latency`` (the wait
for samples still in flight) and a real-time consumer then holds that
estimate until the next one, ``1 / rate`` later. An estimate of the attitude
at ``T`` is thus 5 to 15 ms old while it is used (at 100 Hz with 5 ms of
latency): 3-9 deg at BROAD's 600 deg/s. So the published state is carried
ahead of the tick, as PX4 EKF2's output predictor carries its delayed
state to the newest IMU sample, and stamped with the time it is for
(:attr:`fuser.model.tick.TickResult.ahead_ns`); the filter's own state
stays at the tick.

The rotation is the last gyro sample's rate, bias removed, held over the
lead (the rate held to the tick's end by :mod:`fuser.model.propagation`,
continued), for at most ``gyro.max_interval_s`` after that sample. Its
error is the held rate's (the random walk of the rate, intensity
``gyro.rate_walk_rad_s_rt_s`` = ``s``): a rate held for ``h`` after its
sample leaves an angle error of variance ``s^2 h^3 / 3``, of which the
part up to the tick's end is already in the published state
(``Motion.hold_variance_rad2``) and the rest, ``s^2 ((a + L)^3 - a^3) / 3``
for a sample ``a`` before the tick and a lead ``L``, is added here. Past
the hold's end, or with no rate at all, the uncertainty grows at
``gyro.gap_rate_rad_s`` (``gyro.range_rad_s`` after a saturated sample), as
in a gap.

How far ahead (``extrapolation.to``): ``"published"``, the instant the loop
publishes the estimate (``latency_ms`` after the tick); ``"hold_midpoint"``,
half a period further, the middle of the interval a consumer holds it;
``"tick"``, not at all (the state at the tick, as it was before).

With the output predictor (``extrapolation.every_imu_sample``, the default)
the loop takes this lead back and turns the state by the gyro's samples
themselves (:mod:`fuser.model.output`); the lead's widening stays, and a
tick without a usable rate (no gyro, a saturated sample) is published as
this module carried it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core import quaternion as quat
from fuser.config import FuserConfig, GyroSettings
from fuser.model.state import GyroTrack

__all__ = ["Lead", "ahead_ns", "carry_ns", "lead"]


def ahead_ns(config: FuserConfig) -> int:
    """How far ahead of its tick the published state's stamp is (ns), from ``extrapolation.to``."""
    if config.extrapolation.to == "tick":
        return 0
    half_period = 0.5e9 / config.rate_hz if config.extrapolation.to == "hold_midpoint" else 0.0
    return round(config.latency_ms * 1e6 + half_period)


def carry_ns(config: FuserConfig) -> int:
    """How far the published state is carried from the filter's (ns): to its stamp, from the instant the IMU's
    samples describe (``extrapolation.imu_delay_ms`` before the tick)."""
    return ahead_ns(config) + round(config.extrapolation.imu_delay_ms * 1e6)


@dataclass(frozen=True, slots=True)
class Lead:
    """The published state's rotation over the lead and the per-axis variance it adds."""

    rotation: np.ndarray | None
    """Body-frame rotation ``u`` (published ``x (x) u``); None: not turned."""
    variance_rad2: float


def lead(gyro: GyroSettings, track: GyroTrack | None, bias_rad_s: np.ndarray, tick_ns: int, ahead: int) -> Lead:
    """The held rate (bias removed) carried from ``tick_ns`` to ``tick_ns + ahead`` (module docstring)."""
    if ahead <= 0:
        return Lead(None, 0.0)
    ahead_s = ahead * 1e-9
    if track is None:
        return Lead(None, (gyro.gap_rate_rad_s * ahead_s) ** 2)
    if track.saturated:
        return Lead(None, (gyro.range_rad_s * ahead_s) ** 2)
    hold_end = track.last_ns + round(gyro.max_interval_s * 1e9)
    held_s = max(0, min(tick_ns + ahead, hold_end) - tick_ns) * 1e-9
    gap_s = ahead_s - held_s
    variance = (gyro.gap_rate_rad_s * gap_s) ** 2
    if held_s == 0.0:
        return Lead(None, variance)
    age_s = (tick_ns - track.last_ns) * 1e-9
    variance += gyro.rate_walk_rad_s_rt_s**2 * ((age_s + held_s) ** 3 - age_s**3) / 3.0
    (x, y, z), (bx, by, bz) = track.last_rate_rad_s, bias_rad_s.tolist()  # 3-vectors in plain floats
    x, y, z = x - bx, y - by, z - bz
    angle = math.sqrt(x * x + y * y + z * z) * held_s
    return Lead(quat.from_rotvec((x * held_s, y * held_s, z * held_s)) if angle > 0.0 else None, variance)
