"""Cross-checks between a vehicle's IMUs: a sample that disagrees with the others is kept out.

Every IMU of a rigid vehicle measures the same body rate and (up to
vibration and lever arm) the same specific force. Each sample is compared
with the other IMUs' latest samples taken within ``compare_within_s``: its
rate must lie within ``disagree_rad_s + angular_accel_rad_s2 |dt|`` and its
specific force within ``disagree_m_s2`` of theirs. With three or more IMUs
the comparison is against their median, so the one that disagrees is known;
with two, the rougher of the pair (the larger low-passed squared change of
rate from one of its samples to the next: random data is rough, a working
gyro smooth) is the one kept out. Kept-out samples never reach the
integration or the updates; they are counted, and the published estimate is
widened while the check keeps something out (``fault_sigma_deg``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from drivers.samples import ImuSample, SourceId, Vec3
from fuser.config import ImuCheckSettings

__all__ = ["ImuCheckState", "ImuLatest", "check_imus"]


@dataclass(frozen=True, slots=True)
class ImuLatest:
    """One IMU's latest sample (time on the loop's timeline) and its roughness ((rad/s)^2)."""

    t_ns: int
    gyro_rad_s: Vec3
    accel_m_s2: Vec3
    roughness_rad2_s2: float


@dataclass(frozen=True, slots=True)
class ImuCheckState:
    latest: Mapping[SourceId, ImuLatest] = field(default_factory=dict)
    last_fault_ns: int | None = None
    """When a sample was last kept out."""


def _roughness(params: ImuCheckSettings, before: ImuLatest | None, s: ImuSample, t_ns: int) -> float:
    if before is None:
        return 0.0
    (x, y, z), (bx, by, bz) = s.gyro_rad_s, before.gyro_rad_s
    step2 = (x - bx) ** 2 + (y - by) ** 2 + (z - bz) ** 2
    a = min(1.0, (t_ns - before.t_ns) * 1e-9 / params.roughness_s)
    return before.roughness_rad2_s2 + a * (step2 - before.roughness_rad2_s2)


def _agrees(params: ImuCheckSettings, gyro: np.ndarray, accel: np.ndarray, ref_gyro: np.ndarray, ref_accel: np.ndarray, dt_s: float) -> bool:
    rate_gap = gyro - ref_gyro
    force_gap = accel - ref_accel
    return (math.sqrt(float(rate_gap @ rate_gap)) <= params.disagree_rad_s + params.angular_accel_rad_s2 * dt_s
            and math.sqrt(float(force_gap @ force_gap)) <= params.disagree_m_s2)


def check_imus(params: ImuCheckSettings, state: ImuCheckState, samples: Sequence[ImuSample], placed_ns: Sequence[int]
               ) -> tuple[ImuCheckState, list[int], int]:
    """The state after the tick's IMU samples, the indices of the samples kept, and how many were kept out."""
    latest = dict(state.latest)
    kept: list[int] = []
    out = 0
    last_fault = state.last_fault_ns
    window_ns = params.compare_within_s * 1e9
    for i in sorted(range(len(samples)), key=lambda k: placed_ns[k]):
        s, t = samples[i], placed_ns[i]
        mine = ImuLatest(t, s.gyro_rad_s, s.accel_m_s2, _roughness(params, latest.get(s.source), s, t))
        latest[s.source] = mine
        others = [o for src, o in latest.items() if src != s.source and t - o.t_ns <= window_ns] if len(latest) > 1 else []
        good = True
        if params.enabled and others:
            gyro, accel = np.asarray(s.gyro_rad_s), np.asarray(s.accel_m_s2)
            if len(others) >= 2:
                ref_gyro = np.median([o.gyro_rad_s for o in others] + [s.gyro_rad_s], axis=0)
                ref_accel = np.median([o.accel_m_s2 for o in others] + [s.accel_m_s2], axis=0)
                good = _agrees(params, gyro, accel, ref_gyro, ref_accel, max(t - o.t_ns for o in others) * 1e-9)
            else:
                (other,) = others
                good = _agrees(params, gyro, accel, np.asarray(other.gyro_rad_s), np.asarray(other.accel_m_s2), (t - other.t_ns) * 1e-9) \
                    or mine.roughness_rad2_s2 <= other.roughness_rad2_s2
        if good:
            kept.append(i)
        else:
            out += 1
            last_fault = t
    return ImuCheckState(latest, last_fault), sorted(kept), out
