"""Sender timestamps turned into one monotonic nanosecond time line per stream."""

from __future__ import annotations

from typing import Callable

from .validation import Rejected

NS_PER_MS = 1_000_000
NS_PER_US = 1_000
_U32_WRAP_NS = (1 << 32) * NS_PER_MS
DEFAULT_MAX_GAP_NS = 60 * 1_000_000_000
MAX_TIME_NS = 1 << 62
"""Every accepted time (the sender's, and what the stream makes of it) lies in [0, MAX_TIME_NS):
year 2116 on the Unix epoch, and a quarter of the uint64 nanoseconds MCAP stores, so that no
sum of a time and an offset downstream can overflow the recorder."""


class StreamClock:
    """Monotonic time line of one stream (one source, one message type).

    Every time outside [0, MAX_TIME_NS) is refused as ``time_out_of_range``.
    The first time of a stream is compared with ``reference_ns``, the latest
    time the decoder accepted on the same clock of the same sender (if it has
    one): further than ``max_gap_ns`` from it, it is refused as
    ``time_implausible`` unless the next sample confirms the new time line.
    A step forward of at most ``max_gap_ns`` is accepted as it is. A step of
    zero is a ``duplicate``. Any other step (backwards, or forward by more than
    ``max_gap_ns``) is refused as ``time_backwards`` / ``time_jump`` unless the
    next sample confirms the new time line, which is then adopted and reported
    through ``on_event`` as ``reboot`` or ``clock_jump``. After a reboot (time
    went back) the output stays monotonic: it continues after the last accepted
    time by the receive time that passed in between (when the caller gives
    receive times; by nothing otherwise), so that a receiver's mapping of
    sender time to receive time stays valid across it. A confirmed jump forward
    is kept as the sender says.
    """

    __slots__ = ("_last_raw", "_last_rx", "_offset", "_pending", "_pending_rx", "_wrap_ns", "_max_gap", "_on_event")

    def __init__(self, on_event: Callable[[str], None], max_gap_ns: int = DEFAULT_MAX_GAP_NS) -> None:
        self._last_raw: int | None = None
        self._last_rx: int | None = None
        self._offset = 0
        self._pending: int | None = None
        self._pending_rx: int | None = None
        self._wrap_ns = 0
        self._max_gap = max_gap_ns
        self._on_event = on_event

    @property
    def started(self) -> bool:
        """Whether the stream has accepted a sample yet."""
        return self._last_raw is not None

    def stamp(self, raw_ns: int, reference_ns: int | None = None, receive_ns: int | None = None) -> int:
        """Return the monotonic time of a sample stamped ``raw_ns`` by its sender (received at
        ``receive_ns`` on the receiver's clock, if known), or raise ``Rejected``."""
        if not 0 <= raw_ns < MAX_TIME_NS or raw_ns + self._offset >= MAX_TIME_NS:
            raise Rejected("time_out_of_range", f"{raw_ns} ns")
        last = self._last_raw
        if last is not None:
            step = raw_ns - last
            if step <= 0 or step > self._max_gap:
                self._discontinuity(raw_ns, last, step, receive_ns)
        elif reference_ns is not None and abs(raw_ns - reference_ns) > self._max_gap:
            pending = self._pending
            if pending is None or not 0 < raw_ns - pending <= self._max_gap:
                self._pending = raw_ns
                raise Rejected("time_implausible", f"first time {raw_ns} ns, {raw_ns - reference_ns} ns from the sender's")
        self._last_raw = raw_ns
        self._last_rx = receive_ns
        self._pending = None
        return raw_ns + self._offset

    def unwrap_ms_u32(self, time_boot_ms: int) -> int:
        """Nanoseconds of a uint32 millisecond counter, unwrapped past its 49.7-day wrap-around
        relative to this stream's last time (pass the result to ``stamp``)."""
        raw = time_boot_ms * NS_PER_MS + self._wrap_ns
        last = self._last_raw
        if last is not None and last - raw > _U32_WRAP_NS // 2:
            raw += _U32_WRAP_NS
        return raw

    def stamp_ms_u32(self, time_boot_ms: int, reference_ns: int | None = None, receive_ns: int | None = None) -> int:
        """Like ``stamp`` for a uint32 millisecond counter (see ``unwrap_ms_u32``)."""
        raw = self.unwrap_ms_u32(time_boot_ms)
        t = self.stamp(raw, reference_ns, receive_ns)
        self._wrap_ns = raw - time_boot_ms * NS_PER_MS
        return t

    def _discontinuity(self, raw: int, last: int, step: int, receive_ns: int | None) -> None:
        if step == 0:
            raise Rejected("duplicate", f"time {raw} ns again")
        pending = self._pending
        if pending is not None and 0 < raw - pending <= self._max_gap:
            if raw < last:
                self._on_event("reboot")
                elapsed = 0 if self._pending_rx is None or self._last_rx is None else max(self._pending_rx - self._last_rx, 0)
                self._offset += last - pending + elapsed
            else:
                self._on_event("clock_jump")
            return
        self._pending = raw
        self._pending_rx = receive_ns
        if step < 0:
            raise Rejected("time_backwards", f"{-step} ns back")
        raise Rejected("time_jump", f"{step} ns forward")
