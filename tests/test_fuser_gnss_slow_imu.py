"""An IMU slower than the loop, with GNSS fixes that arrive between its samples (as an ArduPilot DataFlash log at
LOG_BITMASK's 50 Hz IMU rate holds them: each GPS record at the time the autopilot received the fix, on no IMU
sample's time), scored against the simulator's truth.

The simulated multirotor's first 30 s with a 50 Hz IMU, fused by the default 100 Hz loop: every other tick has no
IMU sample, and the fixes are received 10 ms after the IMU sample they came with (in the ticks without one). The
aided gravity update reads the GNSS low-pass only in ticks with an IMU sample: a pair fused in a tick without one
was never read, and the next reading's spacing was counted from it. Measured before on a reviewer's ArduPilot-shaped
DataFlash log (one IMU at 50 Hz, GPS at 5 Hz with its vertical velocity, 150 s): 123 deg RMS against the log's EKF3
attitude, the tilt 41-52 deg off from 30 s on, reporting 28-70; three IMUs at 25 Hz 64.8 deg; the same logs at a
50 Hz loop 1.7 deg. Now the reading is taken at the next tick with an IMU sample (fuser/model/velocity.py,
``reading_due``): 1.8 and 2.0 deg on those logs.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drivers.samples import GnssSample
from drivers.sim import SimConfig, simulate
from fuser.config import FuserConfig
from test_fuser_gnss_flights import TOTAL_BOUND_DEG, _fly, received

IMU_RATE_HZ = 50.0
GNSS_AFTER_IMU_NS = 10_000_000
"""The fixes are received this long after the IMU sample they were sent with: half the IMU's period."""


def _between_imu_samples(flight, after_ns: int):
    """The flight's deliveries with every GNSS fix stamped and received ``after_ns`` later, on its own (a fix stamped
    at the IMU's times is placed in the tick of the IMU sample it came with)."""
    held: list[tuple[int, list]] = []
    for receive_ns, samples in received(flight):
        while held and held[0][0] <= receive_ns:
            yield held.pop(0)
        fixes = [dataclasses.replace(s, t_ns=s.t_ns + after_ns) for s in samples if isinstance(s, GnssSample)]
        yield receive_ns, [s for s in samples if not isinstance(s, GnssSample)]
        if fixes:
            held.append((receive_ns + after_ns, fixes))
    yield from held


def test_fixes_between_the_samples_of_a_slower_imu_count_as_much_as_fixes_with_them():
    """Against the same flight with its fixes on the IMU's ticks (measured 1.29 deg RMS, reporting 3.38, 97 % inside the
    90 % region): before, 2.99 deg reporting 8.84 (1.56 and 3.36 on the ticks); now 1.28 reporting 3.39."""
    flight = simulate(SimConfig(seed=0, duration_s=30.0, imu_rate_hz=IMU_RATE_HZ))
    on_ticks, _ = _fly(flight, FuserConfig(), deliveries=_between_imu_samples(flight, 0))
    counters: dict = {}
    between, level = _fly(flight, FuserConfig(), counters=counters, deliveries=_between_imu_samples(flight, GNSS_AFTER_IMU_NS))
    assert counters.get("gnss_fused", 0) > 250, counters  # the fixes were used (10 Hz over 30 s)
    assert between["total"] < 1.2 * on_ticks["total"], (between, on_ticks)
    assert between["uncertainty"] < 1.2 * on_ticks["uncertainty"], (between, on_ticks)
    assert between["total"] < TOTAL_BOUND_DEG["multirotor"], between
    assert np.mean(level <= 0.9) >= 0.85, np.mean(level <= 0.9)
