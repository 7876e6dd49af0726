"""Hand-made inputs for the fusion model's tests: perfect IMU readings of a known attitude, and ticks."""

from __future__ import annotations

import numpy as np

from core import quaternion as quat
from drivers.samples import ImuSample, Sample, SourceId
from fuser.model import TickInput

SRC = SourceId("sim", 1, 1, 0)
FIELD = np.array([0.21, 0.0, 0.43])
"""The default reference field of fuser.config.MagSettings (north, east, down; gauss)."""
GRAVITY_M_S2 = 9.80665
TICK = 10_000_000  # 100 Hz


def tick(samples: list[Sample], t_ns: int, dt_ns: int = TICK) -> TickInput:
    """One tick ending at ``t_ns`` whose samples' own times are on the loop's clock."""
    return TickInput(t_ns, dt_ns, samples)


def imu_at(q, t_ns, gyro=(0.0, 0.0, 0.0), accel_extra=(0.0, 0.0, 0.0), mag=True, mag_extra=(0.0, 0.0, 0.0), source=SRC):
    """A perfect IMU reading of attitude q (body FRD -> NED): specific force of a body at rest."""
    f = quat.rotate(quat.conjugate(q), [0.0, 0.0, -GRAVITY_M_S2]) + np.asarray(accel_extra)
    m = quat.rotate(quat.conjugate(q), FIELD) + np.asarray(mag_extra) if mag else None
    return ImuSample(t_ns, tuple(gyro), tuple(f), None if m is None else tuple(m), source)
