"""The queue between source threads and the loop is bounded: a flood the loop cannot keep up with is counted, not kept."""

import queue
import threading

from drivers.base import SampleSource
from drivers.samples import ImuSample, SourceId
from fuser.live import _SourceThread
from fuser.wallclock import WallClock

SRC = SourceId("test", 1, 1, 0)


class _Burst(SampleSource):
    """Returns ``n`` samples on the first poll, then stops the thread."""

    def __init__(self, n: int, stop: threading.Event) -> None:
        self.stats = {}
        self.n, self.stop = n, stop

    def poll(self, timeout: float) -> list:
        self.stop.set()
        n, self.n = self.n, 0
        return [ImuSample(1_000 + k, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81), None, SRC) for k in range(n)]


def test_a_full_queue_drops_and_counts_the_overflow():
    stop = threading.Event()
    out: queue.Queue = queue.Queue(5)
    thread = _SourceThread("burst", _Burst(8, stop), out, stop, WallClock.start())
    thread.start()
    thread.join(timeout=5)
    assert out.qsize() == 5
    assert [out.get_nowait()[0].t_ns for _ in range(5)] == [1_000, 1_001, 1_002, 1_003, 1_004]  # the first ones kept, in order
    assert thread.queue_full == 3 and thread.health(0)["queue_full"] == 3
