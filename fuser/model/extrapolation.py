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
``gyro.rate_walk_rad_s_rt_s`` = ``s``, or the rougher one the last samples
showed, :func:`fuser.model.propagation.rate_walk2`): a rate held for ``h`` after its
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

:func:`lead` is compiled with numba for the tick (:func:`fuser.model.fusion.tick`)
and reads the state's gyro track (:data:`fuser.model.state.GYRO`);
:func:`ahead_ns` and :func:`carry_ns` are the model's, computed once.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.quaternion_kernels import IDENTITY, from_rotvec
from fuser.config import FuserConfig
from fuser.model.propagation import rate_walk2
from fuser.model.tick import Lead

__all__ = ["ahead_ns", "carry_ns", "lead"]


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


@njit(cache=True, nogil=True)
def lead(params: np.record, gyro: np.record, bias_rad_s: tuple, tick_ns: int, ahead: int) -> Lead:
    """The held rate (bias removed) carried from ``tick_ns`` to ``tick_ns + ahead`` (module docstring); ``params``
    the ``gyro`` group, ``gyro`` the state's (:data:`fuser.model.state.GYRO`, its track after the tick). Not turned
    (``has_rotation`` False, the identity) without a held rate."""
    if ahead <= 0:
        return Lead(False, IDENTITY, 0.0)
    ahead_s = ahead * 1e-9
    if not gyro.has_track:
        gap = params.gap_rate_rad_s * ahead_s
        return Lead(False, IDENTITY, gap * gap)
    track = gyro.track
    if track.saturated:
        unknown = params.range_rad_s * ahead_s
        return Lead(False, IDENTITY, unknown * unknown)
    hold_end = track.last_ns + round(params.max_interval_s * 1e9)
    held_s = max(0, min(tick_ns + ahead, hold_end) - tick_ns) * 1e-9
    gap = params.gap_rate_rad_s * (ahead_s - held_s)
    variance = gap * gap
    if held_s == 0.0:
        return Lead(False, IDENTITY, variance)
    age_s = (tick_ns - track.last_ns) * 1e-9
    end_s = age_s + held_s
    variance += rate_walk2(params, track, tick_ns) * (end_s * end_s * end_s - age_s * age_s * age_s) / 3.0
    rate = track.last_rate_rad_s
    x, y, z = rate[0] - bias_rad_s[0], rate[1] - bias_rad_s[1], rate[2] - bias_rad_s[2]
    angle = math.sqrt(x * x + y * y + z * z) * held_s
    if angle > 0.0:
        return Lead(True, from_rotvec(x * held_s, y * held_s, z * held_s), variance)
    return Lead(False, IDENTITY, variance)
