"""Offline replay: a recorded log through the same loop on a virtual clock, as fast as possible.

The clock is the recorded receive time of each sample, so ticks fall exactly
where they fell live, and two replays of one log write byte-identical
files. The output MCAP holds the inputs again (so it can itself be
replayed), the estimates, and the log's truth if it had any. Inputs and
truth from an MCAP log are copied as they are stored (JSON bytes), not
decoded and encoded again.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, TextIO

from drivers.samples import Sample
from fuser.codec import decode_sample, loads
from fuser.config import FuserConfig
from fuser.inputs import tlog_inputs
from fuser.pipeline import Pipeline
from fuser.record import INPUT_TOPICS, LogContents, McapRecorder, read_log

__all__ = ["ReplaySummary", "replay"]

MAX_CATCH_UP_TICKS = 1000
"""A gap in a log longer than this many ticks is skipped (counted), not filled tick by tick."""


@dataclass(frozen=True)
class ReplaySummary:
    samples: int
    estimates: int
    seconds: float
    counters: dict[str, int]

    @property
    def samples_per_s(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")


class _Progress:
    """One self-overwriting status line on a terminal, at most twice a second."""

    def __init__(self, stream: TextIO | None) -> None:
        self.stream = stream if stream is not None and stream.isatty() else None
        self.start = time.monotonic()
        self.last = 0.0

    def update(self, samples: int, log_s: float) -> None:
        now = time.monotonic()
        if self.stream is None or now - self.last < 0.5:
            return
        self.last = now
        rate = samples / max(now - self.start, 1e-9)
        self.stream.write(f"\rreplay: {samples:,} samples, {log_s:,.1f} s of log, {rate:,.0f} samples/s")
        self.stream.flush()

    def done(self) -> None:
        if self.stream is not None:
            self.stream.write("\n")


def _copied_inputs(contents: LogContents, pipeline: Pipeline, recorder: McapRecorder) -> Iterator[tuple[Sample, int]]:
    """An MCAP log's inputs, each written unchanged to ``recorder`` where an input sink of the pipeline would write it."""
    for m in contents.of(INPUT_TOPICS):
        sample, receive_ns = decode_sample(m.topic, loads(m.data))
        pipeline.advance(receive_ns)  # as in Pipeline.feed: the ticks due before the sample are recorded before it
        recorder.write_message(m.topic, receive_ns, sample.t_ns, m.data)
        yield sample, receive_ns


def replay(log: str | Path, out: str | Path, config: FuserConfig, progress: TextIO | None = sys.stderr) -> ReplaySummary:
    """Fuse every input of ``log`` (MCAP or .tlog) and record the result to ``out``."""
    bar = _Progress(progress)
    start = time.monotonic()
    samples = 0
    first_ns: int | None = None
    with McapRecorder(out, metadata={"source_log": Path(log).name}) as recorder:
        pipeline = Pipeline(config, [], [recorder.write_estimate], MAX_CATCH_UP_TICKS)
        contents = None if str(log).endswith(".tlog") else read_log(log)
        if contents is None:
            pipeline.inputs.append(recorder.write_sample)
        for sample, receive_ns in (tlog_inputs(log) if contents is None else _copied_inputs(contents, pipeline, recorder)):
            pipeline.feed(sample, receive_ns)
            samples += 1
            first_ns = receive_ns if first_ns is None else first_ns
            if samples % 4096 == 0:
                bar.update(samples, (receive_ns - first_ns) * 1e-9)
        pipeline.finish()
        if contents is not None:
            for truth in contents.of(["/truth/pose"]):
                recorder.write_message(*truth)
    bar.done()
    counters = dict(pipeline.loop.counters) | dict(pipeline.loop.model.counters)
    return ReplaySummary(samples, pipeline.estimates, time.monotonic() - start, counters)
