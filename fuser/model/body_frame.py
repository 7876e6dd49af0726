"""A tick's vector readings (specific force, magnetic field) averaged in the body frame of the state's time.

The samples of a tick lie at different times; at 600 deg/s the body turns 3
degrees in half a 10-ms tick, which averaging in the moving frame would put
into the tilt and heading measurements. Each reading is turned into the body
frame of the state's time (its lag later) at the tick's rate before it is
averaged: small-angle rotation ``v - (w lag) x v``.

Compiled (numba) for the tick (:mod:`fuser.model.fusion`), which computes each
sample's lag (seconds it lies behind the state's time) itself.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["mean_in_state_body"]


@njit(cache=True, nogil=True)
def mean_in_state_body(vectors: np.ndarray, lags: np.ndarray, has_rate: bool, rate_rad_s: tuple) -> tuple:
    """Mean of body-frame vectors (``(n, 3)``, ``n > 0``), each turned by ``rate_rad_s`` (bias-corrected;
    ``has_rate`` False: not turned) over its lag (``lags``, ``(n,)`` seconds). The rotation is linear in the vector:
    the mean of the turned vectors turns the lag-weighted mean once."""
    n = vectors.shape[0]
    sx = sy = sz = 0.0
    for k in range(n):
        sx += vectors[k, 0]
        sy += vectors[k, 1]
        sz += vectors[k, 2]
    mx, my, mz = sx / n, sy / n, sz / n
    if not has_rate:
        return mx, my, mz
    lx = ly = lz = 0.0
    for k in range(n):
        lag = lags[k]
        lx += lag * vectors[k, 0]
        ly += lag * vectors[k, 1]
        lz += lag * vectors[k, 2]
    lx, ly, lz = lx / n, ly / n, lz / n
    wx, wy, wz = rate_rad_s
    return mx - (wy * lz - wz * ly), my - (wz * lx - wx * lz), mz - (wx * ly - wy * lx)  # mean - w x lagged mean
