"""argparse types of the command line's numbers: each refuses nan, inf and anything outside its range with one line
naming the range (argparse puts the option before it: ``argument --speed: expected a number from 0 to 1000 ...``).

A number the command cannot do anything with is refused while the command line is read, before anything opens: a
``--speed`` of 1e300 overflowed the wall clock, an ``--imu-rate`` of 1e9 asked for 447 GiB, ``--foxglove 99999``
ran without the live view it asked for, and ``listen --count 0`` listened for ever.
"""

from __future__ import annotations

import argparse
from typing import Callable

__all__ = ["integer", "number"]


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
