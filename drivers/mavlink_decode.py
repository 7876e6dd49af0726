"""MAVLink bytes to samples: ATTITUDE, ATTITUDE_QUATERNION, HIGHRES_IMU, SCALED_IMU/2/3, RAW_IMU,
GPS_RAW_INT, GLOBAL_POSITION_INT.

Unit scaling, as the message definitions document it:

==================  ======================  ==========================  ============
message             time                    gyro / accel                mag
==================  ======================  ==========================  ============
HIGHRES_IMU         time_usec (us)          rad/s, m/s^2                gauss
SCALED_IMU[2,3]     time_boot_ms (uint32)   mrad/s, mG (g=9.80665)      mgauss
RAW_IMU             time_usec (us)          mrad/s, mG (as ArduPilot)   mgauss
ATTITUDE            time_boot_ms (uint32)   roll/pitch/yaw rad (3-2-1)  -
ATTITUDE_QUATERNION time_boot_ms (uint32)   q1..q4 = w, x, y, z         -
GPS_RAW_INT         time_usec (us)          vel cm/s, cog cdeg (no down) lat/lon degE7, alt mm
GLOBAL_POSITION_INT time_boot_ms (uint32)   vx, vy, vz cm/s NED         lat/lon degE7, alt mm
==================  ======================  ==========================  ============
"""

from __future__ import annotations

import importlib
import logging
import math
from typing import Any, Callable

from .decoder import Decoder
from .euler import quaternion_from_euler
from .samples import AttitudeSample, GnssSample, ImuSample, Sample, SourceId, Vec3
from .timebase import NS_PER_US, StreamClock
from .validation import (
    ACCEL_MAX_M_S2,
    GNSS_VELOCITY_MAX_M_S,
    GYRO_MAX_RAD_S,
    MAG_MAX_GAUSS,
    Rejected,
    check_position,
    check_quaternion,
    check_vector,
)

log = logging.getLogger(__name__)

STANDARD_GRAVITY = 9.80665
MG_TO_M_S2 = STANDARD_GRAVITY / 1000.0
MILLI = 1e-3
HIGHRES_MAG_BITS = 0x1C0
"""HIGHRES_IMU ``fields_updated`` bits 6-8: the magnetometer axes are new in this message."""
SCALED_IMU_INSTANCE = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
DEG_E7 = 1e-7
CENTI = 1e-2
UINT16_UNKNOWN = 0xFFFF
"""GPS_RAW_INT's ``vel`` and ``cog`` when the receiver does not know them."""
FIX_2D = 2
"""GPS_FIX_TYPE of the first fix that carries a velocity."""
_ANGLE_LIMIT = 7.0  # radians; MAVLink Euler angles are within +-pi


def dialect_module(dialect: str) -> Any:
    """The MAVLink 2 pymavlink module of ``dialect`` (it parses MAVLink 1 frames too)."""
    return importlib.import_module(f"pymavlink.dialects.v20.{dialect}")


def _bad_data_reason(text: str) -> str:
    if text == "Bad prefix":
        return "garbage"
    if text.startswith("invalid MAVLink CRC"):
        return "bad_crc"
    return "bad_frame"


class MavlinkDecoder(Decoder):
    """Decode MAVLink bytes (``feed``) or parsed messages (``decode_message``) into samples.

    ``system``/``component`` keep only messages from that sender (None: all).
    ``parser`` is the pymavlink ``MAVLink`` object that frames the bytes (a
    connection's ``.mav`` when the bytes come through ``mavutil``); it is set
    to robust parsing. After a frame fails (bad CRC, bad header) or turns out
    to be an unknown message, the decoder hands the parser every byte of it
    but the first again, so a valid packet swallowed by a false header found
    in garbage is still decoded.
    """

    def __init__(
        self,
        system: int | None = None,
        component: int | None = None,
        dialect: str = "common",
        parser: Any = None,
        **decoder_options: Any,
    ) -> None:
        super().__init__("mavlink", log, **decoder_options)
        mod = dialect_module(dialect)
        self.parser = parser if parser is not None else mod.MAVLink(None)
        self.parser.robust_parsing = True
        self._system = system
        self._component = component
        self._bad_data = mod.MAVLink_bad_data
        self._unknown = mod.MAVLink_unknown
        self._handlers: dict[type, Callable[[Any], Sample]] = {
            mod.MAVLink_attitude_message: self._attitude,
            mod.MAVLink_attitude_quaternion_message: self._attitude_quaternion,
            mod.MAVLink_highres_imu_message: self._highres_imu,
            mod.MAVLink_raw_imu_message: self._raw_imu,
            mod.MAVLink_gps_raw_int_message: self._gps_raw_int,
            mod.MAVLink_global_position_int_message: self._global_position_int,
        }
        for name in SCALED_IMU_INSTANCE:
            self._handlers[getattr(mod, f"MAVLink_{name.lower()}_message")] = self._scaled_imu

    def feed(self, data: bytes) -> list[Sample]:
        """Parse ``data`` (any split of a byte stream) and return the samples completed by it."""
        samples = []
        parser = self.parser
        msg = parser.parse_char(data)
        while msg is not None:
            sample = self.decode_message(msg)
            if sample is not None:
                samples.append(sample)
            msg = parser.parse_char(b"")
        return samples

    def decode_message(self, msg: Any) -> Sample | None:
        """Sample of one parsed pymavlink message, or None (refusals are counted in ``stats``)."""
        handler = self._handlers.get(type(msg))
        if handler is None:
            self._not_decoded(msg)
            return None
        if (self._system is not None and msg.get_srcSystem() != self._system) or (
            self._component is not None and msg.get_srcComponent() != self._component
        ):
            self.stats["other_sender"] += 1
            return None
        try:
            sample = handler(msg)
        except Rejected as rejected:
            self._note(rejected.reason, f"{msg.get_type()}: {rejected.detail}")
            return None
        self.stats["accepted"] += 1
        return sample

    def _not_decoded(self, msg: Any) -> None:
        kind = type(msg)
        if kind is self._bad_data:
            reason = _bad_data_reason(msg.reason)
            self._note(reason, msg.reason)
            if reason != "garbage":
                self._rescan(msg.data)
        elif kind is self._unknown:
            self._note("unknown_message", msg.get_type())
            self._rescan(msg.data)
        else:
            self.stats["ignored"] += 1

    def _rescan(self, frame: bytes) -> None:
        """Put back all bytes of a refused frame but its first in front of the parser's buffer."""
        parser = self.parser
        parser.buf = bytearray(frame[1:]) + parser.buf[parser.buf_index :]
        parser.buf_index = 0

    def _stream_of(self, msg: Any, instance: int = 0) -> tuple[StreamClock, SourceId]:
        return self._stream(type(msg), msg.get_srcSystem(), msg.get_srcComponent(), instance)

    def _imu(self, m: Any, instance: int, gyro: Vec3, accel: Vec3, mag: Vec3 | None, time_usec: int | None) -> ImuSample:
        """Validated sample; stamped by ``time_usec``, or by ``time_boot_ms`` when that is None."""
        check_vector("gyro", gyro, GYRO_MAX_RAD_S)
        check_vector("accel", accel, ACCEL_MAX_M_S2)
        if mag is not None:
            check_vector("mag", mag, MAG_MAX_GAUSS)
        clock, source = self._stream_of(m, instance)
        t_ns = clock.stamp_ms_u32(m.time_boot_ms) if time_usec is None else clock.stamp(time_usec * NS_PER_US)
        return ImuSample(t_ns, gyro, accel, mag, source)

    def _highres_imu(self, m: Any) -> ImuSample:
        mag = (m.xmag, m.ymag, m.zmag) if m.fields_updated & HIGHRES_MAG_BITS else None
        return self._imu(m, m.id, (m.xgyro, m.ygyro, m.zgyro), (m.xacc, m.yacc, m.zacc), mag, m.time_usec)

    def _milli_imu(self, m: Any, instance: int, time_usec: int | None) -> ImuSample:
        """IMU sample from the integer mrad/s, mG, mgauss fields of SCALED_IMU* and RAW_IMU."""
        mag = None
        if m.xmag or m.ymag or m.zmag:  # all zero: no magnetometer behind this IMU
            mag = (m.xmag * MILLI, m.ymag * MILLI, m.zmag * MILLI)
        gyro = (m.xgyro * MILLI, m.ygyro * MILLI, m.zgyro * MILLI)
        accel = (m.xacc * MG_TO_M_S2, m.yacc * MG_TO_M_S2, m.zacc * MG_TO_M_S2)
        return self._imu(m, instance, gyro, accel, mag, time_usec)

    def _scaled_imu(self, m: Any) -> ImuSample:
        return self._milli_imu(m, SCALED_IMU_INSTANCE[m.get_type()], None)

    def _raw_imu(self, m: Any) -> ImuSample:
        return self._milli_imu(m, m.id, m.time_usec)

    def _attitude(self, m: Any) -> AttitudeSample:
        roll, pitch, yaw = check_vector("euler", (m.roll, m.pitch, m.yaw), _ANGLE_LIMIT)
        clock, source = self._stream_of(m)
        return AttitudeSample(clock.stamp_ms_u32(m.time_boot_ms), quaternion_from_euler(roll, pitch, yaw), source)

    def _attitude_quaternion(self, m: Any) -> AttitudeSample:
        q = check_quaternion((m.q1, m.q2, m.q3, m.q4))
        clock, source = self._stream_of(m)
        return AttitudeSample(clock.stamp_ms_u32(m.time_boot_ms), q, source)

    def _position(self, m: Any) -> tuple[float | None, float | None, float | None]:
        """WGS84 latitude, longitude (degE7) and MSL altitude (mm) of a GNSS message; all None for 0, 0 (unknown)."""
        if m.lat == 0 and m.lon == 0:
            return None, None, None
        return check_position(m.lat * DEG_E7, m.lon * DEG_E7, m.alt * MILLI)

    def _gps_raw_int(self, m: Any) -> GnssSample:
        """A receiver's fix: ground speed along the course over ground (no vertical velocity)."""
        vel = None
        if m.fix_type >= FIX_2D and m.vel != UINT16_UNKNOWN and m.cog != UINT16_UNKNOWN:
            speed, course = m.vel * CENTI, math.radians(m.cog * CENTI)
            vel = check_vector("gnss_velocity", (speed * math.cos(course), speed * math.sin(course), 0.0), GNSS_VELOCITY_MAX_M_S)
        accuracy = getattr(m, "vel_acc", 0) * MILLI or None  # extension field, 0 = unknown
        lat, lon, alt = self._position(m) if m.fix_type >= FIX_2D else (None, None, None)
        clock, source = self._stream_of(m)
        return GnssSample(clock.stamp(m.time_usec * NS_PER_US), m.fix_type, vel, False, accuracy, lat, lon, alt, False, source)

    def _global_position_int(self, m: Any) -> GnssSample:
        """The autopilot's fused navigation solution: NED velocity, position (fix type 3 by definition)."""
        vel = check_vector("gnss_velocity", (m.vx * CENTI, m.vy * CENTI, m.vz * CENTI), GNSS_VELOCITY_MAX_M_S)
        lat, lon, alt = self._position(m)
        clock, source = self._stream_of(m)
        return GnssSample(clock.stamp_ms_u32(m.time_boot_ms), 3, vel, True, None, lat, lon, alt, True, source)
