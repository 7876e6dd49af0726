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


def lags_s(placed_ns: Sequence[int], state_ns: int) -> np.ndarray:
    """Seconds each sample (at its time on the loop's timeline) lies behind the state's time."""
    return np.array([(state_ns - t) * 1e-9 for t in placed_ns])


def mean_in_state_body(vectors: Sequence[Vec3], lags: np.ndarray, rate_rad_s: np.ndarray | None) -> np.ndarray:
    """Mean of body-frame vectors, each turned by ``rate_rad_s`` (bias-corrected; None: not turned) over its lag.
    The rotation is linear in the vector: the mean of the turned vectors turns the lag-weighted mean once."""
    # a tick's few 3-vectors in plain floats: numpy's per-call cost would dominate
    n = len(vectors)
    sx = sy = sz = 0.0
    for x, y, z in vectors:
        sx += x
        sy += y
        sz += z
    mx, my, mz = sx / n, sy / n, sz / n
    if rate_rad_s is None:
        return np.array([mx, my, mz])
    lx = ly = lz = 0.0
    for lag, (x, y, z) in zip(lags.tolist(), vectors):
        lx += lag * x
        ly += lag * y
        lz += lag * z
    lx, ly, lz = lx / n, ly / n, lz / n
    wx, wy, wz = rate_rad_s.tolist()
    return np.array([mx - (wy * lz - wz * ly), my - (wz * lx - wx * lz), mz - (wx * ly - wy * lx)])  # mean - w x lagged mean
