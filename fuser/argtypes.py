"""argparse types of the command line's numbers: each refuses nan, inf and anything outside its range with one line
naming the range (argparse puts the option before it: ``argument --speed: expected a number from 0 to 1000 ...``).

A number the command cannot do anything with is refused while the command line is read, before anything opens: a
``--speed`` of 1e300 overflowed the wall clock, an ``--imu-rate`` of 1e9 asked for 447 GiB, ``--foxglove 99999``
ran without the live view it asked for, and ``listen --count 0`` listened for ever.
"""

from __future__ import annotations

import argparse
import math
from typing import Callable

__all__ = ["integer", "number", "outage", "seconds", "start_time"]


def number(low: float, high: float, unit: str = "") -> Callable[[str], float]:
    """A type: a number from ``low`` to ``high`` (``unit`` follows the bounds in the message)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not low <= value <= high:  # nan fails too
            raise argparse.ArgumentTypeError(f"expected a number from {low:g} to {high:g}{unit}, got {text!r}")
        return value

    return parse


def integer(low: int, high: int | None = None) -> Callable[[str], int]:
    """A type: a whole number of at least ``low`` (and at most ``high``)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < low or (high is not None and value > high):
            wanted = f"from {low} to {high}" if high is not None else f"of at least {low}"
            raise argparse.ArgumentTypeError(f"expected a whole number {wanted}, got {text!r}")
        return value

    return parse


def seconds(text: str, positive: bool = True) -> float:
    """argparse type of a number of seconds: finite, and > 0 if ``positive`` (a ``--duration``: nan or inf would run
    forever, 0 or less stop at once) else >= 0 (``import --start``)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        raise argparse.ArgumentTypeError(f"expected a finite number of seconds {'>' if positive else '>='} 0, got {text!r}")
    return value


def outage(text: str) -> tuple[float, float]:
    """argparse type of ``sim --outage AT:SECONDS``: two finite numbers, AT >= 0 and SECONDS > 0."""
    at, _, length = text.partition(":")
    try:
        out = float(at), float(length)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected AT:SECONDS, e.g. 4:2.5") from None
    if not all(map(math.isfinite, out)) or out[0] < 0 or out[1] <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: AT must be >= 0 and SECONDS > 0")
    return out


def start_time(text: str) -> str:
    """argparse type of ``sim --start-at``: a Unix time or ``+SECONDS``, finite and >= 0 (kept as written: ``+`` is
    counted from when the flight is ready)."""
    try:
        when = float(text[1:] if text.startswith("+") else text)
    except ValueError:
        when = math.nan
    if not math.isfinite(when) or when < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a Unix time or +SECONDS")
    return text
