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

A paced ``sim --speed X`` (X other than 1) runs its clock X times as fast as
the monotonic clock, from the Unix time at its start: the loop then ticks at
its rate in the flight's time, as it would live (a clock at wall speed would
give a 4x-accelerated flight a quarter of the estimates). Its times are
Unix times only at the start; the metadata records the speed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

__all__ = ["WallClock"]

_SAMPLES = 5
"""Readings taken to measure the offset; the one bracketed most tightly by two monotonic reads wins."""


@dataclass(frozen=True)
class WallClock:
    """``now_ns()`` = ``time.monotonic_ns() + offset_ns``: monotonic, on the Unix epoch (at ``speed`` 1)."""

    offset_ns: int
    """Unix time minus monotonic time, ns, measured once."""
    start_monotonic_ns: int = 0
    """Monotonic time at the start, from which a clock of another ``speed`` runs."""
    speed: float = 1.0
    """How many nanoseconds this clock advances per monotonic nanosecond (``sim --speed``)."""

    def __post_init__(self) -> None:
        if not self.speed > 0:
            raise ValueError(f"clock speed must be > 0, got {self.speed}")

    @classmethod
    def start(cls, speed: float = 1.0) -> WallClock:
        """Measure the offset now: the Unix time read between two monotonic reads, the tightest of a few."""
        best: tuple[int, int] | None = None
        for _ in range(_SAMPLES):
            before = time.monotonic_ns()
            unix = time.time_ns()
            after = time.monotonic_ns()
            if best is None or after - before < best[0]:
                best = (after - before, unix - (before + after) // 2)
        assert best is not None
        return cls(best[1], time.monotonic_ns(), speed)

    def now_ns(self) -> int:
        mono = time.monotonic_ns()
        if self.speed == 1.0:
            return mono + self.offset_ns
        return self.start_monotonic_ns + self.offset_ns + round((mono - self.start_monotonic_ns) * self.speed)

    def sleep_until(self, due_ns: int, at_most_s: float) -> None:
        """Sleep until this clock reads ``due_ns``, or ``at_most_s`` seconds of real time, whichever is first."""
        wait_s = (due_ns - self.now_ns()) / self.speed / 1e9
        if wait_s > 0:
            time.sleep(min(wait_s, at_most_s))

    def metadata(self) -> dict[str, str]:
        """The mapping, for the recording's metadata (see fuser/IO.md)."""
        out = {"time": "unix", "unix_minus_monotonic_ns": str(self.offset_ns)}
        if self.speed != 1.0:
            out |= {"time": f"unix at the start, then {self.speed:g} times as fast", "clock_speed": repr(self.speed),
                    "clock_start_monotonic_ns": str(self.start_monotonic_ns)}
        return out
