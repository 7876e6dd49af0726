"""The live runner's publish latency is measured from each tick's due time (its tick time plus the wait),
not from the estimate's stamp, which the extrapolation puts ahead of the tick (fuser.model.extrapolation)."""

from dataclasses import dataclass

import pytest

from drivers.samples import ImuSample, SourceId
from fuser.config import FuserConfig
from fuser.live import LiveRunner
from fuser.pipeline import Pipeline

SRC = SourceId("test", 1, 1, 0)
PERIOD_NS = 10_000_000


@dataclass
class _Clock:
    """A clock the test sets: what LiveRunner reads when an estimate reaches its last sink."""

    t_ns: int = 0

    def now_ns(self) -> int:
        return self.t_ns


@pytest.mark.parametrize("to, every_imu_sample, ahead_ms", [("published", False, 5.0), ("hold_midpoint", False, 10.0), ("tick", False, 0.0),
                                                          ("hold_midpoint", True, 5.0)])  # the output predictor: stamped when due
def test_latency_is_measured_from_the_tick_due_time(to, every_imu_sample, ahead_ms):
    config = FuserConfig().replace(rate_hz=100.0, latency_ms=5.0, latency={"adaptive": False},
                                   extrapolation={"to": to, "every_imu_sample": every_imu_sample})
    clock = _Clock()
    pipeline = Pipeline(config, [], [])
    runner = LiveRunner(pipeline, {}, clock=clock)  # type: ignore[arg-type]
    stamps = []
    pipeline.outputs.insert(0, lambda est: stamps.append(est.t_ns))
    t0 = 1_000_000_000
    for k in range(21):  # 200 Hz up to the tick, received on time: every tick waits the configured 5 ms
        t = t0 + k * 5_000_000
        pipeline.feed(ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81), None, SRC), t)
    tick_ns = t0 + 10 * PERIOD_NS
    clock.t_ns = tick_ns + 5_000_000 + 1_234_000  # 1.234 ms after that tick was due
    pipeline.advance(clock.t_ns)  # runs that tick alone: the ones before it ran as the samples came
    assert stamps, "no tick ran"
    assert stamps[-1] == tick_ns + round(ahead_ms * 1e6)  # the stamp is the time the state is for: ahead of the tick
    assert runner.latencies_ns[-1] == 1_234_000
    assert runner.counters["overruns"] == 0
