"""Sender timestamps turned into one monotonic nanosecond time line per stream."""

from __future__ import annotations

from typing import Callable

from .validation import Rejected

NS_PER_MS = 1_000_000
NS_PER_US = 1_000
_U32_WRAP_NS = (1 << 32) * NS_PER_MS
DEFAULT_MAX_GAP_NS = 60 * 1_000_000_000


class StreamClock:
    """Monotonic time line of one stream (one source, one message type).

    A step forward of at most ``max_gap_ns`` is accepted as it is. A step of
    zero is a ``duplicate``. Any other step (backwards, or forward by more than
    ``max_gap_ns``) is refused as ``time_backwards`` / ``time_jump`` unless the
    next sample confirms the new time line, which is then adopted and reported
    through ``on_event`` as ``reboot`` (time went back: the output continues
    just after the last accepted time, so it stays monotonic) or
    ``clock_jump`` (time went forward: kept as the sender says).
    """

    __slots__ = ("_last_raw", "_offset", "_pending", "_wrap_ns", "_max_gap", "_on_event")

    def __init__(self, on_event: Callable[[str], None], max_gap_ns: int = DEFAULT_MAX_GAP_NS) -> None:
        self._last_raw: int | None = None
        self._offset = 0
        self._pending: int | None = None
        self._wrap_ns = 0
        self._max_gap = max_gap_ns
        self._on_event = on_event

    def stamp(self, raw_ns: int) -> int:
        """Return the monotonic time of a sample stamped ``raw_ns`` by its sender, or raise ``Rejected``."""
        last = self._last_raw
        if last is not None:
            step = raw_ns - last
            if step <= 0 or step > self._max_gap:
                self._discontinuity(raw_ns, last, step)
        self._last_raw = raw_ns
        self._pending = None
        return raw_ns + self._offset

    def stamp_ms_u32(self, time_boot_ms: int) -> int:
        """Like ``stamp`` for a uint32 millisecond counter, unwrapping its 49.7-day wrap-around."""
        raw = time_boot_ms * NS_PER_MS + self._wrap_ns
        last = self._last_raw
        if last is not None and last - raw > _U32_WRAP_NS // 2:
            raw += _U32_WRAP_NS
        t = self.stamp(raw)
        self._wrap_ns = raw - time_boot_ms * NS_PER_MS
        return t

    def _discontinuity(self, raw: int, last: int, step: int) -> None:
        if step == 0:
            raise Rejected("duplicate", f"time {raw} ns again")
        pending = self._pending
        if pending is not None and 0 < raw - pending <= self._max_gap:
            if raw < last:
                self._on_event("reboot")
                self._offset += last - pending
            else:
                self._on_event("clock_jump")
            return
        self._pending = raw
        if step < 0:
            raise Rejected("time_backwards", f"{-step} ns back")
        raise Rejected("time_jump", f"{step} ns forward")
