"""Scalar Euler 3-2-1 (yaw, pitch, roll) conversions, as MAVLink's ATTITUDE message uses them.

Plain ``math`` on purpose: these run once per message in the decoder's hot
path, where a numpy call costs more than the whole formula.
"""

from __future__ import annotations

import math

from .samples import Quat


def quaternion_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """(w, x, y, z) of the rotation yaw about z, then pitch about y, then roll about x (intrinsic)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quaternion(q: Quat) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians of a unit quaternion (w, x, y, z); inverse of ``quaternion_from_euler``."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw
