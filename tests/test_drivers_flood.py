"""Bounded under floods: what the decoders and sources keep is capped, the overflow counted (no timing here:
the figures are in benchmarks/flood.py)."""

from __future__ import annotations

import logging
import os
import socket

import can
import pytest
from pymavlink.dialects.v20 import common as mav_common

from drivers import DroneCanDecoder, LinkSettings, MavlinkDecoder, MavlinkSource
from drivers.decoder import MAX_SENDERS, MAX_STREAMS
from drivers.dronecan_decode import MAX_PENDING_TRANSFERS, RAW_IMU, data_type

MAX_FRAME = 280
"""The longest MAVLink 2 frame: 10 header + 255 payload + 2 CRC + 13 signature bytes."""


@pytest.fixture(autouse=True)
def _quiet_reason_log(caplog):
    caplog.set_level(logging.ERROR, logger="drivers")


def highres(system: int, component: int, instance: int, time_usec: int = 1_000_000, seq: int = 0) -> bytes:
    mav = mav_common.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.seq = seq
    msg = mav_common.MAVLink_highres_imu_message(time_usec, 0, 0, -9.81, 0, 0, 0, 0.2, 0, 0.4, 0, 0, 0, 0, 0x1FF, instance)
    return bytes(msg.pack(mav))


def unknown_id_frame(msgid: int, seq: int = 0) -> bytes:
    """A MAVLink 2 frame with an id outside every dialect (pymavlink cannot check its CRC)."""
    payload = bytes(20)
    return bytes([0xFD, len(payload), 0, 0, seq & 0xFF, 1, 1]) + msgid.to_bytes(3, "little") + payload + b"\x00\x00"


def test_thousands_of_distinct_sources_leave_the_decoder_capped():
    decoder = MavlinkDecoder(LinkSettings(lock_first_autopilot=False))
    sources = [(1 + k % 250, 1 + (k // 250) % 250, k % 7) for k in range(5_000)]
    data = b"".join(highres(*src) for src in sources)
    decoder.feed(data)
    assert len(decoder._streams) <= MAX_STREAMS and len(decoder._senders) <= MAX_SENDERS
    refused = decoder.stats["too_many_streams"] + decoder.stats["too_many_senders"]
    assert decoder.stats["accepted"] + refused == len(sources)
    assert decoder.stats["accepted"] == MAX_SENDERS  # the first MAX_SENDERS senders, one stream each


def test_one_sender_with_hundreds_of_sensor_instances_is_capped_at_max_streams():
    decoder = MavlinkDecoder()
    decoder.feed(b"".join(highres(1, 1, instance, seq=instance) for instance in range(256)))
    assert decoder.stats["accepted"] == MAX_STREAMS and decoder.stats["too_many_streams"] == 256 - MAX_STREAMS


def test_with_the_vehicle_locked_other_senders_create_no_state():
    decoder = MavlinkDecoder(LinkSettings(system=1, component=1))
    decoder.feed(b"".join(highres(2 + k % 250, 1 + k // 250, 0) for k in range(3_000)) + highres(1, 1, 0))
    assert len(decoder._streams) == 1 and len(decoder._senders) == 1
    assert decoder.stats["other_sender"] == 3_000 and decoder.stats["accepted"] == 1


def test_the_parser_buffer_holds_at_most_one_frame_between_feeds():
    decoder = MavlinkDecoder()
    noise = os.urandom(1 << 20)
    for k in range(0, len(noise), 4096):
        decoder.feed(noise[k : k + 4096])
        assert len(decoder.frames.mav.buf) <= MAX_FRAME


def test_a_datagram_of_40_frames_yields_all_40_samples():
    decoder = MavlinkDecoder()
    datagram = b"".join(highres(1, 1, 0, 1_000_000 + 2500 * i, seq=i) for i in range(40))
    assert len(decoder.feed_datagram(datagram)) == 40
    assert len(decoder.frames.mav.buf) == 0


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_live_flood_of_unknown_ids_grows_nothing_and_the_real_sample_gets_through():
    """pymavlink's connection keeps the last message of every id in ``mavfile.messages`` (39 MB of
    unknown ids added 806 MB); the source frames the bytes itself, so nothing is kept per id."""
    port = free_udp_port()
    with MavlinkSource(f"udpin:127.0.0.1:{port}", LinkSettings(lock_first_autopilot=False)) as source, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        tx.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        cached = len(source.connection.messages)
        sent, got = 0, []
        for batch in range(20):  # 20 x 100 datagrams of unknown ids, drained as they come
            for k in range(100):
                msgid = 60_000 + batch * 100 + k
                tx.sendto(b"".join(unknown_id_frame(msgid + 5_000 * j, seq=j) for j in range(10)), ("127.0.0.1", port))
                sent += 1
            for _ in range(5):
                source.poll(0.0)
        tx.sendto(highres(1, 1, 0, 5_000_000), ("127.0.0.1", port))
        for _ in range(100):
            got += source.poll(0.05)
            if got:
                break
        assert [s.t_ns for s in got] == [5_000_000_000]
        assert len(source.connection.messages) == cached
        assert source.stats["unknown_message"] >= 10_000 * 0.5  # most of them read, the kernel may drop some
        assert set(source.decoder.received) == {"HIGHRES_IMU"}
        assert len(source.decoder.frames.mav.buf) == 0


def test_unfinished_can_transfers_are_capped():
    decoder = DroneCanDecoder()
    raw_imu_id = data_type(RAW_IMU).default_dtid
    for node in range(1, 128):
        for prio in range(4):  # a start frame never followed by the rest: 508 transfers left open
            can_id = (prio << 24) | (raw_imu_id << 8) | node
            decoder.feed(can.Message(arbitration_id=can_id, data=bytes(7) + b"\x80", is_extended_id=True, timestamp=1.0))
    assert len(decoder._partials) == MAX_PENDING_TRANSFERS
    assert decoder.stats["too_many_transfers"] == 127 * 4 - MAX_PENDING_TRANSFERS


def test_a_false_header_claiming_another_sender_swallows_nothing():
    """Other senders' frames are skipped whole only when a frame starts right after them; this false
    header (payload 16 bytes, system 9) ends inside the real frame, so only its magic byte is stepped over."""
    decoder = MavlinkDecoder(LinkSettings(system=1, component=1))
    false_header = b"\xfd\x10\x00\x00\x00\x09\x01\x00\x00\x00"
    out = decoder.feed(false_header + highres(1, 1, 0, 2_000_000))
    assert [s.t_ns for s in out] == [2_000_000_000]
    assert decoder.stats["garbage"] >= 1 and decoder.stats["other_sender"] == 0
