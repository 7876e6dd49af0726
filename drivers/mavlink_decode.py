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
GPS_INPUT           time_usec (us)          vn, ve, vd m/s NED          lat/lon degE7, alt m
HIL_GPS             time_usec (us)          vn, ve, vd cm/s NED         lat/lon degE7, alt mm
==================  ======================  ==========================  ============

``time_usec`` is "UNIX Epoch time or time since system boot", told apart, as the MAVLink
definitions say, by its magnitude: from 10^15 us (September 2001) on it is Unix time.

Before any message becomes a sample, the decoder chooses the vehicle (``drivers.link``:
by default the first autopilot HEARTBEAT's system and component; everyone else is
``other_sender``) and counts the frames missing in the vehicle's sequence numbers as ``lost``.
"""

from __future__ import annotations

import importlib
import logging
import math
from collections import Counter
from typing import Any, Callable

from .decoder import BOOT_CLOCK, Decoder, Sender, Stream
from .euler import quaternion_from_euler
from .link import LinkSettings
from .mavlink_frames import FrameParser
from .samples import AttitudeSample, GnssSample, ImuSample, Sample, Vec3
from .timebase import NS_PER_US
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
EPOCH_CLOCK = "epoch"
EPOCH_MIN_US = 10**15
"""A ``time_usec`` this large is Unix time, not time since boot (31.7 years of uptime)."""
REORDER_MAX = 16
"""A step back in a sender's sequence numbers by at most this much is a reordered frame, not a restart."""
IMU_MESSAGES = ("HIGHRES_IMU", "RAW_IMU", *SCALED_IMU_INSTANCE)
"""The message types that carry an IMU sample."""
GPS_INPUT_IGNORE_ALT, GPS_INPUT_IGNORE_VEL_HORIZ, GPS_INPUT_IGNORE_VEL_VERT, GPS_INPUT_IGNORE_SPEED_ACCURACY = 1, 8, 16, 32
"""GPS_INPUT ``ignore_flags`` bits (GPS_INPUT_IGNORE_FLAGS) of the fields the decoder uses."""
NOT_A_VEHICLE = (
    "GCS", "ANTENNA_TRACKER", "ONBOARD_CONTROLLER", "GIMBAL", "ADSB", "CAMERA", "CHARGING_STATION", "FLARM",
    "SERVO", "ODID", "BATTERY", "PARACHUTE", "LOG", "OSD", "IMU", "GPS", "WINCH", "ILLUMINATOR", "GRIPPER",
)
"""MAV_TYPE names of peripherals and ground stations: their HEARTBEATs never choose the vehicle."""
MAX_OTHER_VEHICLES = 16
"""Other vehicles named in :attr:`MavlinkDecoder.other_vehicles` at most (HEARTBEATs from any ids cost no more)."""


def dialect_module(dialect: str) -> Any:
    """The MAVLink 2 pymavlink module of ``dialect`` (it parses MAVLink 1 frames too)."""
    return importlib.import_module(f"pymavlink.dialects.v20.{dialect}")


class MavlinkDecoder(Decoder):
    """Decode MAVLink bytes into samples: ``feed`` for a byte stream, ``feed_datagram`` for whole datagrams or log records.

    ``link`` chooses the vehicle, the signing key and the dialect (``drivers.link``); without one
    every sender is used, in the ``ardupilotmega`` dialect, unsigned (tests, the simulator, imports).
    ``signing_timestamp``: see :class:`~drivers.mavlink_frames.FrameParser`. ``screen``: once the
    vehicle is chosen, count other senders' frames without decoding them (a flood costs a header
    read per frame); a log reader turns it off to count every sender's messages. ``received``
    counts the valid messages of every type decoded (used or not), ``used`` those that became
    samples; ``stats`` counts ``accepted`` and every reason a frame or message was not used.
    """

    imu_types = IMU_MESSAGES
    """The message types that carry IMU samples (keys of ``received`` and ``used``)."""

    def __init__(
        self,
        link: LinkSettings | None = None,
        signing_timestamp: int | None = None,
        screen: bool = True,
        **decoder_options: Any,
    ) -> None:
        super().__init__("mavlink", log, **decoder_options)
        self.link = link if link is not None else LinkSettings(lock_first_autopilot=False)
        mod = dialect_module(self.link.dialect)
        self.frames = FrameParser(mod, self._note, self.link.signing_key(), signing_timestamp)
        self._received: dict[type, int] = {}
        self._used: dict[type, int] = {}
        self.system = self.link.system
        """System id data is taken from (None: any, or not chosen yet)."""
        self.component = self.link.component
        """Component id data is taken from (None: any, or not chosen yet)."""
        self.autopilot: int | None = None
        """MAV_AUTOPILOT of the vehicle's last HEARTBEAT (None before one, or with every sender used)."""
        self.other_vehicles: set[tuple[int, int]] = set()
        """(system, component) of the other vehicles whose autopilot HEARTBEAT was heard once the vehicle was chosen
        (their data counted ``other_sender``), at most :data:`MAX_OTHER_VEHICLES`."""
        self._awaiting_autopilot = self.link.system is None and self.link.lock_first_autopilot
        self._heartbeat = mod.MAVLink_heartbeat_message
        self._not_a_vehicle = frozenset(getattr(mod, f"MAV_TYPE_{name}") for name in NOT_A_VEHICLE if hasattr(mod, f"MAV_TYPE_{name}"))
        self._invalid_autopilot = mod.MAV_AUTOPILOT_INVALID
        self._gimbal_component = mod.MAV_COMP_ID_GIMBAL
        self._handlers: dict[type, Callable[[Any], Sample]] = {
            mod.MAVLink_attitude_message: self._attitude,
            mod.MAVLink_attitude_quaternion_message: self._attitude_quaternion,
            mod.MAVLink_highres_imu_message: self._highres_imu,
            mod.MAVLink_raw_imu_message: self._raw_imu,
            mod.MAVLink_gps_raw_int_message: self._gps_raw_int,
            mod.MAVLink_global_position_int_message: self._global_position_int,
            mod.MAVLink_gps_input_message: self._gps_input,
            mod.MAVLink_hil_gps_message: self._hil_gps,
        }
        for name in SCALED_IMU_INSTANCE:
            self._handlers[getattr(mod, f"MAVLink_{name.lower()}_message")] = self._scaled_imu
        self._imu_kinds = tuple(getattr(mod, f"MAVLink_{name.lower()}_message") for name in IMU_MESSAGES)
        self._screen = screen
        self._set_screen()

    def _set_screen(self) -> None:
        """Let the frame parser skip other senders' frames once the vehicle is chosen (see FrameParser)."""
        system, component = self.system, self.component
        if self._screen and system is not None:
            self.frames.screen = lambda s, c: s == system and (component is None or c == component)

    def feed(self, data: bytes, receive_ns: int | None = None) -> list[Sample]:
        """Samples completed by ``data``, any split of a byte stream (serial, TCP).

        ``receive_ns``, the receiver's time of ``data`` where known, keeps a stream's time line
        continuous in receive time across a sender's reboot (see ``StreamClock``).
        """
        self._receive_ns = receive_ns
        return self._decode_all(self.frames.parse(data))

    def feed_datagram(self, data: bytes, receive_ns: int | None = None) -> list[Sample]:
        """Samples of ``data``, a whole datagram or log record: a frame cut short at its end is ``truncated``."""
        self._receive_ns = receive_ns
        return self._decode_all(self.frames.parse(data, complete=True))

    @property
    def received(self) -> Counter[str]:
        """Valid messages decoded, by type name (every sender, used or not)."""
        return Counter({kind.msgname: n for kind, n in self._received.items()})

    @property
    def used(self) -> Counter[str]:
        """Messages that became samples, by type name."""
        return Counter({kind.msgname: n for kind, n in self._used.items()})

    @property
    def imu_used(self) -> int:
        """IMU messages that became samples (of :attr:`imu_types`; cheap enough to ask at every poll)."""
        return sum(self._used.get(kind, 0) for kind in self._imu_kinds)

    def _decode_all(self, messages: list[Any]) -> list[Sample]:
        """Samples of valid messages; the others are counted (not from the vehicle, ignored, refused)."""
        samples = []
        stats, received, senders, handlers = self.stats, self._received, self._senders, self._handlers
        for msg in messages:
            kind = type(msg)
            received[kind] = received.get(kind, 0) + 1
            if self._awaiting_autopilot:
                if kind is not self._heartbeat or not self._is_autopilot(msg):
                    stats["no_vehicle_yet"] += 1
                    continue
                self._lock(msg)
            header = msg._header
            system, component = header.srcSystem, header.srcComponent
            if (self.system is not None and system != self.system) or (self.component is not None and component != self.component):
                stats["other_sender"] += 1
                if kind is self._heartbeat and len(self.other_vehicles) < MAX_OTHER_VEHICLES and self._is_vehicle(msg):
                    self.other_vehicles.add((system, component))
                continue
            handler = handlers.get(kind)
            try:
                sender = senders.get((system, component)) or self._sender((system, component))
                if sender.last_seq is not None and header.seq == (sender.last_seq + 1) & 0xFF:
                    sender.last_seq = header.seq  # the usual case: the next frame
                else:
                    self._sequence(sender, header.seq)
                if handler is None:
                    if kind is self._heartbeat and self.system is not None and msg.autopilot != self._invalid_autopilot:
                        self.autopilot = msg.autopilot
                    stats["ignored"] += 1
                    continue
                sample = handler(msg)
            except Rejected as rejected:
                self._note(rejected.reason, f"{msg._type}: {rejected.detail}")
                continue
            stats["accepted"] += 1
            self._used[kind] = self._used.get(kind, 0) + 1
            samples.append(sample)
        return samples

    def _is_vehicle(self, hb: Any) -> bool:
        """pymavlink's ``probably_vehicle_heartbeat``, with every peripheral MAV_TYPE excluded."""
        return hb.autopilot != self._invalid_autopilot and hb.type not in self._not_a_vehicle and hb.get_srcComponent() != self._gimbal_component

    def _is_autopilot(self, hb: Any) -> bool:
        """:meth:`_is_vehicle`, from the component asked for if one was."""
        return self._is_vehicle(hb) and (self.component is None or hb.get_srcComponent() == self.component)

    def _lock(self, hb: Any) -> None:
        self._awaiting_autopilot = False
        self.system, self.component = hb.get_srcSystem(), hb.get_srcComponent()
        self._set_screen()
        log.info("vehicle: system %d component %d (autopilot %d, type %d)", self.system, self.component, hb.autopilot, hb.type)

    def _sequence(self, sender: Sender, seq: int) -> None:
        """Note the frames missing before ``seq``: a step forward of 2-128 misses 1-127 frames.

        A repeated number (a duplicate, or exactly 256 frames lost) counts nothing; so does a step
        back: by up to REORDER_MAX a late frame (the sequence stays where it was), further a restart
        or a jump (it continues from ``seq``). A gap waits as ``pending_lost`` until a boot time
        from the sender shows whether it restarted (see ``Decoder._settle``).
        """
        last = sender.last_seq
        if last is None:
            sender.last_seq = seq
            return
        gap = (seq - last - 1) & 0xFF
        if gap >= 256 - REORDER_MAX:  # 255: the same number again; 240-254: a frame overtaken on the way
            return
        sender.last_seq = seq
        if 0 < gap < 128:
            self.stats["lost"] += sender.pending_lost
            sender.pending_lost = gap

    def _stream_of(self, msg: Any, instance: int = 0) -> Stream:
        return self._stream(type(msg), msg.get_srcSystem(), msg.get_srcComponent(), instance)

    def _stamp_usec(self, stream: Stream, time_usec: int) -> int:
        """Time of a ``time_usec`` field: Unix time from EPOCH_MIN_US on, time since boot below."""
        return self._stamp(stream, time_usec * NS_PER_US, EPOCH_CLOCK if time_usec >= EPOCH_MIN_US else BOOT_CLOCK)

    def _imu(self, m: Any, instance: int, gyro: Vec3, accel: Vec3, mag: Vec3 | None, time_usec: int | None) -> ImuSample:
        """Validated sample; stamped by ``time_usec``, or by ``time_boot_ms`` when that is None."""
        check_vector("gyro", gyro, GYRO_MAX_RAD_S)
        check_vector("accel", accel, ACCEL_MAX_M_S2)
        if mag is not None:
            check_vector("mag", mag, MAG_MAX_GAUSS)
        stream = self._stream_of(m, instance)
        t_ns = self._stamp_ms_u32(stream, m.time_boot_ms) if time_usec is None else self._stamp_usec(stream, time_usec)
        return ImuSample(t_ns, gyro, accel, mag, stream.source)

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
        return self._milli_imu(m, SCALED_IMU_INSTANCE[m._type], None)

    def _raw_imu(self, m: Any) -> ImuSample:
        return self._milli_imu(m, m.id, m.time_usec)

    def _attitude(self, m: Any) -> AttitudeSample:
        roll, pitch, yaw = check_vector("euler", (m.roll, m.pitch, m.yaw), _ANGLE_LIMIT)
        stream = self._stream_of(m)
        return AttitudeSample(self._stamp_ms_u32(stream, m.time_boot_ms), quaternion_from_euler(roll, pitch, yaw), stream.source)

    def _attitude_quaternion(self, m: Any) -> AttitudeSample:
        q = check_quaternion((m.q1, m.q2, m.q3, m.q4))
        stream = self._stream_of(m)
        return AttitudeSample(self._stamp_ms_u32(stream, m.time_boot_ms), q, stream.source)

    def _position(self, m: Any, alt_m: float | None) -> tuple[float | None, float | None, float | None]:
        """WGS84 latitude, longitude (degE7 fields) and MSL altitude of a GNSS message; all None for 0, 0 (unknown)."""
        if m.lat == 0 and m.lon == 0:
            return None, None, None
        lat, lon, alt = check_position(m.lat * DEG_E7, m.lon * DEG_E7, 0.0 if alt_m is None else alt_m)
        return lat, lon, None if alt_m is None else alt

    def _gps_raw_int(self, m: Any) -> GnssSample:
        """A receiver's fix: ground speed along the course over ground (no vertical velocity)."""
        vel = None
        if m.fix_type >= FIX_2D and m.vel != UINT16_UNKNOWN and m.cog != UINT16_UNKNOWN:
            speed, course = m.vel * CENTI, math.radians(m.cog * CENTI)
            vel = check_vector("gnss_velocity", (speed * math.cos(course), speed * math.sin(course), 0.0), GNSS_VELOCITY_MAX_M_S)
        accuracy = getattr(m, "vel_acc", 0) * MILLI or None  # extension field, 0 = unknown
        lat, lon, alt = self._position(m, m.alt * MILLI) if m.fix_type >= FIX_2D else (None, None, None)
        stream = self._stream_of(m)
        return GnssSample(self._stamp_usec(stream, m.time_usec), m.fix_type, vel, False, accuracy, lat, lon, alt, False, stream.source)

    def _global_position_int(self, m: Any) -> GnssSample:
        """The autopilot's fused navigation solution: NED velocity, position (fix type 3 by definition)."""
        vel = check_vector("gnss_velocity", (m.vx * CENTI, m.vy * CENTI, m.vz * CENTI), GNSS_VELOCITY_MAX_M_S)
        lat, lon, alt = self._position(m, m.alt * MILLI)
        stream = self._stream_of(m)
        return GnssSample(self._stamp_ms_u32(stream, m.time_boot_ms), 3, vel, True, None, lat, lon, alt, True, stream.source)

    def _gps_input(self, m: Any) -> GnssSample:
        """A receiver's fix injected by a companion computer: NED velocity in m/s, fields switched off by ``ignore_flags``."""
        ignore = m.ignore_flags
        vel, vertical = None, False
        if m.fix_type >= FIX_2D and not ignore & GPS_INPUT_IGNORE_VEL_HORIZ:
            vertical = not ignore & GPS_INPUT_IGNORE_VEL_VERT
            vel = check_vector("gnss_velocity", (m.vn, m.ve, m.vd if vertical else 0.0), GNSS_VELOCITY_MAX_M_S)
        accuracy = None if ignore & GPS_INPUT_IGNORE_SPEED_ACCURACY or not m.speed_accuracy > 0 else m.speed_accuracy
        position = self._position(m, None if ignore & GPS_INPUT_IGNORE_ALT else m.alt) if m.fix_type >= FIX_2D else (None, None, None)
        stream = self._stream_of(m, m.gps_id)
        return GnssSample(self._stamp_usec(stream, m.time_usec), m.fix_type, vel, vertical, accuracy, *position, False, stream.source)

    def _hil_gps(self, m: Any) -> GnssSample:
        """A simulator's GNSS fix: NED velocity in cm/s (no accuracy: ``eph``/``epv`` are dilutions)."""
        vel = None
        if m.fix_type >= FIX_2D:
            vel = check_vector("gnss_velocity", (m.vn * CENTI, m.ve * CENTI, m.vd * CENTI), GNSS_VELOCITY_MAX_M_S)
        position = self._position(m, m.alt * MILLI) if m.fix_type >= FIX_2D else (None, None, None)
        stream = self._stream_of(m, m.id)
        return GnssSample(self._stamp_usec(stream, m.time_usec), m.fix_type, vel, vel is not None, None, *position, False, stream.source)
