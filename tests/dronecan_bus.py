"""A DroneCAN bus shaped like a real vehicle's, deterministic, from a simulated flight's truth and sensors.

What a 1 Mbit/s bus of an ArduPilot/PX4 vehicle with CAN peripherals carries:

* an IMU node (an autopilot or an AP_Periph IMU board) sending uavcan.equipment.ahrs.RawIMU at the flight's
  IMU rate and ahrs.Solution, stamped (``uavcan.Timestamp``) with its own uptime;
* a GNSS + compass node (Here3/Here4-like) sending ahrs.MagneticFieldStrength2 (no timestamp) at the flight's
  magnetometer rate and gnss.Fix2 stamped with the fix time on *its* uptime, sent ``gnss_latency`` later;
* uavcan.protocol.NodeStatus once a second from every node;
* each node's transfer ids counting per message type modulo 32; multi-frame transfers going out frame by frame
  (about 130 us a frame at 1 Mbit/s), so that transfers of different nodes interleave on the bus;
* receive times on the receiver's own clock (Unix-like), a little after the frames went out.

Nothing here uses the project's encoders or decoders: payloads and frames come from ``dronecan`` itself.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from typing import Any

import can
import dronecan
import numpy as np
from dronecan.transport import Transfer

from drivers.sim import Flight, samples
from drivers.samples import AttitudeSample, GnssSample, ImuSample

FRAME_S = 130e-6
"""Time one extended CAN frame with 8 data bytes takes at 1 Mbit/s (about 130 bits)."""
RX_EPOCH_S = 1_780_000_000.0
"""The receiver's clock when the flight's clock reads zero (a Unix time, as python-can stamps frames)."""
IMU_NODE, GNSS_NODE = 10, 124
IMU_UPTIME_S = 12.5
"""The IMU node's uptime when the flight's clock reads zero."""
GNSS_UPTIME_S = 3.25
"""The GNSS node's uptime then: booted later than the autopilot, so the two time bases differ by 9.25 s."""


def dtype(name: str) -> Any:
    """A dronecan DSDL type by its full name."""
    return dronecan.TYPENAMES[name]


def stamp(t_s: float) -> Any:
    """A ``uavcan.Timestamp`` of ``t_s`` seconds (0 means unknown)."""
    return dtype("uavcan.Timestamp")(usec=round(t_s * 1e6))


def raw_imu(t_s: float, gyro: Any, accel: Any) -> Any:
    """uavcan.equipment.ahrs.RawIMU with only the latest samples (no integrals), stamped ``t_s``."""
    return dtype("uavcan.equipment.ahrs.RawIMU")(timestamp=stamp(t_s), integration_interval=-1.0,
                                                 rate_gyro_latest=list(gyro), accelerometer_latest=list(accel))


def mag_field(mag: Any, sensor_id: int = 0) -> Any:
    """uavcan.equipment.ahrs.MagneticFieldStrength2 (gauss); it carries no timestamp."""
    return dtype("uavcan.equipment.ahrs.MagneticFieldStrength2")(sensor_id=sensor_id, magnetic_field_ga=list(mag))


def solution(t_s: float, q_wxyz: Any) -> Any:
    """uavcan.equipment.ahrs.Solution with the orientation only (x, y, z, w on the wire)."""
    w, x, y, z = q_wxyz
    return dtype("uavcan.equipment.ahrs.Solution")(timestamp=stamp(t_s), orientation_xyzw=[x, y, z, w])


def fix2(t_s: float, vel_ned: Any, lat_deg: float, lon_deg: float, alt_m: float, sigma_m_s: float = 0.1) -> Any:
    """uavcan.equipment.gnss.Fix2, a 3-D fix, with the velocity variances on the covariance's diagonal."""
    v = sigma_m_s * sigma_m_s
    return dtype("uavcan.equipment.gnss.Fix2")(
        timestamp=stamp(t_s), latitude_deg_1e8=round(lat_deg * 1e8), longitude_deg_1e8=round(lon_deg * 1e8),
        height_msl_mm=round(alt_m * 1e3), ned_velocity=list(vel_ned), status=3, sats_used=14,
        covariance=[1.0, 1.0, 4.0, v, v, v])


def node_status(uptime_s: float) -> Any:
    """uavcan.protocol.NodeStatus: healthy, operational."""
    return dtype("uavcan.protocol.NodeStatus")(uptime_sec=int(uptime_s), health=0, mode=0)


def frames(payload: Any, node: int, tid: int, rx_s: float, priority: int = 16) -> list[can.Message]:
    """The CAN frames of one transfer, all stamped ``rx_s`` (the caller spaces them on the bus)."""
    transfer = Transfer(payload=payload, source_node_id=node, transfer_id=tid % 32, transfer_priority=priority)
    return [can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=rx_s)
            for f in transfer.to_frames()]


@dataclass
class Bus:
    """Transfers queued by send time, to be put on the wire frame by frame (:meth:`wire`)."""

    latency_s: float = 200e-6
    """From the end of a frame on the wire to its receive time stamp."""
    _queue: list[tuple[float, int, list[can.Message]]] = field(default_factory=list)
    _tids: dict[tuple[int, str], int] = field(default_factory=dict)

    def send(self, t_s: float, node: int, payload: Any, priority: int = 16) -> None:
        """Queue ``payload`` from ``node`` at flight time ``t_s``, with the node's next transfer id for its type."""
        key = (node, dronecan.get_dronecan_data_type(payload).full_name)
        tid = self._tids.get(key, 0)
        self._tids[key] = tid + 1
        heapq.heappush(self._queue, (t_s, len(self._queue), frames(payload, node, tid, 0.0, priority)))

    def wire(self) -> list[can.Message]:
        """Every frame in bus order with its receive time: a transfer's frames go one after the other, and a
        transfer queued while another is on the wire interleaves with it frame by frame."""
        pending = sorted(self._queue)
        self._queue = []
        active: list[list[can.Message]] = []
        out: list[can.Message] = []
        t = pending[0][0] if pending else 0.0
        i = 0
        while i < len(pending) or active:
            while i < len(pending) and pending[i][0] <= t:
                active.append(list(pending[i][2]))
                i += 1
            if not active:
                t = pending[i][0]
                continue
            for queue in list(active):  # one frame of each transfer in turn: nodes contend frame by frame
                frame = queue.pop(0)
                t += FRAME_S
                frame.timestamp = RX_EPOCH_S + t + self.latency_s
                out.append(frame)
                if not queue:
                    active.remove(queue)
        return out


@dataclass(frozen=True)
class VehicleBus:
    """A flight's frames on the bus, and what the receiver should make of them."""

    frames: list[can.Message]
    imu_sent: int
    mag_sent: int
    fix_sent: int
    solution_sent: int
    status_sent: int


def vehicle_bus(flight: Flight, gnss_latency_s: float = 0.05, gnss_jitter_s: float = 0.0, with_solution: bool = True,
                seed: int = 0, mag_from_s: float = 0.0) -> VehicleBus:
    """The IMU node's RawIMU (and Solution), the GNSS node's magnetometer and fixes, NodeStatus from both.

    A fix goes out ``gnss_latency_s`` after the time it is stamped with, plus up to ``gnss_jitter_s`` more (uniform):
    a receiver's solution takes a varying time to compute and to reach the node's CAN driver. The magnetometer
    starts ``mag_from_s`` into the flight (a compass still starting up while the receiver already sends fixes)."""
    t_first = flight.t_ns[0] * 1e-9
    rng = np.random.default_rng(seed)
    bus = Bus()
    counts = dict(imu=0, mag=0, fix=0, solution=0, status=0)
    next_status = 0.0
    for t_ns, _q, tick in samples(flight):
        t = t_ns * 1e-9
        for s in tick:
            if isinstance(s, ImuSample):
                bus.send(t, IMU_NODE, raw_imu(t + IMU_UPTIME_S, s.gyro_rad_s, s.accel_m_s2), priority=8)
                counts["imu"] += 1
                if s.mag_gauss is not None and t - t_first >= mag_from_s:
                    bus.send(t + 0.0004, GNSS_NODE, mag_field(s.mag_gauss), priority=12)
                    counts["mag"] += 1
            elif isinstance(s, AttitudeSample) and with_solution:
                bus.send(t, IMU_NODE, solution(t + IMU_UPTIME_S, s.q_wxyz), priority=12)
                counts["solution"] += 1
            elif isinstance(s, GnssSample) and s.vel_ned_m_s is not None:
                fix_t = s.t_ns * 1e-9
                bus.send(fix_t + gnss_latency_s + gnss_jitter_s * rng.random(), GNSS_NODE, fix2(fix_t + GNSS_UPTIME_S, s.vel_ned_m_s, s.lat_deg, s.lon_deg, s.alt_m),
                         priority=16)
                counts["fix"] += 1
        while t >= next_status:
            for node, uptime in ((IMU_NODE, IMU_UPTIME_S), (GNSS_NODE, GNSS_UPTIME_S)):
                bus.send(next_status, node, node_status(next_status + uptime), priority=24)
                counts["status"] += 1
            next_status += 1.0
    return VehicleBus(bus.wire(), counts["imu"], counts["mag"], counts["fix"], counts["solution"], counts["status"])


def rx_ns(frame: can.Message) -> int:
    """A frame's receive time in integer nanoseconds (as a source thread would stamp it)."""
    return round(frame.timestamp * 1e9)
