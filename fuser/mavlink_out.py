"""The fused attitude back to the ground station over MAVLink.

``--mavlink-out CONN`` sends, from a component of its own so that QGroundControl, Mission
Planner or MAVProxy tell it from the autopilot (MAVLink common.xml):

* ``ATTITUDE_QUATERNION`` (#31): ``q1..q4`` = w, x, y, z rotating body FRD into NED (the
  estimate's ``q_wxyz``), body rates from the latest IMU sample, ``repr_offset_q`` zero;
* ``ATTITUDE`` (#30), for ground stations that only show that: roll, pitch, yaw (ZYX, rad)
  and the same rates;
* ``HEARTBEAT`` (#0) once a second: ``MAV_TYPE_ONBOARD_CONTROLLER``,
  ``MAV_AUTOPILOT_INVALID`` (not an autopilot), ``MAV_STATE_ACTIVE``.

Only a fresh attitude is sent: once no IMU sample has arrived for ``STALE_AFTER_NS`` (1 s), the
attitudes stop (counted as ``withheld``) until the IMU is back; the heartbeat goes on, the fuser
being alive. The loop keeps publishing estimates carried by the last rate after its input stops,
and a ground station shows whatever attitude it is sent as current.

The system id is the vehicle's (the first MAVLink input sample's), unless set; the
component id is ``MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY`` (197) by default. ``time_boot_ms``
is the estimate's time on the vehicle's IMU clock (``sensor_t_ns``: for MAVLink autopilots
the time since their boot), so the fused attitude lines up with the autopilot's in a ground
station's plots. Rates are counted on the loop's timeline (the wall clock live), never on
the time of sending. A connection that cannot be opened is an error at once (``FuserError``, before
the run starts); once open it never raises into the loop: failed sends are counted, the first logged once.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Any

from drivers.link import check_connection
from drivers.samples import ImuSample, Sample, SourceId
from fuser.codec import Estimate
from fuser.errors import FuserError

__all__ = ["MavlinkOut", "MavlinkOutSettings"]

log = logging.getLogger(__name__)

HEARTBEAT_PERIOD_NS = 1_000_000_000
STALE_AFTER_NS = 1_000_000_000
"""No attitude is sent once the last IMU sample is older than this (on the loop's timeline): after its input stops the
loop goes on publishing, the last rate held, which a ground station would show as a fresh attitude. 1 s: ten
periods of a 10 Hz IMU, three of ArduPilot's default 3 Hz telemetry stream, far beyond a 50-400 Hz IMU's jitter."""
MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY = 197
DEFAULT_SYSTEM_ID = 1
"""Used until the first MAVLink input sample tells the vehicle's system id."""


@dataclass(frozen=True)
class MavlinkOutSettings:
    """MAVLink output (``[fuser.mavlink_out]``; ``--mavlink-out CONN`` sets ``connection``)."""

    connection: str = ""
    """pymavlink connection to send on, e.g. ``udpout:127.0.0.1:14550``; empty: do not send."""
    rate_hz: float = 10.0
    """ATTITUDE_QUATERNION and ATTITUDE per second (at most the loop's rate)."""
    system_id: int | None = None
    """MAVLink system id; None: the vehicle's, from the first MAVLink input sample."""
    component_id: int = MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
    """MAVLink component id: not the autopilot's (1), so a ground station tells the two apart."""
    send_attitude: bool = True
    """Also send ATTITUDE (Euler angles), which every ground station displays."""

    def __post_init__(self) -> None:
        if not isinstance(self.connection, str):
            raise ValueError(f"mavlink_out.connection: a pymavlink connection string (or empty), got {self.connection!r}")
        if self.connection:
            try:
                check_connection(self.connection)
            except ValueError as exc:
                raise ValueError(f"mavlink_out.connection: {exc}") from None
        if not (isinstance(self.rate_hz, (int, float)) and 0.1 <= self.rate_hz <= 1000):  # 1e-300 overflowed the next send's time
            raise ValueError(f"mavlink_out.rate_hz: must be from 0.1 to 1000, got {self.rate_hz!r}")
        if self.system_id is not None and not (isinstance(self.system_id, int) and 1 <= self.system_id <= 255):
            raise ValueError(f"mavlink_out.system_id: must be an integer in 1..255 or unset, got {self.system_id!r}")
        if not (isinstance(self.component_id, int) and 1 <= self.component_id <= 255):
            raise ValueError(f"mavlink_out.component_id: must be an integer in 1..255, got {self.component_id!r}")
        if self.component_id == 1:
            raise ValueError("mavlink_out.component_id: 1 is MAV_COMP_ID_AUTOPILOT1; pick a component id of its own (default 197)")


class MavlinkOut:
    """Send estimates as MAVLink at ``settings.rate_hz`` plus a 1 Hz heartbeat; counts ``sent`` and ``errors``."""

    def __init__(self, settings: MavlinkOutSettings) -> None:
        """Open ``settings.connection``; ``FuserError`` naming it if it cannot be (a port in use, no such device)."""
        self.settings = settings
        self.sent = 0
        self.errors = 0
        self.error: str | None = None
        self._period_ns = round(1e9 / settings.rate_hz)
        self._next_attitude_ns: int | None = None
        self._next_heartbeat_ns: int | None = None
        self._vehicle: SourceId | None = None
        self._gyro_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._gyro_source: SourceId | None = None
        self._last_imu_ns: int | None = None
        self.withheld = 0
        """Attitudes due but not sent: no IMU sample for ``STALE_AFTER_NS``."""
        self._t0_ns: int | None = None
        self._conn: Any = None
        os.environ.setdefault("MAVLINK20", "1")  # mavutil speaks MAVLink 1 unless told before its first import
        from pymavlink import mavutil  # here: importing the settings (fuser.config does) needs no pymavlink

        self._mavlink = mavutil.mavlink
        try:
            self._conn = mavutil.mavlink_connection(
                settings.connection, dialect="common", source_system=settings.system_id or DEFAULT_SYSTEM_ID,
                source_component=settings.component_id)
        except (OSError, ValueError, OverflowError) as e:  # sockets, pyserial (SerialException is an OSError)
            raise FuserError(f"cannot open --mavlink-out {settings.connection}: {getattr(e, 'strerror', None) or e}") from e

    @property
    def system_id(self) -> int:
        return self._conn.mav.srcSystem if self._conn is not None else (self.settings.system_id or DEFAULT_SYSTEM_ID)

    def _fail(self, message: str) -> None:
        self.errors += 1
        if self.error is None:
            self.error = message
            log.error("mavlink-out: %s", message)

    def write_sample(self, sample: Sample, receive_ns: int) -> None:
        """Learn the vehicle's system id from its first MAVLink sample; keep the latest gyro of the first IMU and
        when the last IMU sample arrived (an InputSink)."""
        if self._vehicle is None and sample.source.transport == "mavlink":
            self._vehicle = sample.source
            if self.settings.system_id is None and self._conn is not None:
                self._conn.mav.srcSystem = sample.source.system
        if isinstance(sample, ImuSample):
            self._last_imu_ns = receive_ns if self._last_imu_ns is None else max(self._last_imu_ns, receive_ns)
            if self._gyro_source is None:
                self._gyro_source = sample.source
            if sample.source == self._gyro_source:
                self._gyro_rad_s = sample.gyro_rad_s

    def publish_estimate(self, est: Estimate) -> None:
        """Send what is due at this estimate's time (an EstimateSink)."""
        if self._conn is None:
            self.errors += 1
            return
        t = est.t_ns
        if self._t0_ns is None:
            self._t0_ns = self._next_attitude_ns = self._next_heartbeat_ns = t
        mav = self._conn.mav
        try:
            if t >= self._next_heartbeat_ns:
                self._next_heartbeat_ns = _next(self._next_heartbeat_ns, HEARTBEAT_PERIOD_NS, t)
                ml = self._mavlink
                mav.heartbeat_send(ml.MAV_TYPE_ONBOARD_CONTROLLER, ml.MAV_AUTOPILOT_INVALID, 0, 0, ml.MAV_STATE_ACTIVE)
                self.sent += 1
            if t >= self._next_attitude_ns:
                self._next_attitude_ns = _next(self._next_attitude_ns, self._period_ns, t)
                if self._stale(t):
                    self.withheld += 1
                    return
                boot_ms = (est.t_ns - self._t0_ns if est.sensor_t_ns is None else est.sensor_t_ns) // 1_000_000 % 2**32
                p, q, r = self._gyro_rad_s
                mav.attitude_quaternion_send(boot_ms, *est.q_wxyz, p, q, r, (0.0, 0.0, 0.0, 0.0))
                self.sent += 1
                if self.settings.send_attitude:
                    roll, pitch, yaw = (math.radians(a) for a in est.euler_deg)
                    mav.attitude_send(boot_ms, roll, pitch, yaw, p, q, r)
                    self.sent += 1
        except Exception as e:  # noqa: BLE001 - socket or serial failure: count it, keep the loop going
            self._fail(f"send failed: {e}")

    def _stale(self, t_ns: int) -> bool:
        """Whether an estimate at ``t_ns`` is carried past its input: no IMU sample for over ``STALE_AFTER_NS``."""
        return self._last_imu_ns is None or t_ns - self._last_imu_ns > STALE_AFTER_NS

    def close(self) -> None:
        if self._conn is not None:
            conn, self._conn = self._conn, None
            try:
                conn.close()
            except Exception as e:  # noqa: BLE001
                self._fail(f"close failed: {e}")


def _next(due_ns: int, period_ns: int, t_ns: int) -> int:
    """The first due time after ``t_ns`` on the grid ``due_ns + k period`` (a gap skips, never bursts)."""
    return due_ns + ((t_ns - due_ns) // period_ns + 1) * period_ns
