"""Samples to MAVLink bytes, each decoded message type available (simulator, tests, replay)."""

from __future__ import annotations

import math
import struct
from typing import Any

from .euler import euler_from_quaternion
from .mavlink_decode import (
    CENTI,
    DEG_E7,
    GPS_INPUT_IGNORE_SPEED_ACCURACY,
    GPS_INPUT_IGNORE_VEL_HORIZ,
    GPS_INPUT_IGNORE_VEL_VERT,
    HIGHRES_MAG_BITS,
    IMU_MESSAGES,
    MG_TO_M_S2,
    MILLI,
    SCALED_IMU_INSTANCE,
    UINT16_UNKNOWN,
    dialect_module,
)
from .samples import AttitudeSample, GnssSample, ImuSample, Sample, Vec3
from .timebase import NS_PER_MS, NS_PER_US

HIGHRES_ACCEL_GYRO_BITS = 0x3F
ATTITUDE_MESSAGES = ("ATTITUDE_QUATERNION", "ATTITUDE")
GNSS_MESSAGES = ("GPS_RAW_INT", "GLOBAL_POSITION_INT", "GPS_INPUT", "HIL_GPS")
HEARTBEAT_PERIOD_NS = 1_000_000_000
"""An autopilot sends HEARTBEAT at 1 Hz."""
_INT16 = 32767
MESSAGES_OF = {ImuSample: IMU_MESSAGES, AttitudeSample: ATTITUDE_MESSAGES, GnssSample: GNSS_MESSAGES}
"""The messages :meth:`MavlinkEncoder.encode` writes, by sample type."""


class UnencodableSample(ValueError):
    """A sample with a value its message has no field for: a time before 0 or beyond the field's integer, a
    NaN or infinite value where the message holds an integer (a damaged log's record, say)."""


def _milli(v: Vec3 | None, scale: float) -> tuple[int, int, int]:
    """Integer milli-units (int16, saturated) of a vector; zeros for None."""
    if v is None:
        return (0, 0, 0)
    return tuple(max(-_INT16, min(_INT16, round(c / scale))) for c in v)  # type: ignore[return-value]


class MavlinkEncoder:
    """Pack samples as MAVLink 2 frames from one sender, with its own sequence counter.

    Like an autopilot, the sender announces itself: a HEARTBEAT (``vehicle_type``, ``autopilot``:
    MAV_TYPE and MAV_AUTOPILOT values) goes before its first frame and then once a second of
    sample time, so that a receiver locked onto the first autopilot heard accepts its data.
    ``heartbeat=False`` leaves them out (single frames in tests).
    """

    def __init__(
        self,
        system: int = 1,
        component: int = 1,
        dialect: str = "common",
        heartbeat: bool = True,
        vehicle_type: int = 2,  # MAV_TYPE_QUADROTOR
        autopilot: int = 0,  # MAV_AUTOPILOT_GENERIC
    ) -> None:
        self._mod = dialect_module(dialect)
        self.mav = self._mod.MAVLink(None, srcSystem=system, srcComponent=component)
        self._heartbeat = self._mod.MAVLink_heartbeat_message(vehicle_type, autopilot, 0, 0, 4, 3) if heartbeat else None  # MAV_STATE_ACTIVE
        self._next_heartbeat_ns: int | None = None

    def encode(self, sample: Sample, message: str | None = None) -> bytes:
        """Frame of ``sample`` as ``message`` (default HIGHRES_IMU for IMU, ATTITUDE_QUATERNION for attitude),
        after a HEARTBEAT when one is due.

        Raises :class:`UnencodableSample` for a sample the message cannot hold (nothing is sent, the sequence
        and the HEARTBEAT schedule stay as they were), ValueError for a message that is not one of the sample's
        (:data:`MESSAGES_OF`).
        """
        if message is not None and message not in MESSAGES_OF.get(type(sample), ()):
            raise ValueError(f"{message!r} is not a message for {type(sample).__name__}: {MESSAGES_OF.get(type(sample), ())}")
        seq, next_heartbeat_ns = self.mav.seq, self._next_heartbeat_ns
        try:
            msg = self.message(sample, message)
            data = b""
            if self._heartbeat is not None and (self._next_heartbeat_ns is None or sample.t_ns >= self._next_heartbeat_ns):
                data = self._pack(self._heartbeat)
                self._next_heartbeat_ns = sample.t_ns + HEARTBEAT_PERIOD_NS
            return data + self._pack(msg)
        except (struct.error, OverflowError, ValueError) as e:  # an integer field's range; round() of NaN or infinity
            self.mav.seq, self._next_heartbeat_ns = seq, next_heartbeat_ns
            raise UnencodableSample(f"{type(sample).__name__} at {sample.t_ns} ns does not fit {message or 'its message'}: {e}") from e

    def _pack(self, msg: Any) -> bytes:
        data = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data

    def message(self, sample: Sample, message: str | None = None) -> Any:
        """The pymavlink message object ``encode`` would pack."""
        if isinstance(sample, ImuSample):
            return self._imu_message(sample, message or "HIGHRES_IMU")
        if isinstance(sample, AttitudeSample):
            return self._attitude_message(sample, message or "ATTITUDE_QUATERNION")
        if isinstance(sample, GnssSample):
            return self._gnss_message(sample, message or "GPS_RAW_INT")
        raise TypeError(f"MAVLink carries magnetometer data inside IMU messages, not {type(sample).__name__}")

    def _imu_message(self, s: ImuSample, message: str) -> Any:
        m = self._mod
        if message == "HIGHRES_IMU":
            mag = s.mag_gauss or (0.0, 0.0, 0.0)
            updated = HIGHRES_ACCEL_GYRO_BITS | (HIGHRES_MAG_BITS if s.mag_gauss is not None else 0)
            return m.MAVLink_highres_imu_message(
                s.t_ns // NS_PER_US, *s.accel_m_s2, *s.gyro_rad_s, *mag, 0.0, 0.0, 0.0, 0.0, updated, s.source.instance
            )
        fields = (*_milli(s.accel_m_s2, MG_TO_M_S2), *_milli(s.gyro_rad_s, MILLI), *_milli(s.mag_gauss, MILLI))
        if message == "RAW_IMU":
            return m.MAVLink_raw_imu_message(s.t_ns // NS_PER_US, *fields, s.source.instance, 0)
        if message in SCALED_IMU_INSTANCE:
            cls = getattr(m, f"MAVLink_{message.lower()}_message")
            return cls(self._time_boot_ms(s.t_ns), *fields, 0)
        raise ValueError(f"{message!r} is not one of {IMU_MESSAGES}")

    def _attitude_message(self, s: AttitudeSample, message: str) -> Any:
        m = self._mod
        if message == "ATTITUDE_QUATERNION":
            return m.MAVLink_attitude_quaternion_message(self._time_boot_ms(s.t_ns), *s.q_wxyz, 0.0, 0.0, 0.0, [0.0] * 4)
        if message == "ATTITUDE":
            return m.MAVLink_attitude_message(self._time_boot_ms(s.t_ns), *euler_from_quaternion(s.q_wxyz), 0.0, 0.0, 0.0)
        raise ValueError(f"{message!r} is not one of {ATTITUDE_MESSAGES}")

    def _gnss_message(self, s: GnssSample, message: str) -> Any:
        m = self._mod
        lat, lon = (0, 0) if s.lat_deg is None else (round(s.lat_deg / DEG_E7), round(s.lon_deg / DEG_E7))  # type: ignore[operator]
        alt_mm = 0 if s.alt_m is None else round(s.alt_m / MILLI)
        vn, ve, vd = s.vel_ned_m_s or (0.0, 0.0, 0.0)
        if message == "GPS_RAW_INT":
            if s.vel_ned_m_s is None:
                vel, cog = UINT16_UNKNOWN, UINT16_UNKNOWN
            else:
                vel = round(math.hypot(vn, ve) / CENTI)
                cog = round(math.degrees(math.atan2(ve, vn)) % 360.0 / CENTI) % 36000
            vel_acc = 0 if s.speed_accuracy_m_s is None else round(s.speed_accuracy_m_s / MILLI)
            return m.MAVLink_gps_raw_int_message(
                s.t_ns // NS_PER_US, s.fix_type, lat, lon, alt_mm, UINT16_UNKNOWN, UINT16_UNKNOWN, vel, cog, 10,
                alt_mm, 0, 0, vel_acc, 0, 0,
            )
        if message == "GLOBAL_POSITION_INT":
            return m.MAVLink_global_position_int_message(
                self._time_boot_ms(s.t_ns), lat, lon, alt_mm, 0, round(vn / CENTI), round(ve / CENTI), round(vd / CENTI), UINT16_UNKNOWN
            )
        if message == "GPS_INPUT":
            ignore = (0 if s.vel_ned_m_s is not None else GPS_INPUT_IGNORE_VEL_HORIZ) | (0 if s.vertical_velocity else GPS_INPUT_IGNORE_VEL_VERT)
            ignore |= GPS_INPUT_IGNORE_SPEED_ACCURACY if s.speed_accuracy_m_s is None else 0
            return m.MAVLink_gps_input_message(
                s.t_ns // NS_PER_US, s.source.instance, ignore, 0, 0, s.fix_type, lat, lon, s.alt_m or 0.0, 1.0, 1.0,
                vn, ve, vd, s.speed_accuracy_m_s or 0.0, 0.0, 0.0, 10, 0,
            )
        if message == "HIL_GPS":
            return m.MAVLink_hil_gps_message(
                s.t_ns // NS_PER_US, s.fix_type, lat, lon, alt_mm, UINT16_UNKNOWN, UINT16_UNKNOWN, UINT16_UNKNOWN,
                round(vn / CENTI), round(ve / CENTI), round(vd / CENTI), UINT16_UNKNOWN, 10, s.source.instance, 0,
            )
        raise ValueError(f"{message!r} is not one of {GNSS_MESSAGES}")

    @staticmethod
    def _time_boot_ms(t_ns: int) -> int:
        return (t_ns // NS_PER_MS) & 0xFFFFFFFF


def encode_mavlink(sample: Sample, message: str | None = None, system: int = 1, component: int = 1) -> bytes:
    """One MAVLink 2 frame (sequence 0, no HEARTBEAT) of ``sample``; see ``MavlinkEncoder`` for streams."""
    return MavlinkEncoder(system, component, heartbeat=False).encode(sample, message)
