"""A tick's vector readings (specific force, magnetic field) averaged in the body frame of the state's time.

The samples of a tick lie at different times; at 600 deg/s the body turns 3
degrees in half a 10-ms tick, which averaging in the moving frame would put
into the tilt and heading measurements. Each reading is turned into the body
frame of the state's time (its lag later) at the tick's rate before it is
averaged: small-angle rotation ``v - (w lag) x v``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from drivers.samples import Vec3

__all__ = ["lags_s", "mean_in_state_body"]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (``np.cross`` costs ten times more on one pair)."""
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    return np.array([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx])


def lags_s(placed_ns: Sequence[int], state_ns: int) -> np.ndarray:
    """Seconds each sample (at its time on the loop's timeline) lies behind the state's time."""
    return (state_ns - np.asarray(placed_ns, dtype=np.int64)) * 1e-9


def mean_in_state_body(vectors: Sequence[Vec3], lags: np.ndarray, rate_rad_s: np.ndarray | None) -> np.ndarray:
    """Mean of body-frame vectors, each turned by ``rate_rad_s`` (bias-corrected; None: not turned) over its lag.
    The rotation is linear in the vector: the mean of the turned vectors turns the lag-weighted mean once."""
    v = np.asarray(vectors, dtype=float)
    mean = v.sum(axis=0) / len(v)
    if rate_rad_s is None:
        return mean
    return mean - _cross(rate_rad_s, lags @ v / len(v))
