"""Where an MCAP file's messages break log-time order, read in file order with the mcap package's own reader.

The MCAP specification recommends writing messages in log-time order; Foxglove and readers that stream a file
rely on it (``mcap doctor`` warns about every message earlier than one before it). :func:`order_violations`
counts, in the order the messages are stored, each message earlier than the latest log time before it in the
whole file (``"*"``, as ``mcap doctor`` counts them) and in its own channel (its topic).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from mcap.reader import make_reader


def order_violations(path: str | Path) -> dict[str, int]:
    """``{"*": whole file, topic: within that channel}``, only where there is at least one."""
    out: Counter[str] = Counter()
    latest: dict[str, int] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            t = message.log_time
            if t < latest.get("*", t):
                out["*"] += 1
            if t < latest.get(channel.topic, t):
                out[channel.topic] += 1
            latest["*"] = max(latest.get("*", t), t)
            latest[channel.topic] = max(latest.get(channel.topic, t), t)
    return dict(out)
