"""The one data path after the drivers: loop, then sinks (recorder, publisher).

Live, simulated and replayed inputs all enter through :meth:`Pipeline.feed`
with the time the fuser received them, so every line after the driver is
shared and a replay reproduces a recording's estimates.
"""

from __future__ import annotations

from typing import Callable, Sequence

from drivers.samples import Sample
from fuser.codec import Estimate
from fuser.config import FuserConfig
from fuser.loop import FusionLoop

__all__ = ["STATUS_PERIOD_NS", "EstimateSink", "InputSink", "Pipeline"]

STATUS_PERIOD_NS = 1_000_000_000
"""The status (:meth:`Pipeline.status` and the outputs' health) goes out once a second: of wall time live, of
flight time in a simulated run."""

InputSink = Callable[[Sample, int], None]
"""Receives every input sample with its receive time (e.g. ``McapRecorder.write_sample``)."""
EstimateSink = Callable[[Estimate], None]
"""Receives every estimate (e.g. ``McapRecorder.write_estimate``, ``ZenohPublisher.publish_estimate``)."""


class Pipeline:
    """A :class:`FusionLoop` wired to sinks."""

    def __init__(
        self,
        config: FuserConfig,
        inputs: Sequence[InputSink] = (),
        outputs: Sequence[EstimateSink] = (),
        max_catch_up_ticks: int | None = None,
    ) -> None:
        self.loop = FusionLoop(config, max_catch_up_ticks)
        self.inputs = list(inputs)
        self.outputs = list(outputs)
        self.estimates = 0

    def feed(self, sample: Sample, receive_ns: int) -> None:
        """Run the ticks due before this sample arrived, then record and buffer it (and emit the output
        predictor's estimate at it, ``extrapolation.every_imu_sample``)."""
        self.advance(receive_ns)
        for sink in self.inputs:
            sink(sample, receive_ns)
        self._emit(self.loop.push(sample, receive_ns))

    def advance(self, now_ns: int) -> None:
        """Run every tick due at ``now_ns``."""
        self._emit(self.loop.advance(now_ns))

    def finish(self) -> None:
        """Run the ticks that cover the samples still buffered (end of input)."""
        self._emit(self.loop.flush())

    def status(self) -> dict:
        """The loop's part of the status (``.../status``, ``/status``): estimates so far, the loop's and the
        model's counters, the last tick's update diagnostics (fuser/IO.md, "Status")."""
        return {
            "estimates": self.estimates,
            "loop": dict(self.loop.counters),
            "model": dict(self.loop.model.counters),
            "diagnostics": self.loop.diagnostics(),
        }

    def _emit(self, estimates: list[Estimate]) -> None:
        for est in estimates:
            for sink in self.outputs:
                sink(est)
            self.estimates += 1
