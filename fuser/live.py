"""Live operation: sources in threads, the loop paced by the wall clock, status once a second.

Each source is polled in its own thread, which stamps every sample with the
:class:`~fuser.wallclock.WallClock` (the monotonic clock on the Unix epoch) as
it arrives; the main thread feeds them to the
:class:`~fuser.pipeline.Pipeline` and runs each tick at its due time, so
ticks, estimates and status are all in Unix nanoseconds. A tick
that finishes after the next one is due is counted as an overrun (it is
still published: nothing is dropped). Publish latency is measured from a
tick's due time to the moment its estimate has been handed to zenoh.
"""

from __future__ import annotations

import gc
import logging
import queue
import threading
import time
from collections import Counter, deque
from typing import Callable, Iterable

import numpy as np

from drivers.base import SampleSource
from drivers.samples import AttitudeSample, ImuSample, Sample, SourceId
from fuser.codec import Estimate
from fuser.inputs import silence_hint
from fuser.model import FusionModel, TickInput
from fuser.pipeline import STATUS_PERIOD_NS, Pipeline
from fuser.wallclock import WallClock

__all__ = ["LiveRunner"]

log = logging.getLogger("bingham_fuser.live")


STALL_NS = 500_000_000
"""A source silent this long after it has delivered is counted once as a stall (link down, sender gone)."""

SPIN_NS = 300_000
"""The loop blocks for samples until this long before a tick is due, then polls for them until the tick:
a blocking wait wakes 0.1-0.3 ms late (timer slack, scheduling), polling wakes on time (2% of a core at 100 Hz)."""


SILENT_START_NS = 5_000_000_000
"""A source that has delivered no sample this long after the run started says what it did receive, once."""

MAX_QUEUED_SAMPLES = 20_000
"""Samples waiting between the source threads and the loop (50 s of a 400 Hz IMU): beyond it, a sample is
dropped and counted (``queue_full``) rather than memory growing while the loop cannot keep up."""


class _SourceThread(threading.Thread):
    """Polls one source until stopped; a failing poll is counted, logged and retried; silences are counted as stalls."""

    def __init__(self, name: str, source: SampleSource, out: queue.Queue, stop: threading.Event, clock: WallClock) -> None:
        super().__init__(name=f"source-{name}", daemon=True)
        self.label = name
        self.clock = clock
        self.source = source
        self.out = out
        self.stop = stop
        self.errors = 0
        self.stalls = 0
        self.queue_full = 0
        self.last_sample_ns: int | None = None
        self._stalled = False
        self._silent_since_ns: int | None = None
        """When the run started, until the source has delivered or its silence has been told."""

    def health(self, now_ns: int) -> dict:
        silent = None if self.last_sample_ns is None else round((now_ns - self.last_sample_ns) / 1e9, 3)
        return {"poll_errors": self.errors, "stalls": self.stalls, "queue_full": self.queue_full, "silent_s": silent}

    def run(self) -> None:
        self._silent_since_ns = self.clock.now_ns()
        while not self.stop.is_set():
            try:
                samples = self.source.poll(0.05)
            except Exception as exc:  # a driver must never take the fuser down
                self.errors += 1
                if self.errors == 1 or self.errors % 100 == 0:
                    log.warning("source %s failed to poll (%d times): %s", self.label, self.errors, exc)
                self.stop.wait(0.1)
                continue
            now = self.clock.now_ns()
            if samples:
                self.last_sample_ns, self._stalled, self._silent_since_ns = now, False, None
            elif self._silent_since_ns is not None and now - self._silent_since_ns > SILENT_START_NS:
                self._silent_since_ns = None
                log.warning("no sample in %.0f s: %s", SILENT_START_NS / 1e9, silence_hint(self.label, self.source.stats, self.source.transport))
            elif not self._stalled and self.last_sample_ns is not None and now - self.last_sample_ns > STALL_NS:
                self._stalled = True
                self.stalls += 1
                log.warning("source %s silent for %.1f s (stall %d)", self.label, (now - self.last_sample_ns) / 1e9, self.stalls)
            for s in samples:
                try:
                    self.out.put_nowait((s, now))
                except queue.Full:
                    self.queue_full += 1


def _warm_up(pipeline: Pipeline) -> None:
    """Run a few ticks on a throwaway model so that loading the compiled kernels (about 0.3 s) is not the first live tick's latency."""
    model = FusionModel(pipeline.loop.config)
    src = SourceId("warm-up", 0, 0, 0)
    for k in range(4):
        t = (k + 1) * 10_000_000
        imu = [] if k == 3 else [ImuSample(t - 5_000_000, (0.01, 0.0, 0.0), (0.0, 0.0, -9.8), (0.21, 0.0, 0.43), src),
                                 ImuSample(t, (0.01, 0.0, 0.0), (0.0, 0.0, -9.8), (0.21, 0.0, 0.43), src)]
        model.step(TickInput(t, 10_000_000, [*imu, AttitudeSample(t, (1.0, 0.0, 0.0, 0.0), src)]))


BACKLOG_MAX_S = 1.0
"""Longest :func:`discard_backlog` reads (a flooding source never runs dry)."""


def discard_backlog(sources: dict[str, SampleSource]) -> None:
    """Drop what the open sources queued before the run started (``run``'s warm-up: up to its length old, it would
    reach the loop stamped as just received), counting it in each source's ``stats`` as ``warm_up_discarded``; a
    source whose poll fails is left to its reader thread, which counts and reports that."""
    deadline = time.monotonic() + BACKLOG_MAX_S
    for source in sources.values():
        try:
            while time.monotonic() < deadline and (stale := source.poll(0.0)):
                source.stats["warm_up_discarded"] += len(stale)
        except Exception:  # noqa: BLE001 - a driver's poll may raise anything; its reader thread handles it
            continue


class LiveRunner:
    """Runs a pipeline on live sources until ``stop()`` or ``duration_s``, on ``clock`` (default: measured now)."""

    def __init__(
        self,
        pipeline: Pipeline,
        sources: dict[str, SampleSource],
        status_sinks: Iterable[Callable[[int, dict], None]] = (),
        health: Callable[[], dict] = dict,
        clock: WallClock | None = None,
    ) -> None:
        self.pipeline = pipeline
        self.clock = WallClock.start() if clock is None else clock
        self.sources = sources
        self.status_sinks = list(status_sinks)
        self.health = health
        self.stop_event = threading.Event()
        self.counters: Counter[str] = Counter()
        self.latencies_ns: deque[int] = deque(maxlen=10_000)
        self._queue: queue.Queue[tuple[Sample, int]] = queue.Queue(MAX_QUEUED_SAMPLES)
        self._threads = [_SourceThread(n, s, self._queue, self.stop_event, self.clock) for n, s in sources.items()]
        pipeline.outputs.append(self._measure)

    def stop(self) -> None:
        self.stop_event.set()

    def _measure(self, est: Estimate) -> None:
        """Last sink of every estimate: latency from due time, overrun if the next tick is already due."""
        now = self.clock.now_ns()
        loop = self.pipeline.loop
        due = loop.due_ns(est)
        self.latencies_ns.append(now - due)
        if now > due + loop.period_ns:
            self.counters["overruns"] += 1

    def status(self) -> dict:
        """Health and counters, as published on ``.../status`` and recorded on ``/status``."""
        now = self.clock.now_ns()
        lat = np.array(self.latencies_ns, dtype=float) / 1e6
        latency = {} if lat.size == 0 else {"p50_ms": float(np.percentile(lat, 50)), "p99_ms": float(np.percentile(lat, 99)), "max_ms": float(lat.max())}
        return {
            **self.pipeline.status(),
            "sources": {name: {**dict(src.stats), **t.health(now)} for (name, src), t in zip(self.sources.items(), self._threads)},
            "runner": dict(self.counters),
            "latency": latency,
            **self.health(),
        }

    def _feed_waiting(self, wait_ns: int) -> None:
        """Feed the samples queued now, first waiting up to ``wait_ns`` for one if ``wait_ns`` > 0. Only those: a
        source that refills the queue as fast as it is read (a flood of the vehicle's own frames, 43k packets/s) kept
        the loop here for the flood's whole length, with no tick and no status (estimates 3.1 s late); what comes
        meanwhile waits for the next pass, the bounded queue dropping and counting the overflow."""
        try:
            if wait_ns > 0:
                self.pipeline.feed(*self._queue.get(timeout=wait_ns / 1e9))
            for _ in range(self._queue.qsize()):
                self.pipeline.feed(*self._queue.get_nowait())
        except queue.Empty:
            pass

    def run(self, duration_s: float | None = None, on_start: Callable[[], None] | None = None) -> dict:
        """Run until stopped (or for ``duration_s``); returns the final status. ``on_start`` is called once the
        sources are read (what they queued before is dropped, :func:`discard_backlog`): a sample sent after it is
        fused."""
        _warm_up(self.pipeline)
        gc.collect()
        gc.freeze()  # start-up built ~170k long-lived objects (modules, kernels): a full collection over them takes ~80 ms
        discard_backlog(self.sources)
        for t in self._threads:
            t.start()
        if on_start is not None:
            on_start()
        start = self.clock.now_ns()
        next_status = start + STATUS_PERIOD_NS
        try:
            while not self.stop_event.is_set():
                now = self.clock.now_ns()
                if duration_s is not None and now - start >= duration_s * 1e9:
                    break
                due = self.pipeline.loop.next_due_ns
                self._feed_waiting(50_000_000 if due is None else min(due - SPIN_NS - now, 50_000_000))
                now = self.clock.now_ns()
                self.pipeline.advance(now)
                if now >= next_status:
                    next_status += STATUS_PERIOD_NS
                    status = self.status()
                    for sink in self.status_sinks:
                        sink(now, status)
        finally:
            self.stop_event.set()
            for t in self._threads:
                t.join(timeout=2.0)
        return self.status()
