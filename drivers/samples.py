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


@dataclass(frozen=True, slots=True)
class GnssSample:
    """A GNSS receiver's velocity (and position) solution.

    ``vel_ned_m_s`` is the velocity over ground, north-east-down, m/s, or None when the message
    carries no valid velocity (no fix, unknown speed or course). ``vertical_velocity`` says whether
    its down component was measured (GPS_RAW_INT carries ground speed and course only; down is
    then 0.0 and must not be used). ``speed_accuracy_m_s`` is the receiver's one-sigma speed
    accuracy where the message has one. ``fix_type`` follows MAVLink's GPS_FIX_TYPE (0 no GPS,
    1 no fix, 2 2-D, 3 3-D, 4 DGPS, 5 RTK float, 6 RTK fixed). Position (WGS84 latitude and
    longitude in degrees, altitude above mean sea level in metres) is None where unknown; the
    fuser uses it only for the earth's magnetic field. ``filtered`` marks an autopilot's fused
    navigation solution (GLOBAL_POSITION_INT) rather than a receiver's own fix.
    """

    t_ns: int
    fix_type: int
    vel_ned_m_s: Vec3 | None
    vertical_velocity: bool
    speed_accuracy_m_s: float | None
    lat_deg: float | None
    lon_deg: float | None
    alt_m: float | None
    filtered: bool
    source: SourceId


Sample = Union[ImuSample, MagSample, AttitudeSample, GnssSample]
