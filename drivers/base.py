"""The one interface every sample source implements, and its reject accounting."""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from collections import Counter
from types import TracebackType
from typing import Callable

from .samples import Sample

LOG_INTERVAL_S = 10.0


class SourceError(Exception):
    """A source cannot be opened as configured (bad connection string, unknown CAN interface, unreadable key).

    Raised at construction, never later (as python-can's ``can.exceptions`` are), with a message that
    names what is wrong and what is accepted; the cause is chained as ``__cause__``.
    """


class ReasonLog:
    """Counts events by reason into ``stats`` and logs each reason at most once per interval.

    Calling it with a reason adds ``count`` (one) to ``stats[reason]``; the first
    occurrence, and then one per ``interval_s``, is logged at WARNING with the
    running count and the latest detail.
    """

    def __init__(
        self,
        stats: Counter[str],
        logger: logging.Logger,
        interval_s: float = LOG_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stats = stats
        self._logger = logger
        self._interval = interval_s
        self._clock = clock
        self._next_log: dict[str, float] = {}

    def __call__(self, reason: str, detail: str = "", count: int = 1) -> None:
        self.stats[reason] += count
        now = self._clock()
        if now >= self._next_log.get(reason, now):
            self._next_log[reason] = now + self._interval
            self._logger.warning("%s (%d so far) %s", reason, self.stats[reason], detail)


class SampleSource(ABC):
    """A stream of samples from one transport (modelled on python-can's ``BusABC``).

    ``stats`` counts accepted samples under ``"accepted"`` and every refused
    message or notable event (``"reboot"``) under its reason. ``poll`` never
    raises for bad input; it returns what could be decoded.
    """

    stats: Counter[str]
    transport: str = ""
    """What the source speaks (``"mavlink"``, ``"dronecan"``): what to check when it delivers nothing differs."""

    @abstractmethod
    def poll(self, timeout: float) -> list[Sample]:
        """Wait up to ``timeout`` seconds for input and return the samples decoded from it."""

    def close(self) -> None:
        """Release the underlying connection; the default has nothing to release."""

    def __enter__(self) -> SampleSource:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
