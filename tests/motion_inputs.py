"""A sensor turning by a known rate profile: its true attitude in closed steps and the perfect readings of it.

The truth is integrated independently of the fuser, at 4 kHz with the exact exponential map (the error over a
minute is far below a thousandth of a degree); the readings are what a perfect IMU at the centre of rotation
reads (no linear acceleration), plus the gyro bias and a magnetic disturbance the test chooses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from core import quaternion as quat
from drivers.samples import ImuSample, Sample
from fuser.model import FusionModel, TickInput
from fusion_inputs import FIELD, GRAVITY_M_S2, SRC

SUBSTEPS = 20
"""Truth integration steps per IMU sample (200 Hz samples: 4 kHz)."""


@dataclass
class Motion:
    t_s: np.ndarray
    q_true: np.ndarray
    """Body FRD -> NED at each sample time."""
    rate_rad_s: np.ndarray
    """True body rate at each sample time."""


def turning(rate: Callable[[float], np.ndarray], seconds: float, imu_hz: float = 200.0, q0=quat.IDENTITY) -> Motion:
    n = int(round(seconds * imu_hz))
    h = 1.0 / imu_hz / SUBSTEPS
    q = np.asarray(q0, dtype=float)
    t_s, qs, rates = [], [], []
    t = 0.0
    for k in range(1, n + 1):
        for _ in range(SUBSTEPS):  # midpoint rule on the rate, exact exponential map
            q = quat.normalize(quat.multiply(q, quat.from_rotvec(rate(t + 0.5 * h) * h)))
            t += h
        t = k / imu_hz
        t_s.append(t)
        qs.append(q.copy())
        rates.append(rate(t))
    return Motion(np.array(t_s), np.array(qs), np.array(rates))


def fly(model: FusionModel, motion: Motion, bias_rad_s=(0.0, 0.0, 0.0), field_extra: Callable[[float, np.ndarray], np.ndarray] | None = None,
        tick_s: float = 0.01, extra: Sequence[Sample] = ()) -> list:
    """Feed the perfect readings (plus ``bias_rad_s`` on the gyro, plus ``field_extra(t, q_true)`` on the
    magnetometer, body frame) and the ``extra`` samples (GNSS fixes, by their time) to ``model`` in ticks of
    ``tick_s``; returns each tick's (t_s, result)."""
    tick_ns = round(tick_s * 1e9)
    imu = []
    for t, q, w in zip(motion.t_s, motion.q_true, motion.rate_rad_s):
        f = quat.rotate(quat.conjugate(q), [0.0, 0.0, -GRAVITY_M_S2])
        m = quat.rotate(quat.conjugate(q), FIELD) + (0.0 if field_extra is None else field_extra(t, q))
        imu.append(ImuSample(round(t * 1e9), tuple(w + np.asarray(bias_rad_s)), tuple(f), tuple(m), SRC))
    out, pending = [], []
    next_tick = tick_ns
    for sample in sorted([*imu, *extra], key=lambda x: x.t_ns):
        while sample.t_ns > next_tick:
            out.append((next_tick * 1e-9, model.step(TickInput(next_tick, tick_ns, pending))))
            pending, next_tick = [], next_tick + tick_ns
        pending.append(sample)
    return out


def truth_at(motion: Motion, t_s: float) -> np.ndarray:
    """The true attitude at ``t_s`` (slerp between the neighbouring samples)."""
    i = int(np.clip(np.searchsorted(motion.t_s, t_s), 1, len(motion.t_s) - 1))
    a, b = motion.q_true[i - 1], motion.q_true[i]
    f = (t_s - motion.t_s[i - 1]) / (motion.t_s[i] - motion.t_s[i - 1])
    d = quat.multiply(quat.conjugate(a), b if a @ b >= 0 else -b)
    return quat.multiply(a, quat.from_rotvec(f * quat.to_rotvec(d)))
