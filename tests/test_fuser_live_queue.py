"""The queue between source threads and the loop is bounded: a flood the loop cannot keep up with is counted, not kept."""

import queue
import threading

from drivers.base import SampleSource
from drivers.samples import ImuSample, SourceId
from fuser.live import LiveRunner, _SourceThread
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


class _RefillingPipeline:
    """A pipeline whose every fed sample is followed by another in the queue: a source as fast as the loop reads."""

    def __init__(self, q: queue.Queue) -> None:
        self.queue, self.fed = q, 0

    def feed(self, sample, receive_ns: int) -> None:
        self.fed += 1
        self.queue.put_nowait((sample, receive_ns))


def test_a_source_that_keeps_the_queue_full_cannot_hold_the_loop_from_its_ticks():
    """One pass feeds what was queued when it began, then the runner ticks: before, a flood that refilled the queue
    as fast as it was read kept the runner feeding (no tick, no status) for as long as the flood lasted."""
    runner = LiveRunner.__new__(LiveRunner)  # only the queue and the pipeline take part in a pass
    runner._queue = queue.Queue(100)
    runner.pipeline = _RefillingPipeline(runner._queue)
    sample = ImuSample(1_000, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81), None, SRC)
    for k in range(10):
        runner._queue.put_nowait((sample, k))
    done = threading.Event()
    worker = threading.Thread(target=lambda: (runner._feed_waiting(0), done.set()), daemon=True)
    worker.start()
    assert done.wait(timeout=10.0), "the pass never ended while the queue stayed full"
    assert runner.pipeline.fed == 10  # what was queued when the pass began; the refills wait for the next
    assert runner._queue.qsize() == 10
