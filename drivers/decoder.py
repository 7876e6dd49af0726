"""State shared by the protocol decoders: stats, what is known of each sender, and per stream a clock.

Everything a decoder keeps grows with the number of senders and streams it has seen, so both
are capped (``max_senders``, ``max_streams``): data that would need one more is refused and
counted (``too_many_senders``, ``too_many_streams``), and nothing a flood sends can make a
decoder grow past them.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Hashable

from .base import ReasonLog
from .samples import SourceId
from .timebase import DEFAULT_MAX_GAP_NS, StreamClock
from .validation import Rejected

MAX_SENDERS = 32
"""Senders one decoder keeps state for (MAVLink (system, component) pairs, DroneCAN nodes)."""
MAX_STREAMS = 64
"""Streams (message kind x sender x sensor instance) one decoder keeps a clock for."""
BOOT_CLOCK = "boot"
"""A sender's time since its boot: it restarts near zero when the sender reboots."""
REBOOT_BACK_NS = 1_000_000_000
"""A boot-clock time this far behind the sender's latest shows that the sender restarted."""


class Sender:
    """What a decoder knows of one sender (MAVLink system and component, DroneCAN node)."""

    __slots__ = ("latest_ns", "last_seq", "pending_lost")

    def __init__(self) -> None:
        self.latest_ns: dict[str, int] = {}
        """Per clock of the sender (boot time, Unix time, bus time), the latest raw time accepted."""
        self.last_seq: int | None = None
        """MAVLink: sequence number of the sender's latest frame."""
        self.pending_lost = 0
        """MAVLink: frames missing at the latest sequence gap, counted as lost once a boot-clock time
        from the sender shows that it did not restart (a restart begins the sequence again)."""


class Stream:
    """One stream: a message kind from one sender's sensor instance, with its clock and source id."""

    __slots__ = ("clock", "source", "sender")

    def __init__(self, clock: StreamClock, source: SourceId, sender: Sender) -> None:
        self.clock = clock
        self.source = source
        self.sender = sender


class Decoder:
    """Base of the pure decoders: ``stats`` counts ``"accepted"`` and every reason refused."""

    def __init__(
        self,
        transport: str,
        logger: logging.Logger,
        max_gap_ns: int = DEFAULT_MAX_GAP_NS,
        max_senders: int = MAX_SENDERS,
        max_streams: int = MAX_STREAMS,
    ) -> None:
        self.stats: Counter[str] = Counter()
        self._note = ReasonLog(self.stats, logger)
        self._transport = transport
        self._max_gap_ns = max_gap_ns
        self._max_senders = max_senders
        self._max_streams = max_streams
        self._senders: dict[Hashable, Sender] = {}
        self._streams: dict[tuple[Hashable, int, int, int], Stream] = {}
        self._receive_ns: int | None = None
        """Receive time of the input being decoded, where the caller gives one (see ``StreamClock``)."""

    def _sender(self, key: Hashable) -> Sender:
        """State of one sender, created on first use; ``Rejected`` once ``max_senders`` are known."""
        sender = self._senders.get(key)
        if sender is None:
            if len(self._senders) >= self._max_senders:
                raise Rejected("too_many_senders", f"{key} would be sender {len(self._senders) + 1}")
            sender = self._senders[key] = Sender()
        return sender

    def _stream(self, kind: Hashable, system: int, component: int, instance: int) -> Stream:
        """Clock and source id of one stream, created on first use; ``Rejected`` once ``max_streams`` exist."""
        key = (kind, system, component, instance)
        stream = self._streams.get(key)
        if stream is None:
            if len(self._streams) >= self._max_streams:
                raise Rejected("too_many_streams", f"{key} would be stream {len(self._streams) + 1}")
            sender = self._sender((system, component))
            source = SourceId(self._transport, system, component, instance)
            stream = self._streams[key] = Stream(StreamClock(self._note, self._max_gap_ns), source, sender)
        return stream

    def _stamp(self, stream: Stream, raw_ns: int, clock: str) -> int:
        """Monotonic time of a sample stamped ``raw_ns`` on the sender's ``clock``, or ``Rejected``.

        A stream's first time is checked against the sender's latest on the same clock; every
        accepted time becomes that latest. A boot-clock time also settles a pending sequence gap.
        """
        reference = self._settle(stream, raw_ns, clock)
        t = stream.clock.stamp(raw_ns, reference, self._receive_ns)
        stream.sender.latest_ns[clock] = raw_ns
        return t

    def _stamp_ms_u32(self, stream: Stream, time_boot_ms: int) -> int:
        """``_stamp`` for a uint32 millisecond boot time, unwrapped past its 49.7-day wrap-around."""
        raw = stream.clock.unwrap_ms_u32(time_boot_ms)
        reference = self._settle(stream, raw, BOOT_CLOCK)
        t = stream.clock.stamp_ms_u32(time_boot_ms, reference, self._receive_ns)
        stream.sender.latest_ns[BOOT_CLOCK] = raw
        return t

    def _settle(self, stream: Stream, raw_ns: int, clock: str) -> int | None:
        """Count a pending sequence gap as lost unless this boot time shows a restart; return the
        reference a stream's first time is checked against (None once the stream has started)."""
        sender = stream.sender
        latest = sender.latest_ns.get(clock)
        if sender.pending_lost and clock == BOOT_CLOCK and latest is not None:
            if raw_ns >= latest - REBOOT_BACK_NS:
                self.stats["lost"] += sender.pending_lost
            sender.pending_lost = 0
        return None if stream.clock.started else latest
