"""DroneCAN as a real vehicle's bus carries it: several nodes, their own clocks, anonymous frames, faults.

Every frame is built with ``dronecan`` itself (``tests/dronecan_bus.py``), never with the project's encoder.
"""

from __future__ import annotations

import can
import dronecan
import pytest
from dronecan.transport import Transfer

from drivers import DroneCanDecoder
from drivers.samples import Sample
from dronecan_bus import IMU_NODE, frames, raw_imu

RAW_IMU_DTID = dronecan.TYPENAMES["uavcan.equipment.ahrs.RawIMU"].default_dtid


def feed(decoder: DroneCanDecoder, frames_: list[can.Message]) -> list[Sample]:
    """Every sample the decoder makes of ``frames_``, in order."""
    return [s for f in frames_ for s in decoder.feed(f)]


def next_imu(usec: int = 2_000_000, tid: int = 2) -> list[can.Message]:
    """A valid RawIMU transfer from the IMU node, stamped ``usec``."""
    return frames(raw_imu(usec * 1e-6, (0.1, 0.0, 0.0), (0.0, 0.0, -9.81)), IMU_NODE, tid, 1.0)


def raw_frame(data: bytes, node: int = IMU_NODE) -> can.Message:
    """One hand-made frame on RawIMU's data type id from ``node``."""
    return can.Message(arbitration_id=(16 << 24) | (RAW_IMU_DTID << 8) | node, data=data, is_extended_id=True, timestamp=1.0)


@pytest.mark.parametrize(
    "bad",
    [
        [raw_frame(b"\x80"), raw_frame(b"\x00\x60")],  # a start frame with no data, an end frame with one byte
        [raw_frame(b"\x80"), raw_frame(b"\x60")],  # a start and an end frame, both with nothing but the tail byte
        [raw_frame(b"\x01\x80"), raw_frame(b"\x60")],  # one byte in all: half a CRC
    ],
)
def test_a_multi_frame_transfer_too_short_for_its_crc_is_refused_not_raised(bad: list[can.Message]) -> None:
    """A two-frame transfer carrying fewer than the two CRC bytes raised IndexError out of ``feed``."""
    decoder = DroneCanDecoder()
    out = feed(decoder, bad + next_imu())
    assert [s.t_ns for s in out] == [2_000_000_000]
    assert decoder.stats["bad_length"] == 1
    assert set(decoder.stats) == {"bad_length", "accepted"}


def test_dynamic_node_id_allocation_requests_are_ignored_not_unknown() -> None:
    """A node booting without a node id asks for one with anonymous (node id 0) Allocation frames, whose 29-bit id
    holds a discriminator and two bits of the data type id where other frames hold the whole type id: they were
    taken for unknown data types (a warning on every boot) or for another type."""
    alloc = dronecan.TYPENAMES["uavcan.protocol.dynamic_node_id.Allocation"](unique_id=list(range(6)), first_part_of_unique_id=1)
    anonymous = [
        can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=1.0)
        for disc in (0x1234, 0x00FA, 0x3FFF, 250)
        for f in Transfer(payload=alloc, source_node_id=0, transfer_id=0, transfer_priority=30, discriminator=disc).to_frames()
    ]
    decoder = DroneCanDecoder()
    out = feed(decoder, anonymous + next_imu())
    assert [s.t_ns for s in out] == [2_000_000_000]
    assert decoder.stats == {"ignored": 4, "accepted": 1}


def test_a_frame_from_node_id_0_is_never_a_sample() -> None:
    """Anonymous transfers are single frames used for node id allocation; a RawIMU's frames with node id 0 are
    not a node's data: no sample comes from them."""
    decoder = DroneCanDecoder()
    forged = [can.Message(arbitration_id=f.arbitration_id & ~0x7F, data=f.data, is_extended_id=True, timestamp=1.0) for f in next_imu(1_000_000, 1)]
    out = feed(decoder, forged + next_imu())
    assert [s.source.system for s in out] == [IMU_NODE]
    assert decoder.stats["accepted"] == 1
