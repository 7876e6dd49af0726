"""The state's fixed slots: 16 IMUs and 8 GNSS streams of the one vehicle; what comes beyond them is counted, not fused.

The compiled tick keeps each IMU's latest sample (the IMU check) and each GNSS stream's last fix (velocity
aiding) in slots of the state record (:mod:`fuser.model.state`). A vehicle has at most a few of either; a
log or a bus with more (a corrupt source id, a replay of many vehicles' samples through one model) must not
crash the tick or overwrite another IMU's slot.
"""

from __future__ import annotations

import numpy as np

from drivers.samples import GnssSample, ImuSample, SourceId
from fuser.config import FuserConfig
from fuser.model import FusionModel, TickInput
from fuser.model.state import MAX_GNSS_STREAMS, MAX_IMUS

TICK_NS = 10_000_000


def _imu(instance: int, t_ns: int) -> ImuSample:
    return ImuSample(t_ns, (0.01, 0.0, 0.0), (0.0, 0.0, -9.80665), (0.21, 0.0, 0.43), SourceId("mavlink", 1, 1, instance))


def _fix(system: int, t_ns: int) -> GnssSample:
    return GnssSample(t_ns, 3, (1.0, 0.0, 0.0), True, 0.3, None, None, None, False, SourceId("mavlink", system, 1, 0))


def test_imus_beyond_the_slots_are_counted_and_kept_out():
    model = FusionModel(FuserConfig())
    extra = 3
    samples = [_imu(i, TICK_NS // 2) for i in range(MAX_IMUS + extra)]
    result = model.step(TickInput(TICK_NS, TICK_NS, samples))
    assert result.counters["imu_too_many"] == extra
    assert int(np.count_nonzero(model.state.imu_check.seen)) == MAX_IMUS  # the first 16 kept their slots
    assert len(model.state.imu_slots) == MAX_IMUS
    again = model.step(TickInput(2 * TICK_NS, TICK_NS, [_imu(MAX_IMUS + 1, 3 * TICK_NS // 2), _imu(0, 3 * TICK_NS // 2)]))
    assert again.counters["imu_too_many"] == extra + 1  # a later sample of an IMU beyond them, again
    assert np.isfinite(again.published.Z).all()


def test_gnss_streams_beyond_the_slots_are_counted_and_not_fused():
    model = FusionModel(FuserConfig())
    extra = 2
    fixes = [_fix(system, TICK_NS // 2) for system in range(1, MAX_GNSS_STREAMS + extra + 1)]
    result = model.step(TickInput(TICK_NS, TICK_NS, [_imu(0, TICK_NS // 2), *fixes]))
    assert result.counters["gnss_too_many"] == extra
    assert len(model.state.gnss_slots) == MAX_GNSS_STREAMS
    assert int(np.count_nonzero(model.state.velocity.stream_seen)) == MAX_GNSS_STREAMS
