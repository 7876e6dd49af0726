"""DroneCAN frames (python-can ``Message``) to samples.

Decodes uavcan.equipment.ahrs.RawIMU (latest gyro and accel samples),
MagneticFieldStrength2, Solution and uavcan.equipment.gnss.Fix2 with the
``dronecan`` package's own DSDL definitions. Multi-frame transfers are reassembled here rather than by
``dronecan.transport.TransferManager`` (whose stale-transfer cleanup crashes
and whose per-transfer object set-up is 60% of its decode time); the CRC
uses ``binascii.crc_hqx``, the same CRC-16-CCITT as ``dronecan``'s own.

Times: RawIMU, Solution and Fix2 carry ``uavcan.Timestamp`` (the node's time
base, us; Fix2's is zero when the node has no synchronised time).
MagneticFieldStrength2 carries none (nor does a Fix2 with a zero timestamp),
so its time is the frame's receive time (``Message.timestamp``) moved onto the
node's time base by the offset of the least delayed timestamped transfer of the
*same node* (:class:`_TimeBase`; a stream that starts before one is seen stays
on the receive time): two nodes' clocks need not agree. Fix2's
``gnss_timestamp`` is on a GNSS time standard (UTC, GPS, TAI, with leap
seconds), not the node's clock, and is not used for the sample time.
"""

from __future__ import annotations

import binascii
import logging
import math
from collections import Counter
from typing import Any, Callable

import can
import dronecan
from dronecan.dsdl import CompoundType
from dronecan.transport import bits_from_bytes

from .decoder import Decoder, Stream
from .samples import AttitudeSample, GnssSample, ImuSample, MagSample, Sample
from .timebase import MAX_TIME_NS, NS_PER_US
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

RAW_IMU = "uavcan.equipment.ahrs.RawIMU"
MAG_FIELD = "uavcan.equipment.ahrs.MagneticFieldStrength2"
SOLUTION = "uavcan.equipment.ahrs.Solution"
FIX2 = "uavcan.equipment.gnss.Fix2"
MAX_PENDING_TRANSFERS = 64
"""Multi-frame transfers reassembled at once; one more is refused as ``too_many_transfers``."""
BUS_CLOCK = "bus"
"""A node's own time base (``uavcan.Timestamp``)."""
RECEIVE_CLOCK = "receive"
"""The receiver's clock, for a node whose time base has not been seen yet."""
FIX2_STATUS_2D = 2
FIX2_MODE_DGPS, FIX2_MODE_RTK = 1, 2
FIX2_SUB_MODE_RTK_FIXED = 1
FIX2_VELOCITY_VARIANCES = {6: (3, 4, 5), 36: (21, 28, 35)}
"""Where the north, east, down velocity variances sit in Fix2's ``covariance`` (6: the diagonal
of position then velocity; 36: the full 6x6 matrix), as ArduPilot's AP_GPS_DroneCAN reads it."""
TRANSFER_TIMEOUT_S = 1.0
TIME_BASE_DRIFT = 2e-4
"""How fast a node's time base may fall behind the receive clock (200 ppm; crystals drift tens of ppm)."""
TIME_BASE_STEP_NS = 1_000_000_000
"""A node time this much further behind the receive time than its time base says is a restart, not latency."""
_SERVICE_BIT = 1 << 7
_NODE_ID = 0x7F
"""The source node id in a frame's id; 0 is an anonymous frame (dynamic node id allocation)."""
_START, _END, _TOGGLE, _TID = 0x80, 0x40, 0x20, 0x1F


def data_type(full_name: str) -> Any:
    """The dronecan DSDL type object of a message name."""
    return dronecan.TYPENAMES[full_name]


class _Partial:
    """A multi-frame transfer being reassembled; once ``spoilt`` (refused and counted), its remaining frames are
    dropped without a count, so that one lost frame is one refusal."""

    __slots__ = ("tid", "toggle", "data", "last", "repeats", "t_first", "spoilt")

    def __init__(self, tid: int, data: bytes, t_first: float) -> None:
        self.tid = tid
        self.toggle = _TOGGLE
        self.data = bytearray(data)
        self.last = b""
        """The latest frame, tail byte included: a frame received twice repeats it (with the previous toggle bit)."""
        self.repeats = 0
        """Frames taken for repeats and dropped; counted (``duplicate_frame``) once the CRC shows they were."""
        self.t_first = t_first
        self.spoilt = False


class _TimeBase:
    """A node's time base against the receive clock: ``offset_ns`` = node time - receive time.

    Taken from the node's least delayed timestamped transfer rather than its latest: a fix is stamped with the
    time it was measured and sent a varying time later (tens of ms), and the latest one alone would move every
    untimestamped sample placed with it by that much. Between updates the offset stays put; at each update the
    kept one first drops by ``TIME_BASE_DRIFT`` of the receive time since the last, so a node clock running slow
    is followed, and a drop of more than ``TIME_BASE_STEP_NS`` (a restart, its uptime from zero) is taken at once.
    """

    __slots__ = ("offset_ns", "rx_ns")

    def __init__(self) -> None:
        self.offset_ns: int | None = None
        self.rx_ns = 0

    def update(self, offset_ns: int, rx_ns: int) -> None:
        """Take a timestamped transfer's ``node time - receive time`` (received at ``rx_ns``)."""
        kept = self.offset_ns
        if kept is not None:
            kept -= round(max(rx_ns - self.rx_ns, 0) * TIME_BASE_DRIFT)
            if kept - TIME_BASE_STEP_NS <= offset_ns < kept:
                offset_ns = kept
        self.offset_ns, self.rx_ns = offset_ns, rx_ns


class DroneCanDecoder(Decoder):
    """Feed CAN frames one by one (``feed``); returns the samples of each completed transfer."""

    imu_types = (RAW_IMU,)
    """The data types that carry IMU samples (keys of ``received`` and ``used``)."""

    def __init__(self, **decoder_options: Any) -> None:
        super().__init__("dronecan", log, **decoder_options)
        self._handlers: dict[int, tuple[Any, Any, Callable[[Any, int, float], Sample]]] = {}
        for name, handler in ((RAW_IMU, self._raw_imu), (MAG_FIELD, self._mag), (SOLUTION, self._solution), (FIX2, self._fix2)):
            dtype = data_type(name)
            # One payload object per type, unpacked into again for every transfer: creating
            # a fresh dronecan value object costs more than decoding it.
            self._handlers[dtype.default_dtid] = (dtype, dtype(), handler)
        self._partials: dict[int, _Partial] = {}
        self._time_bases: dict[int, _TimeBase] = {}
        """Per node id (at most 127), its time base, once a timestamped transfer of it has been accepted."""
        self._on_receive_clock: set[Stream] = set()
        """Streams that started before their node's time base was known (at most ``max_streams``)."""
        self.received: Counter[str] = Counter()
        """Valid transfers decoded, by data type name (used or not), as ``MavlinkDecoder.received``."""
        self.used: Counter[str] = Counter()
        """Transfers that became samples, by data type name."""

    @property
    def imu_used(self) -> int:
        """IMU transfers that became samples (of :attr:`imu_types`), as ``MavlinkDecoder.imu_used``."""
        return sum(self.used[name] for name in self.imu_types)

    def feed(self, msg: can.Message) -> list[Sample]:
        """Samples completed by this frame (empty for a frame in the middle of a transfer)."""
        can_id = msg.arbitration_id
        data = msg.data
        if not msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or can_id & _SERVICE_BIT:
            self.stats["not_dronecan_message"] += 1
            return []
        if not data or len(data) != msg.dlc or (len(data) > 8 and not msg.is_fd):
            self._note("bad_dlc", f"id {can_id:#x} dlc {msg.dlc} with {len(data)} bytes")
            return []
        if not can_id & _NODE_ID:  # anonymous: a node asking for a node id; bits 8-23 are no data type id
            self.stats["ignored"] += 1
            return []
        handler = self._handlers.get((can_id >> 8) & 0xFFFF)
        if handler is None:
            self._not_decoded(can_id)
            return []
        payload = self._reassemble(can_id, data, msg.timestamp, handler[0])
        if payload is None:
            return []
        dtype, value, convert = handler
        try:
            value._unpack(bits_from_bytes(payload), not msg.is_fd)
        except Exception as exc:  # noqa: BLE001 - dronecan raises many kinds on malformed payloads
            self._note("bad_payload", f"{dtype.full_name}: {exc!r}")
            return []
        self.received[dtype.full_name] += 1
        try:
            sample = convert(value, can_id & _NODE_ID, msg.timestamp)
        except Rejected as rejected:
            self._note(rejected.reason, f"{dtype.full_name}: {rejected.detail}")
            return []
        self.stats["accepted"] += 1
        self.used[dtype.full_name] += 1
        return [sample]

    def _not_decoded(self, can_id: int) -> None:
        if ((can_id >> 8) & 0xFFFF, CompoundType.KIND_MESSAGE) in dronecan.DATATYPES:
            self.stats["ignored"] += 1
        else:
            self._note("unknown_message", f"data type id {(can_id >> 8) & 0xFFFF}")

    def _reassemble(self, can_id: int, data: bytes | bytearray, t_rx: float, dtype: Any) -> bytes | None:
        """Payload of the transfer this frame completes, CRC-checked; None if it completes none."""
        tail = data[-1]
        body = bytes(data[:-1])
        if tail & _START:
            return self._first_frame(can_id, data, t_rx)
        partial = self._partials.get(can_id)
        if partial is None or partial.tid != tail & _TID:
            return self._spoil(can_id, _Partial(tail & _TID, b"", t_rx), tail, "orphan_frame")
        if partial.spoilt:
            if tail & _END:
                del self._partials[can_id]
            return None
        if tail & _TOGGLE != partial.toggle:
            if data == partial.last:
                partial.repeats += 1
                return None
            return self._spoil(can_id, partial, tail, "bad_toggle")
        if len(partial.data) + len(body) > dtype.get_max_bitlen() // 8 + 2:
            return self._spoil(can_id, partial, tail, "bad_length")
        partial.data += body
        partial.last = bytes(data)
        partial.toggle ^= _TOGGLE
        if not tail & _END:
            return None
        del self._partials[can_id]
        payload = self._checked(can_id, partial.data, dtype)
        if payload is not None and partial.repeats:
            self._note("duplicate_frame", f"id {can_id:#x}: {partial.repeats} frame(s) received twice", partial.repeats)
        return payload

    def _first_frame(self, can_id: int, data: bytes | bytearray, t_rx: float) -> bytes | None:
        """A start frame: a single-frame transfer's payload, or a multi-frame transfer begun (None)."""
        tail = data[-1]
        body = bytes(data[:-1])
        previous = self._partials.pop(can_id, None)
        if previous is not None and not previous.spoilt:
            self._note("incomplete_transfer", f"id {can_id:#x} restarted")
        if tail & _END:
            return body
        partial = _Partial(tail & _TID, body, t_rx)
        partial.last = bytes(data)
        if tail & _TOGGLE:
            return self._spoil(can_id, partial, tail, "bad_toggle")
        self._start(can_id, partial)
        return None

    def _spoil(self, can_id: int, partial: _Partial, tail: int, reason: str) -> None:
        """Refuse a transfer once (``reason``) and drop the rest of its frames uncounted; an unfinished transfer
        it replaces is ``incomplete_transfer``."""
        self._note(reason, f"id {can_id:#x}")
        previous = self._partials.pop(can_id, None)
        if previous is not None and previous is not partial and not previous.spoilt:
            self._note("incomplete_transfer", f"id {can_id:#x} superseded")
        if not tail & _END and len(self._partials) < MAX_PENDING_TRANSFERS:
            partial.spoilt = True
            self._partials[can_id] = partial
        return None

    def _checked(self, can_id: int, data: bytearray, dtype: Any) -> bytes | None:
        """The payload of a reassembled transfer (CRC first), or None if its CRC is missing or wrong."""
        if len(data) < 2:
            self._note("bad_length", f"id {can_id:#x}: {len(data)} bytes, shorter than the CRC")
            return None
        payload = bytes(data[2:])
        if binascii.crc_hqx(payload, dtype.base_crc) != data[0] | data[1] << 8:
            self._note("bad_crc", f"{dtype.full_name} from node {can_id & _NODE_ID}")
            return None
        return payload

    def _start(self, can_id: int, partial: _Partial) -> None:
        """Track a new transfer, dropping (and counting) stale or excess unfinished ones; a spoilt one gives way."""
        partials = self._partials
        for key in [k for k, p in partials.items() if partial.t_first - p.t_first > TRANSFER_TIMEOUT_S]:
            if not partials.pop(key).spoilt:
                self._note("incomplete_transfer", f"id {key:#x} timed out")
        if len(partials) >= MAX_PENDING_TRANSFERS:
            spoilt = next((k for k, p in partials.items() if p.spoilt), None)
            if spoilt is None:
                self._note("too_many_transfers", f"id {can_id:#x}: {len(partials)} unfinished transfers already")
                return
            del partials[spoilt]  # its remaining frames, if any come, count once more as an orphan_frame
        partials[can_id] = partial

    def _stamp_transfer(self, node: int, kind: str, instance: int, usec: int, t_rx: float) -> tuple[int, Stream]:
        """Monotonic time of a transfer stamped ``usec`` on the node's time base (0: none), and its stream.

        A stream keeps the clock it started on: one that started before its node's time base was known (a
        magnetometer heard before its node's first fix) stays on the receive clock."""
        if not 0.0 <= t_rx < MAX_TIME_NS / 1e9:  # NaN fails too
            raise Rejected("time_out_of_range", f"receive time {t_rx!r} s")
        rx_ns = self._receive_ns = round(t_rx * 1e9)
        stream = self._stream(kind, node, 0, instance)
        base = self._time_bases.get(node)
        if stream in self._on_receive_clock or (base is None and not usec):
            self._on_receive_clock.add(stream)
            t_ns = self._stamp(stream, rx_ns, RECEIVE_CLOCK)
        elif not usec:  # no timestamp in the message (or 0, "unknown")
            t_ns = self._stamp(stream, rx_ns + base.offset_ns, BUS_CLOCK)  # type: ignore[union-attr]
        else:
            t_ns = self._stamp(stream, usec * NS_PER_US, BUS_CLOCK)
        if usec:
            self._time_bases.setdefault(node, _TimeBase()).update(usec * NS_PER_US - rx_ns, rx_ns)
        return t_ns, stream

    def _raw_imu(self, m: Any, node: int, t_rx: float) -> ImuSample:
        gyro = check_vector("gyro", tuple(m.rate_gyro_latest), GYRO_MAX_RAD_S)
        accel = check_vector("accel", tuple(m.accelerometer_latest), ACCEL_MAX_M_S2)
        t_ns, stream = self._stamp_transfer(node, RAW_IMU, 0, m.timestamp.usec, t_rx)
        return ImuSample(t_ns, gyro, accel, None, stream.source)  # type: ignore[arg-type]

    def _mag(self, m: Any, node: int, t_rx: float) -> MagSample:
        mag = check_vector("mag", tuple(m.magnetic_field_ga), MAG_MAX_GAUSS)
        t_ns, stream = self._stamp_transfer(node, MAG_FIELD, m.sensor_id, 0, t_rx)
        return MagSample(t_ns, mag, stream.source)  # type: ignore[arg-type]

    def _solution(self, m: Any, node: int, t_rx: float) -> AttitudeSample:
        x, y, z, w = m.orientation_xyzw
        q = check_quaternion((w, x, y, z))
        t_ns, stream = self._stamp_transfer(node, SOLUTION, 0, m.timestamp.usec, t_rx)
        return AttitudeSample(t_ns, q, stream.source)

    def _fix2(self, m: Any, node: int, t_rx: float) -> GnssSample:
        """A receiver's fix: NED velocity (m/s), speed accuracy from the covariance, WGS84 position."""
        fix_type = 1 if m.status < FIX2_STATUS_2D else m.status  # no fix / time only: MAVLink's GPS_FIX_TYPE_NO_FIX
        if m.status == 3 and m.mode == FIX2_MODE_DGPS:
            fix_type = 4
        elif m.status == 3 and m.mode == FIX2_MODE_RTK:
            fix_type = 6 if m.sub_mode == FIX2_SUB_MODE_RTK_FIXED else 5
        vel = accuracy = lat = lon = alt = None
        if m.status >= FIX2_STATUS_2D:
            vel = check_vector("gnss_velocity", tuple(m.ned_velocity), GNSS_VELOCITY_MAX_M_S)
            variances = [m.covariance[i] for i in FIX2_VELOCITY_VARIANCES.get(len(m.covariance), ())]
            if variances and all(v >= 0.0 for v in variances):  # NaN fails: unknown
                accuracy = math.sqrt(sum(variances) / 3.0)
            lat, lon, alt = check_position(m.latitude_deg_1e8 * 1e-8, m.longitude_deg_1e8 * 1e-8, m.height_msl_mm * 1e-3)
        t_ns, stream = self._stamp_transfer(node, FIX2, 0, m.timestamp.usec, t_rx)
        return GnssSample(t_ns, fix_type, vel, m.status == 3, accuracy, lat, lon, alt, False, stream.source)  # type: ignore[arg-type]
