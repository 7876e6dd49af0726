"""Progress bars on the terminal for the long offline jobs (replay, import), with tqdm.

A bar shows the percentage, the rate and the time left when the total is
known, the count and the rate otherwise. It is drawn only on a terminal: when
stderr is a file or a pipe (CI, scripts, tests) the iterable passes through
untouched and nothing is written.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TextIO, TypeVar

__all__ = ["progress_bar"]

T = TypeVar("T")


def progress_bar(
    items: Iterable[T], total: int | None, desc: str, unit: str, stream: TextIO | None = sys.stderr
) -> Iterable[T]:
    """``items``, with a bar on ``stream`` while they are consumed if ``stream`` is a terminal."""
    if stream is None or not stream.isatty():
        return items
    return _bar(items, total, desc, unit, stream)


def _bar(items: Iterable[T], total: int | None, desc: str, unit: str, stream: TextIO) -> Iterator[T]:
    from tqdm import tqdm  # noqa: PLC0415 - only a terminal pays for the import

    # mininterval 0.5 s: the bar costs one time check per item, about 60 ns, and a redraw twice a second
    with tqdm(items, total=total, desc=desc, unit=unit, file=stream, mininterval=0.5, dynamic_ncols=True) as bar:
        yield from bar
