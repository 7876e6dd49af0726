"""Cross-checks between a vehicle's IMUs: a sample that disagrees with the others is kept out.

Every IMU of a rigid vehicle measures the same body rate and (up to
vibration and lever arm) the same specific force. Each sample is compared
with the other IMUs' latest samples taken within ``compare_within_s``: its
rate must lie within ``disagree_rad_s + angular_accel_rad_s2 |dt|`` and its
specific force within ``disagree_m_s2`` of theirs. With three or more IMUs
the comparison is against their median, so the one that disagrees is known;
with two, the rougher of the pair (the larger low-passed squared change of
rate from one of its samples to the next: random data is rough, a working
gyro smooth) is the one kept out. A gyro axis frozen at one value (``frozen_samples`` samples in a row
exactly equal, while another IMU's same axis moves) is kept out whatever the comparison says: a stuck
axis near the vehicle's rates passes it, and being the smoothest it won the pair. Kept-out samples never reach the
integration or the updates; they are counted, and the published estimate is
widened while the check keeps something out (``fault_sigma_deg``).

Compiled (numba) for the tick (:func:`fuser.model.fusion.tick`): each IMU's
latest sample is in its slot of the state record's ``imu_check`` part
(:data:`fuser.model.state.IMU_CHECK`; the slot is the sample's
``IMU_INPUT.slot``, given by the model in order of the IMUs' first arrival),
changed in place.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["check_imus"]


@njit(cache=True, nogil=True, inline="always")  # inlined: numba types the loop's count as a literal 0 in one call and compiles it twice
def _frozen(params: np.record, check: np.record, slot: int, others: np.ndarray, n_others: int) -> bool:
    """The IMU in ``slot`` has a gyro axis frozen while one of the ``others``' same axis moves (module docstring)."""
    for c in range(3):
        if check.repeats[slot, c] >= params.frozen_samples:
            for m in range(n_others):
                if check.repeats[others[m], c] < params.frozen_samples:
                    return True
    return False


@njit(cache=True, nogil=True)
def _agrees(params: np.record, gyro: tuple, accel: tuple, ref_gyro: tuple, ref_accel: tuple, dt_s: float) -> bool:
    """The sample's rate within ``disagree_rad_s + angular_accel_rad_s2 dt`` and its specific force within
    ``disagree_m_s2`` of the reference's (module docstring)."""
    rx, ry, rz = gyro[0] - ref_gyro[0], gyro[1] - ref_gyro[1], gyro[2] - ref_gyro[2]
    fx, fy, fz = accel[0] - ref_accel[0], accel[1] - ref_accel[1], accel[2] - ref_accel[2]
    return (math.sqrt(rx * rx + ry * ry + rz * rz) <= params.disagree_rad_s + params.angular_accel_rad_s2 * dt_s
            and math.sqrt(fx * fx + fy * fy + fz * fz) <= params.disagree_m_s2)


@njit(cache=True, nogil=True)
def _medians(values: np.ndarray, n: int) -> tuple:
    """The median of each column of ``values[:n]`` (sorted in place; the mean of the middle two for an even ``n``),
    ``np.median`` over the first axis, the same whatever the rows' order: the rows' rates (columns 0-2) and specific
    forces (3-5), as two 3-tuples."""
    out = np.empty(values.shape[1])
    half = n // 2
    for c in range(values.shape[1]):
        for i in range(1, n):  # insertion sort: a few IMUs
            j = i
            while j > 0 and values[j - 1, c] > values[j, c]:
                values[j - 1, c], values[j, c] = values[j, c], values[j - 1, c]
                j -= 1
        out[c] = values[half, c] if n % 2 else (values[half - 1, c] + values[half, c]) / 2.0
    return (out[0], out[1], out[2]), (out[3], out[4], out[5])


@njit(cache=True, nogil=True)
def check_imus(params_imu_check: np.record, check: np.record, imu: np.ndarray) -> tuple:
    """``(kept, disagreeing)``: the indices of the tick's IMU samples (``imu``, :data:`fuser.model.tick.IMU_INPUT`)
    kept, ascending, and how many were kept out. The samples are taken in time order (stable: samples at one
    instant in the tick's order); ``check`` (the state's ``imu_check`` part) holds each IMU's latest after them.

    Each sample: its IMU's roughness (the low-passed squared change of rate from its previous sample), then the
    comparison with the other IMUs' latest within ``compare_within_s`` (module docstring)."""
    params = params_imu_check
    n = imu.shape[0]
    placed = np.empty(n, np.int64)
    order = np.empty(n, np.int64)  # by placed time, stable (insertion sort: a tick holds a few samples, nearly in order)
    for i in range(n):
        placed[i] = imu[i].placed_ns
        order[i] = i
        j = i
        while j > 0 and placed[order[j - 1]] > placed[order[j]]:
            order[j - 1], order[j] = order[j], order[j - 1]
            j -= 1
    good = np.empty(n, np.bool_)
    slots = check.t_ns.shape[0]
    others = np.empty(slots, np.int64)
    rows = np.empty((slots + 1, 6))  # the other IMUs' and the sample's gyro and accel, for the medians
    window_ns = params.compare_within_s * 1e9
    out = 0
    for k in range(n):
        i = order[k]
        slot, t = imu[i].slot, placed[i]
        g, a = imu[i].gyro_rad_s, imu[i].accel_m_s2
        gyro, accel = (g[0], g[1], g[2]), (a[0], a[1], a[2])
        roughness = 0.0  # the first sample of its IMU: none
        if check.seen[slot]:
            bx, by, bz = check.gyro_rad_s[slot, 0], check.gyro_rad_s[slot, 1], check.gyro_rad_s[slot, 2]
            for c, before_c in enumerate((bx, by, bz)):
                check.repeats[slot, c] = check.repeats[slot, c] + 1 if gyro[c] == before_c else 0
            step2 = (gyro[0] - bx) * (gyro[0] - bx) + (gyro[1] - by) * (gyro[1] - by) + (gyro[2] - bz) * (gyro[2] - bz)
            gain = min(1.0, (t - check.t_ns[slot]) * 1e-9 / params.roughness_s)
            before = check.roughness_rad2_s2[slot]
            roughness = before + gain * (step2 - before)
        check.seen[slot], check.t_ns[slot], check.roughness_rad2_s2[slot] = 1, t, roughness
        for c in range(3):
            check.gyro_rad_s[slot, c] = gyro[c]
            check.accel_m_s2[slot, c] = accel[c]
        n_others = 0
        for o in range(slots):
            if o != slot and check.seen[o] and t - check.t_ns[o] <= window_ns:
                others[n_others] = o
                n_others += 1
        ok = True
        if params.enabled and n_others >= 2:  # against the median of the others and itself
            oldest = check.t_ns[others[0]]
            for m in range(n_others):
                o = others[m]
                oldest = min(oldest, check.t_ns[o])
                for c in range(3):
                    rows[m, c], rows[m, 3 + c] = check.gyro_rad_s[o, c], check.accel_m_s2[o, c]
            for c in range(3):
                rows[n_others, c], rows[n_others, 3 + c] = gyro[c], accel[c]
            ref_gyro, ref_accel = _medians(rows, n_others + 1)
            ok = _agrees(params, gyro, accel, ref_gyro, ref_accel, (t - oldest) * 1e-9)
        elif params.enabled and n_others == 1:  # against the other: the rougher of two that disagree is kept out
            o = others[0]
            ref_gyro = (check.gyro_rad_s[o, 0], check.gyro_rad_s[o, 1], check.gyro_rad_s[o, 2])
            ref_accel = (check.accel_m_s2[o, 0], check.accel_m_s2[o, 1], check.accel_m_s2[o, 2])
            ok = (_agrees(params, gyro, accel, ref_gyro, ref_accel, (t - check.t_ns[o]) * 1e-9)
                  or roughness <= check.roughness_rad2_s2[o])
        if params.enabled and ok and n_others >= 1:
            ok = not _frozen(params, check, slot, others, n_others)
        good[i] = ok
        if not ok:
            out += 1
            check.has_last_fault_ns, check.last_fault_ns = True, t
    kept = np.empty(n - out, np.int64)
    m = 0
    for i in range(n):
        if good[i]:
            kept[m] = i
            m += 1
    return kept, out
