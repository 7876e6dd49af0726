"""State shared by the protocol decoders: stats and, per stream, a clock and a source id."""

from __future__ import annotations

import logging
from collections import Counter
from typing import Hashable

from .base import ReasonLog
from .samples import SourceId
from .timebase import DEFAULT_MAX_GAP_NS, StreamClock


class Decoder:
    """Base of the pure decoders: ``stats`` counts ``"accepted"`` and every reason refused."""

    def __init__(self, transport: str, logger: logging.Logger, max_gap_ns: int = DEFAULT_MAX_GAP_NS) -> None:
        self.stats: Counter[str] = Counter()
        self._note = ReasonLog(self.stats, logger)
        self._transport = transport
        self._max_gap_ns = max_gap_ns
        self._streams: dict[tuple[Hashable, int, int, int], tuple[StreamClock, SourceId]] = {}

    def _stream(self, kind: Hashable, system: int, component: int, instance: int) -> tuple[StreamClock, SourceId]:
        """Clock and source id of one stream: a message kind from one sender's sensor instance."""
        key = (kind, system, component, instance)
        stream = self._streams.get(key)
        if stream is None:
            source = SourceId(self._transport, system, component, instance)
            stream = self._streams[key] = (StreamClock(self._note, self._max_gap_ns), source)
        return stream
