"""Plausibility limits for decoded values and the rejection they raise.

The checks are written for the hot path: one chained comparison per vector
(NaN fails every comparison), with the precise reason worked out only once a
value has already failed.
"""

from __future__ import annotations

import math

from .samples import Quat, Vec3

GYRO_MAX_RAD_S = 35.0
"""Per axis; 2000 deg/s full scale is 34.9 rad/s."""
ACCEL_MAX_M_S2 = 160.0
"""Per axis; 16 g full scale is 157 m/s^2."""
MAG_MAX_GAUSS = 10.0
"""Per axis; the Earth's field is below 0.7 gauss."""
MAG_MIN_FIELD_GAUSS = 1e-3
"""The weakest field that can be a heading reference (norm): a two-hundredth of the Earth's weakest, 0.22 gauss. A
reference of 1e-300 gauss divided by zero inside the filter."""
GNSS_VELOCITY_MAX_M_S = 300.0
"""Per axis; well above any UAV (and below the 515 m/s export limit of civil receivers)."""
QUAT_NORM_TOL = 0.05
"""Largest accepted | |q| - 1 |; accepted quaternions are renormalised."""


class Rejected(Exception):
    """A message was refused; ``reason`` is the key counted in a driver's ``stats``."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(reason, detail)
        self.reason = reason
        self.detail = detail


def _fail(kind: str, values: tuple[float, ...]) -> Rejected:
    if not all(math.isfinite(v) for v in values):
        return Rejected("non_finite", f"{kind} {values}")
    return Rejected(f"{kind}_out_of_range", f"{kind} {values}")


def check_vector(kind: str, v: Vec3, limit: float) -> Vec3:
    """Return ``v`` if every component is finite and within +-limit, else raise ``Rejected``."""
    x, y, z = v
    if -limit <= x <= limit and -limit <= y <= limit and -limit <= z <= limit:
        return v
    raise _fail(kind, v)


def check_quaternion(q: Quat) -> Quat:
    """Return ``q`` scaled to unit norm if its norm is within QUAT_NORM_TOL of one, else raise."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(n - 1.0) <= QUAT_NORM_TOL:
        return (w / n, x / n, y / n, z / n)
    if not all(math.isfinite(c) for c in q):
        raise Rejected("non_finite", f"quaternion {q}")
    raise Rejected("quaternion_norm", f"norm {n:.6g} of {q}")


def check_position(lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
    """Return a WGS84 position if it is on the earth (altitude -1 km to 100 km), else raise ``Rejected``."""
    if -90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0 and -1_000.0 <= alt_m <= 100_000.0:
        return lat_deg, lon_deg, alt_m
    raise _fail("position", (lat_deg, lon_deg, alt_m))
