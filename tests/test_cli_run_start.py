"""How ``run`` starts: inputs and outputs open before the filter compiles, and what queued meanwhile is dropped
(:func:`fuser.live.discard_backlog`, just before the live loop's reader threads start).

On the first run after installing, the warm-up (fuser/warmup.py) compiles the filter for about 30 s. A source
that cannot open must be reported at once, not after that; and the samples a source queued during the warm-up
(up to its length old) must not reach the loop stamped as just received.
"""

from __future__ import annotations

import socket
from collections import Counter

import fuser.cli as cli
import fuser.live as live
import fuser.warmup as warmup
from drivers.samples import ImuSample, SourceId
from local_net import free_port

SAMPLE = ImuSample(1, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), None, SourceId("mavlink", 1, 1, 0))


class QueuedSource:
    """A source holding ``batches`` of samples already received, then nothing."""

    def __init__(self, batches: list[int]) -> None:
        self.batches = list(batches)
        self.stats: Counter[str] = Counter()
        self.timeouts: list[float] = []

    def poll(self, timeout: float) -> list:
        self.timeouts.append(timeout)
        return [SAMPLE] * self.batches.pop(0) if self.batches else []


class FloodingSource(QueuedSource):
    """A source that never runs dry."""

    def poll(self, timeout: float) -> list:
        self.timeouts.append(timeout)
        return [SAMPLE] * 10


def test_what_queued_during_the_warm_up_is_dropped_and_counted():
    a, b = QueuedSource([3, 5]), QueuedSource([])
    live.discard_backlog({"a": a, "b": b})
    assert a.stats["warm_up_discarded"] == 8 and not a.batches  # every queued batch, read without waiting
    assert b.stats["warm_up_discarded"] == 0
    assert set(a.timeouts + b.timeouts) == {0.0}


def test_a_flooding_source_does_not_hold_the_start(monkeypatch):
    monkeypatch.setattr(live, "BACKLOG_MAX_S", 0.05)
    flood = FloodingSource([])
    live.discard_backlog({"flood": flood})  # returns: bounded by the time, not by the source running dry
    assert flood.stats["warm_up_discarded"] >= 10


def test_a_source_that_cannot_open_is_reported_before_the_filter_compiles(monkeypatch, capsys):
    warmed: list[object] = []
    monkeypatch.setattr(warmup, "warm_up", lambda config, notice=None: warmed.append(config) or 0.0)
    code = cli.main(["run", "--mavlink", f"tcp:127.0.0.1:{free_port()}", "--no-zenoh"])  # nothing listens there
    err = capsys.readouterr().err.splitlines()
    assert code == 1 and len(err) == 1 and "cannot open MAVLink" in err[0], err
    assert warmed == []


def test_a_run_that_opens_warms_up_then_fuses(monkeypatch, capsys):
    """With a source that opens, the run warms up once and fuses to the end."""
    warmed: list[object] = []
    real = warmup.warm_up
    monkeypatch.setattr(warmup, "warm_up", lambda config, notice=None: warmed.append(config) or real(config, notice))
    code = cli.main(["run", "--mavlink", f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}", "--no-zenoh", "--duration", "0.3"])
    assert code == 0, capsys.readouterr().err
    assert len(warmed) == 1
