"""Bad input never stops a decoder: each kind is counted by reason, logged once, and the next message decodes."""

from __future__ import annotations

import logging
import math

import can
import pytest
from dronecan.transport import Transfer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mav_common

from drivers import DroneCanDecoder, LinkSettings, MavlinkDecoder, SourceId
from drivers.dronecan_decode import RAW_IMU, data_type
from drivers.timebase import StreamClock
from drivers.validation import Rejected

SEC = 1_000_000_000


def imu_frame(time_usec: int, gyro=(0.0, 0.0, 0.0), accel=(0.0, 0.0, -9.81), mag=(0.2, 0.0, 0.4), seq: int = 0) -> bytes:
    msg = mav_common.MAVLink_highres_imu_message(time_usec, *accel, *gyro, *mag, 0, 0, 0, 0, 0x1FF, 0)
    mav = mav_common.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.seq = seq
    return bytes(msg.pack(mav))


def quat_frame(time_boot_ms: int, q) -> bytes:
    msg = mav_common.MAVLink_attitude_quaternion_message(time_boot_ms, *q, 0, 0, 0, [0.0] * 4)
    return bytes(msg.pack(mav_common.MAVLink(None, srcSystem=1, srcComponent=1)))


def times_of(samples) -> list[int]:
    return [s.t_ns for s in samples]


GOOD = imu_frame(2_000_000)
GOOD_T = 2_000_000_000


@pytest.mark.parametrize(
    "bad, reason",
    [
        (b"\x00\x01\x02hello world\x10", "garbage"),
        (imu_frame(1_000_000)[:30], "bad_crc"),  # truncated: the next frame's bytes are taken as its rest
        (imu_frame(1_000_000)[:20] + b"\x55" + imu_frame(1_000_000)[21:], "bad_crc"),
        (b"\xfd\x30\x00\x00\x00\x01\x01\x05\x00\x00" + b"\x00" * 3, "bad_crc"),  # false header in garbage
        (b"\xfd\x09\x04\x00\x00\x01\x01\x1e\x00\x00" + b"\x00" * 11, "bad_frame"),  # unknown incompat flag
        (b"\xfd\x03\x00\x00\x07\x01\x01\xee\xff\x00\x01\x02\x03\x12\x34", "unknown_message"),  # id 65518: in no dialect
        (imu_frame(1_000_000, gyro=(math.nan, 0.0, 0.0)), "non_finite"),
        (imu_frame(1_000_000, accel=(0.0, math.inf, 0.0)), "non_finite"),
        (imu_frame(1_000_000, gyro=(0.0, 0.0, 40.0)), "gyro_out_of_range"),
        (imu_frame(1_000_000, accel=(-170.0, 0.0, 0.0)), "accel_out_of_range"),
        (imu_frame(1_000_000, mag=(0.0, 11.0, 0.0)), "mag_out_of_range"),
    ],
)
def test_mavlink_bad_input_is_counted_and_the_next_frame_decodes(bad, reason):
    decoder = MavlinkDecoder()
    assert times_of(decoder.feed(bad + GOOD)) == [GOOD_T]
    assert decoder.stats[reason] >= 1
    assert decoder.stats["accepted"] == 1


@pytest.mark.parametrize("dialect, reason", [("ardupilotmega", "ignored"), ("common", "unknown_message")])
def test_ardupilot_messages_are_ignored_in_their_dialect_and_unknown_in_common(dialect, reason):
    ahrs = bytes(apm.MAVLink_ahrs_message(0, 0, 0, 0, 0, 0, 0).pack(apm.MAVLink(None, srcSystem=1, srcComponent=1)))
    decoder = MavlinkDecoder(LinkSettings(lock_first_autopilot=False, dialect=dialect))
    assert times_of(decoder.feed(ahrs + GOOD)) == [GOOD_T]
    assert decoder.stats[reason] == 1


def test_quaternion_far_from_unit_norm_is_refused():
    decoder = MavlinkDecoder()
    out = decoder.feed(quat_frame(10, (2.0, 0.0, 0.0, 0.0)) + quat_frame(20, (1.0, 0.0, 0.0, 0.0)))
    assert times_of(out) == [20_000_000]
    assert decoder.stats["quaternion_norm"] == 1


@pytest.mark.parametrize("link", [None, LinkSettings(system=1, component=1)])
def test_valid_packet_right_after_a_false_header_is_not_lost(link):
    # 0xFD followed by a length of 0x40 would swallow the next 76 bytes in pymavlink alone.
    decoder = MavlinkDecoder(link)
    stream = b"\xfd\x40" + imu_frame(1_000_000) + imu_frame(1_002_500, seq=1)
    assert times_of(decoder.feed(stream)) == [1_000_000_000, 1_002_500_000]


@pytest.mark.parametrize(
    "times_us, expected_ns, reason",
    [
        ([1_000_000, 1_010_000, 500_000, 1_020_000], [1_000_000_000, 1_010_000_000, 1_020_000_000], "time_backwards"),
        ([1_000_000, 1_010_000, 1_010_000, 1_020_000], [1_000_000_000, 1_010_000_000, 1_020_000_000], "duplicate"),
        (
            [1_000_000, 1_010_000, 1_010_000 + 3 * 3600 * 1_000_000, 1_020_000],
            [1_000_000_000, 1_010_000_000, 1_020_000_000],
            "time_jump",
        ),
    ],
)
def test_timestamp_glitches_are_refused(times_us, expected_ns, reason):
    decoder = MavlinkDecoder()
    out = decoder.feed(b"".join(imu_frame(t, seq=i) for i, t in enumerate(times_us)))
    assert times_of(out) == expected_ns
    assert decoder.stats[reason] == 1


def test_reboot_is_counted_and_time_stays_monotonic():
    decoder = MavlinkDecoder()
    times_us = [100_000_000, 100_010_000, 50_000, 60_000, 70_000]  # sender restarted its clock
    out = times_of(decoder.feed(b"".join(imu_frame(t, seq=i) for i, t in enumerate(times_us))))
    assert decoder.stats["reboot"] == 1
    # the first post-reboot sample confirms nothing yet; the ones after continue 10 ms apart
    assert out == [100_000_000_000, 100_010_000_000, 100_020_000_000, 100_030_000_000]


def test_forward_clock_jump_confirmed_by_the_next_sample_is_kept():
    events: list[str] = []
    clock = StreamClock(on_event=events.append)
    hour = 3600 * SEC
    assert clock.stamp(SEC) == SEC
    with pytest.raises(Rejected, match="time_jump"):
        clock.stamp(2 * hour)
    assert clock.stamp(2 * hour + SEC) == 2 * hour + SEC
    assert events == ["clock_jump"]


def test_each_reason_is_logged_once_per_interval(caplog):
    decoder = MavlinkDecoder()
    bad = imu_frame(1_000_000, gyro=(math.nan, 0.0, 0.0))
    with caplog.at_level(logging.WARNING, logger="drivers.mavlink_decode"):
        for _ in range(20):
            decoder.feed(bad)
    assert decoder.stats["non_finite"] == 20
    assert sum("non_finite" in r.getMessage() for r in caplog.records) == 1


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    garbage=st.lists(st.binary(max_size=120), min_size=4, max_size=4),
    cuts=st.lists(st.integers(0, 600), max_size=6),
    locked=st.booleans(),
)
def test_mavlink_fuzz_garbage_between_valid_frames(garbage, cuts, locked):
    """Any split, any garbage; with the vehicle chosen (other senders' frames screened) as without."""
    valid = [imu_frame(1_000_000 + 2500 * i, seq=i) for i in range(3)]
    stream = garbage[0] + valid[0] + garbage[1] + valid[1] + garbage[2] + valid[2] + garbage[3] + b"\x00" * 300
    decoder = MavlinkDecoder(LinkSettings(system=1, component=1) if locked else None)
    out = []
    start = 0
    for cut in sorted(cuts) + [len(stream)]:  # any split of the stream into reads
        out += decoder.feed(stream[start:cut])
        start = max(start, cut)
    assert times_of(out) == [(1_000_000 + 2500 * i) * 1000 for i in range(3)]


# ---------------------------------------------------------------- DroneCAN

NODE = 42


def raw_imu_frames(usec: int, tid: int, gyro=(0.1, 0.2, 0.3), accel=(0.0, 0.0, -9.81), node: int = NODE) -> list[can.Message]:
    """Frames of a RawIMU transfer built with dronecan directly (not with the driver's encoder)."""
    payload = data_type(RAW_IMU)(
        timestamp=data_type("uavcan.Timestamp")(usec=usec), rate_gyro_latest=list(gyro), accelerometer_latest=list(accel)
    )
    frames = Transfer(payload=payload, source_node_id=node, transfer_id=tid, transfer_priority=20).to_frames()
    return [can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=1.0) for f in frames]


def feed_all(decoder, frames) -> list:
    out = []
    for f in frames:
        out += decoder.feed(f)
    return out


def corrupt(frames, index: int, byte: int = 0) -> list[can.Message]:
    f = frames[index]
    data = bytearray(f.data)
    data[byte] ^= 0x5A
    return frames[:index] + [can.Message(arbitration_id=f.arbitration_id, data=data, is_extended_id=True)] + frames[index + 1 :]


NEXT = raw_imu_frames(2_000_000, 2)


@pytest.mark.parametrize(
    "bad, reason",
    [
        (corrupt(raw_imu_frames(1_000_000, 1), 3), "bad_crc"),
        (raw_imu_frames(1_000_000, 1)[:3] + raw_imu_frames(1_000_000, 1)[4:], "bad_toggle"),  # frame lost
        (raw_imu_frames(1_000_000, 1)[:5], "incomplete_transfer"),  # never finished, next one starts
        (raw_imu_frames(1_000_000, 1)[2:], "orphan_frame"),
        ([can.Message(arbitration_id=NEXT[0].arbitration_id, data=b"\x01\x02\x03", dlc=8, is_extended_id=True)], "bad_dlc"),
        ([can.Message(arbitration_id=(20 << 24) | (4321 << 8) | NODE, data=b"\x01\xc0", is_extended_id=True)], "unknown_message"),
        (raw_imu_frames(1_000_000, 1, gyro=(math.nan, 0.0, 0.0)), "non_finite"),
        (raw_imu_frames(1_000_000, 1, gyro=(0.0, 50.0, 0.0)), "gyro_out_of_range"),
        (raw_imu_frames(1_000_000, 1, accel=(0.0, 0.0, 1000.0)), "accel_out_of_range"),
        (raw_imu_frames(2_000_000, 1), "duplicate"),
        (raw_imu_frames(1_000_000, 1)[:6] + [corrupt(raw_imu_frames(1_000_000, 1), 6, 0)[6]], "bad_crc"),
    ],
)
def test_dronecan_bad_input_is_counted_and_the_next_transfer_decodes(bad, reason):
    decoder = DroneCanDecoder()
    out = feed_all(decoder, bad + NEXT)
    assert times_of(out)[-1:] == [2_000_000_000]
    assert decoder.stats[reason] >= 1


def test_dronecan_truncated_single_frame_payload():
    mag = data_type("uavcan.equipment.ahrs.MagneticFieldStrength2")(sensor_id=0, magnetic_field_ga=[0.2, 0.0, 0.4])
    (f,) = Transfer(payload=mag, source_node_id=NODE, transfer_id=0, transfer_priority=20).to_frames()
    short = can.Message(arbitration_id=f.message_id, data=bytes(f.bytes[:2]) + bytes(f.bytes[-1:]), is_extended_id=True)
    decoder = DroneCanDecoder()
    assert feed_all(decoder, [short] + NEXT)[-1].t_ns == 2_000_000_000
    assert decoder.stats["bad_payload"] == 1


def test_dronecan_non_dronecan_frames_are_skipped():
    decoder = DroneCanDecoder()
    std = can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False)
    assert feed_all(decoder, [std] + NEXT)[-1].source == SourceId("dronecan", NODE, 0, 0)
    assert decoder.stats["not_dronecan_message"] == 1


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.integers(0, 2**29 - 1), st.binary(min_size=0, max_size=8), st.booleans()),
        max_size=30,
    )
)
def test_dronecan_fuzz_random_frames_between_transfers(junk):
    valid_ids = {f.arbitration_id for f in NEXT}
    frames = [
        can.Message(arbitration_id=i, data=d, is_extended_id=ext, timestamp=1.0)
        for i, d, ext in junk
        if i not in valid_ids
    ]
    half = len(frames) // 2
    decoder = DroneCanDecoder()
    out = feed_all(decoder, frames[:half] + raw_imu_frames(1_000_000, 1) + frames[half:] + NEXT)
    assert times_of(out) == [1_000_000_000, 2_000_000_000]


# ---------------------------------------------------------------- times at the boundary

def imu_from(system: int, time_usec: int, seq: int = 0, instance: int = 0) -> bytes:
    msg = mav_common.MAVLink_highres_imu_message(time_usec, 0, 0, -9.81, 0, 0, 0, 0.2, 0, 0.4, 0, 0, 0, 0, 0x1FF, instance)
    mav = mav_common.MAVLink(None, srcSystem=system, srcComponent=1)
    mav.seq = seq
    return bytes(msg.pack(mav))


def test_a_first_sample_at_2_to_the_63_us_is_refused_and_the_recorder_stores_the_rest(tmp_path):
    """Issue 12: a HIGHRES_IMU from a new system id with time_usec = 2^63 overflowed the MCAP writer's uint64."""
    from fuser.record import McapRecorder, read_log

    decoder = MavlinkDecoder()
    out = decoder.feed(imu_from(1, 1_000_000) + imu_from(9, 2**63) + imu_from(1, 1_002_500, seq=1))
    assert times_of(out) == [1_000_000_000, 1_002_500_000]
    assert decoder.stats["time_out_of_range"] == 1
    with McapRecorder(tmp_path / "r.mcap") as rec:
        for s in out:
            rec.write_sample(s, s.t_ns + 1_000_000)
    assert [s.t_ns for s, _ in read_log(tmp_path / "r.mcap").inputs()] == times_of(out)


def test_a_new_streams_first_time_far_from_its_senders_clock_waits_for_confirmation():
    decoder = MavlinkDecoder()
    att = mav_common.MAVLink_attitude_message
    mav = mav_common.MAVLink(None, srcSystem=1, srcComponent=1)
    hour_ms = 3_600_000
    stream = imu_frame(100_000_000) + bytes(att(100_000 + hour_ms, 0, 0, 0, 0, 0, 0).pack(mav))  # boot clocks 1 h apart
    assert times_of(decoder.feed(stream)) == [100_000_000_000]
    assert decoder.stats["time_implausible"] == 1
    # a second ATTITUDE on the same time line confirms it (a sender whose clocks truly differ)
    (s,) = decoder.feed(bytes(att(100_010 + hour_ms, 0, 0, 0, 0, 0, 0).pack(mav)))
    assert s.t_ns == (100_010 + hour_ms) * 1_000_000


def test_unix_and_boot_clocks_of_one_sender_are_not_compared():
    """GPS_RAW_INT's time_usec is Unix time on ArduPilot (>= 10^15 us), the IMU's time since boot."""
    gps = mav_common.MAVLink_gps_raw_int_message(1_700_000_000_000_000, 3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    decoder = MavlinkDecoder()
    out = decoder.feed(imu_frame(100_000_000) + bytes(gps.pack(mav_common.MAVLink(None, srcSystem=1, srcComponent=1))))
    assert times_of(out) == [100_000_000_000, 1_700_000_000_000_000_000]


def test_a_can_frame_with_a_nonsense_receive_time_is_refused():
    mag = data_type("uavcan.equipment.ahrs.MagneticFieldStrength2")(sensor_id=0, magnetic_field_ga=[0.2, 0.0, 0.4])
    (f,) = Transfer(payload=mag, source_node_id=NODE, transfer_id=0, transfer_priority=20).to_frames()
    decoder = DroneCanDecoder()
    for t in (math.nan, -1.0, 2.0**62):
        decoder.feed(can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=t))
    assert decoder.stats["time_out_of_range"] == 3


# ---------------------------------------------------------------- sequence numbers

@pytest.mark.parametrize(
    "seqs, lost",
    [
        ([0, 1, 2, 5, 6], 2),
        ([253, 254, 255, 0, 1], 0),  # wrap-around
        ([254, 1, 2], 2),  # a gap across the wrap
        ([10, 11, 11, 12], 0),  # a repeated frame
        ([10, 12, 11, 13], 1),  # reordered: 11 was counted missing when 12 came; late, it changes nothing
        ([0, 1, 130, 131], 0),  # a step of more than 128 is a step back (a restart or a jump), not a loss
        ([100, 101, 40, 41, 43], 1),  # after a step back by more than 16 the sequence continues from there
    ],
)
def test_sequence_gaps_are_counted_as_lost(seqs, lost):
    decoder = MavlinkDecoder()
    decoder.feed(b"".join(imu_frame(1_000_000 + 2500 * i, seq=s) for i, s in enumerate(seqs)))
    assert decoder.stats["lost"] == lost


def test_a_reboot_restarts_the_sequence_without_counting_a_loss():
    decoder = MavlinkDecoder()
    before = [imu_frame(100_000_000 + 2500 * i, seq=190 + i) for i in range(10)]  # up to seq 199
    after = [imu_frame(3_000_000 + 2500 * i, seq=i) for i in range(10)]  # booted again: time and seq from the start
    decoder.feed(b"".join(before + after))
    assert decoder.stats["lost"] == 0 and decoder.stats["reboot"] == 1


def test_a_loss_just_before_a_reboot_is_dropped_but_one_after_it_counts():
    decoder = MavlinkDecoder()
    frames = [imu_frame(100_000_000, seq=50), imu_frame(100_002_500, seq=51)]
    frames += [imu_frame(3_000_000 + 2500 * i, seq=s) for i, s in enumerate([0, 1, 2, 3, 7, 8])]  # 4, 5, 6 lost after the reboot
    decoder.feed(b"".join(frames))
    assert decoder.stats["lost"] == 3


def test_after_a_reboot_the_stream_continues_by_the_receive_time_that_passed():
    """An autopilot at 100 s of uptime reboots; 8 s of receive time later it sends again from 3 s.
    The stream goes on 8 s (plus its own step) after its last time, where a receiver expects it."""
    decoder = MavlinkDecoder()
    rx0 = 5_000 * SEC
    before = [(100_000_000 + 10_000 * i, rx0 + 10_000_000 * i) for i in range(3)]  # (time_usec, receive_ns)
    after = [(3_000_000 + 10_000 * i, rx0 + 20_000_000 + 8 * SEC + 10_000_000 * i) for i in range(3)]
    out = [s.t_ns for t, rx in before + after for s in decoder.feed(imu_frame(t), rx)]
    last = 100_020_000_000
    assert out == [100_000_000_000, 100_010_000_000, last, last + 8 * SEC + 10_000_000, last + 8 * SEC + 20_000_000]
    assert decoder.stats["reboot"] == 1
