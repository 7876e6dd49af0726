"""Typed, timestamped samples shared by every driver.

Units are SI except the magnetic field (gauss, as MAVLink and DroneCAN send it).
Vectors are in the body frame FRD (x forward, y right, z down); attitude
quaternions are (w, x, y, z), Hamilton, rotating body FRD vectors into the
world NED frame (``v_ned = q v_frd q*``), as MAVLink's ATTITUDE_QUATERNION.
``t_ns`` is the sender's own message time in integer nanoseconds, made
monotonic per stream by the driver (see ``drivers.timebase``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


@dataclass(frozen=True, slots=True, order=True)
class SourceId:
    """Where a sample comes from: transport ("mavlink", "dronecan", "sim"),
    system id (CAN node id for DroneCAN), component id and sensor instance.
    Ordered by those fields, so that several sources are always fused in one order."""

    transport: str
    system: int
    component: int
    instance: int


@dataclass(frozen=True, slots=True)
class ImuSample:
    """Rate gyro (rad/s), specific force (m/s^2) and optional magnetometer (gauss), body FRD."""

    t_ns: int
    gyro_rad_s: Vec3
    accel_m_s2: Vec3
    mag_gauss: Vec3 | None
    source: SourceId


@dataclass(frozen=True, slots=True)
class MagSample:
    """Magnetic field in gauss, body FRD (DroneCAN sends it on its own)."""

    t_ns: int
    mag_gauss: Vec3
    source: SourceId


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """Unit quaternion (w, x, y, z) from body FRD to world NED, as estimated by the sender."""

    t_ns: int
    q_wxyz: Quat
    source: SourceId


Sample = Union[ImuSample, MagSample, AttitudeSample]
