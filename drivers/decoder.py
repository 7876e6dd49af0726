"""State shared by the protocol decoders: stats, per-stream clocks, interned source ids."""

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
        self._clocks: dict[Hashable, StreamClock] = {}
        self._sources: dict[tuple[int, int, int], SourceId] = {}

    def _clock(self, stream: Hashable) -> StreamClock:
        clock = self._clocks.get(stream)
        if clock is None:
            clock = self._clocks[stream] = StreamClock(self._note, self._max_gap_ns)
        return clock

    def _source(self, system: int, component: int, instance: int) -> SourceId:
        key = (system, component, instance)
        source = self._sources.get(key)
        if source is None:
            source = self._sources[key] = SourceId(self._transport, system, component, instance)
        return source
