"""The live timeline: the monotonic clock for pacing, shifted once onto Unix time for every time stamp.

A live run (``run``, a paced ``sim``) stamps each received sample, each tick,
each estimate and each status with ``unix_ns = monotonic_ns + offset_ns``,
the offset measured once at start. So every channel of a recording and every
zenoh payload is on one timeline in nanoseconds since the Unix epoch (a
recording opens in Foxglove at the date it was made), while the loop paces
on a clock that never steps: an NTP correction during the run moves nothing.
The offset is recorded in the MCAP metadata (:meth:`WallClock.metadata`), so
the monotonic time of any record can be recovered. Replay keeps the log's
own times; a ``sim --speed 0`` run keeps the simulated flight's clock.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

__all__ = ["WallClock"]

_SAMPLES = 5
"""Readings taken to measure the offset; the one bracketed most tightly by two monotonic reads wins."""


@dataclass(frozen=True)
class WallClock:
    """``now_ns()`` = ``time.monotonic_ns() + offset_ns``: monotonic, on the Unix epoch."""

    offset_ns: int
    """Unix time minus monotonic time, ns, measured once."""

    @classmethod
    def start(cls) -> WallClock:
        """Measure the offset now: the Unix time read between two monotonic reads, the tightest of a few."""
        best: tuple[int, int] | None = None
        for _ in range(_SAMPLES):
            before = time.monotonic_ns()
            unix = time.time_ns()
            after = time.monotonic_ns()
            if best is None or after - before < best[0]:
                best = (after - before, unix - (before + after) // 2)
        assert best is not None
        return cls(best[1])

    def now_ns(self) -> int:
        return time.monotonic_ns() + self.offset_ns

    def metadata(self) -> dict[str, str]:
        """The mapping, for the recording's metadata (see fuser/IO.md)."""
        return {"time": "unix", "unix_minus_monotonic_ns": str(self.offset_ns)}
