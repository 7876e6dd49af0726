"""MAVLink decoding: every message type built by pymavlink itself, our encoder, a .tlog, live UDP."""

from __future__ import annotations

import math
import socket
import struct
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mav_common

from core import quaternion as cq
from drivers import (
    AttitudeSample,
    ImuSample,
    LinkSettings,
    MavlinkDecoder,
    MavlinkEncoder,
    MavlinkSource,
    SourceId,
    TlogSource,
    encode_mavlink,
)
from drivers.euler import euler_from_quaternion, quaternion_from_euler

G = 9.80665


def frame(msg, system: int = 1, component: int = 1, seq: int = 0) -> bytes:
    """Pack a pymavlink message exactly as an autopilot would send it."""
    mav = mav_common.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.seq = seq
    return bytes(msg.pack(mav))


def decode_one(data: bytes, **kwargs) -> object:
    decoder = MavlinkDecoder(**kwargs)
    samples = decoder.feed(data)
    assert len(samples) == 1, decoder.stats
    return samples[0]


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def test_highres_imu_si_units_and_mag_flag():
    msg = mav_common.MAVLink_highres_imu_message(
        123_456_789, 0.5, -0.25, -9.81, 0.01, -0.02, 3.0, 0.21, -0.05, 0.43, 1013.0, 0.0, 0.0, 25.0, 0x1FF, 2
    )
    s = decode_one(frame(msg, system=3, component=7))
    assert s.t_ns == 123_456_789_000
    assert s.gyro_rad_s == (f32(0.01), f32(-0.02), 3.0)
    assert s.accel_m_s2 == (0.5, -0.25, f32(-9.81))
    assert s.mag_gauss == (f32(0.21), f32(-0.05), f32(0.43))
    assert s.source == SourceId("mavlink", 3, 7, 2)
    no_mag = mav_common.MAVLink_highres_imu_message(1, 0, 0, -9.8, 0, 0, 0, 0.2, 0, 0.4, 0, 0, 0, 0, 0x3F, 0)
    assert decode_one(frame(no_mag)).mag_gauss is None


@pytest.mark.parametrize("name, instance", [("SCALED_IMU", 0), ("SCALED_IMU2", 1), ("SCALED_IMU3", 2)])
def test_scaled_imu_milli_units(name, instance):
    cls = getattr(mav_common, f"MAVLink_{name.lower()}_message")
    s = decode_one(frame(cls(4_000_000, 1000, -500, -1000, 100, -2000, 34000 // 2, 210, 0, 430, 2500)))
    assert s.t_ns == 4_000_000 * 1_000_000
    assert s.accel_m_s2 == pytest.approx((G, -G / 2, -G), abs=1e-12)
    assert s.gyro_rad_s == pytest.approx((0.1, -2.0, 17.0), abs=1e-12)
    assert s.mag_gauss == pytest.approx((0.21, 0.0, 0.43), abs=1e-12)
    assert s.source.instance == instance


def test_raw_imu_uses_ardupilot_milli_units_and_id_instance():
    msg = mav_common.MAVLink_raw_imu_message(77_000_001, 0, 0, -1000, 5, 6, -7, 0, 0, 0, 1, 3000)
    s = decode_one(frame(msg))
    assert s.t_ns == 77_000_001_000
    assert s.accel_m_s2 == pytest.approx((0.0, 0.0, -G))
    assert s.gyro_rad_s == pytest.approx((0.005, 0.006, -0.007))
    assert s.mag_gauss is None  # all-zero magnetometer: none fitted
    assert s.source.instance == 1


def test_attitude_quaternion_is_passed_through_normalised():
    q = np.array([0.9, 0.1, -0.3, 0.2])
    q = q / np.linalg.norm(q)
    s = decode_one(frame(mav_common.MAVLink_attitude_quaternion_message(5000, *q, 0, 0, 0, [0.0] * 4)))
    assert s.t_ns == 5_000_000_000
    assert s.q_wxyz == pytest.approx(tuple(q), abs=1e-7)


def test_attitude_euler_321_matches_rotation_composition():
    roll, pitch, yaw = 0.3, -0.7, 2.5
    s = decode_one(frame(mav_common.MAVLink_attitude_message(42, roll, pitch, yaw, 0, 0, 0)))
    # Independent: yaw about z, then pitch about y, then roll about x (intrinsic), with core.quaternion.
    expected = cq.multiply(
        cq.multiply(cq.from_axis_angle([0, 0, 1], yaw), cq.from_axis_angle([0, 1, 0], pitch)),
        cq.from_axis_angle([1, 0, 0], roll),
    )
    assert np.allclose(s.q_wxyz, expected, atol=1e-6) or np.allclose(s.q_wxyz, -expected, atol=1e-6)
    # A body-x vector pitched up by 0.7 rad points up (negative down in NED).
    nose = cq.rotate(np.array(s.q_wxyz), [1.0, 0.0, 0.0])
    assert nose[2] == pytest.approx(math.sin(0.7), abs=1e-6)


@pytest.mark.parametrize("angles", [(0.1, 0.2, 0.3), (-3.0, 1.5, -2.0), (1.0, -1.2, 3.1)])
def test_euler_round_trip(angles):
    assert euler_from_quaternion(quaternion_from_euler(*angles)) == pytest.approx(angles, abs=1e-9)


IMU = ImuSample(
    1_234_567_000_000, (0.123, -0.456, 1.5), (0.3, -0.2, -9.7), (0.2, 0.01, 0.45), SourceId("mavlink", 1, 1, 0)
)


@pytest.mark.parametrize("message", ["HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "RAW_IMU"])
def test_encoder_round_trip_within_wire_resolution(message):
    s = decode_one(encode_mavlink(IMU, message))
    milli = message != "HIGHRES_IMU"
    assert s.t_ns == (IMU.t_ns if not message.startswith("SCALED") else IMU.t_ns // 1_000_000 * 1_000_000)
    assert s.gyro_rad_s == pytest.approx(IMU.gyro_rad_s, abs=5e-4 if milli else 1e-6)
    assert s.accel_m_s2 == pytest.approx(IMU.accel_m_s2, abs=G * 5e-4 if milli else 1e-6)
    assert s.mag_gauss == pytest.approx(IMU.mag_gauss, abs=5e-4 if milli else 1e-6)


@pytest.mark.parametrize("message", ["ATTITUDE_QUATERNION", "ATTITUDE"])
def test_encoder_attitude_round_trip(message):
    q = tuple(cq.from_axis_angle([1.0, -2.0, 0.5], 2.0))
    s = decode_one(encode_mavlink(AttitudeSample(9_000_000_000, q, IMU.source), message))
    assert s.t_ns == 9_000_000_000
    assert cq.angular_distance(np.array(s.q_wxyz), np.array(q)) < 1e-6


def test_time_boot_ms_wraps_around_without_a_reboot():
    decoder = MavlinkDecoder()
    times = [2**32 - 20, 2**32 - 10, 0, 10]
    data = b"".join(frame(mav_common.MAVLink_attitude_message(t, 0, 0, 0, 0, 0, 0), seq=i) for i, t in enumerate(times))
    out = [s.t_ns for s in decoder.feed(data)]
    assert out == [(2**32 - 20) * 10**6, (2**32 - 10) * 10**6, 2**32 * 10**6, (2**32 + 10) * 10**6]
    assert decoder.stats["reboot"] == 0


def test_filters_by_system_and_component():
    msg = mav_common.MAVLink_attitude_message(1, 0, 0, 0, 0, 0, 0)
    decoder = MavlinkDecoder(LinkSettings(system=2, component=1))
    out = decoder.feed(frame(msg, system=1) + frame(msg, system=2, component=5) + frame(msg, system=2, component=1))
    assert [s.source.system for s in out] == [2]
    assert decoder.stats["other_sender"] == 2


def test_mavlink1_frames_are_decoded_too():
    from pymavlink.dialects.v10 import common as v1

    mav = v1.MAVLink(None, srcSystem=1, srcComponent=1)
    data = bytes(v1.MAVLink_scaled_imu_message(10, 0, 0, -1000, 0, 0, 0, 0, 0, 0).pack(mav))
    assert data[0] == 0xFE
    assert decode_one(data).accel_m_s2 == pytest.approx((0, 0, -G))


def test_tlog_file(tmp_path):
    path = tmp_path / "flight.tlog"
    encoder = MavlinkEncoder()
    truth = [ImuSample(IMU.t_ns + i * 2_500_000, (0.01 * i, 0.0, 0.0), IMU.accel_m_s2, None, IMU.source) for i in range(300)]
    with open(path, "wb") as f:
        for i, s in enumerate(truth):  # tlog record: 8-byte big-endian unix time in us, then the packet
            f.write(struct.pack(">Q", 1_700_000_000_000_000 + i * 2500) + encoder.encode(s))
    with TlogSource(path) as source:
        got = []
        while not source.exhausted:
            got += source.poll(0.1)
    assert [s.t_ns for s in got] == [s.t_ns for s in truth]
    assert [s.gyro_rad_s[0] for s in got] == pytest.approx([s.gyro_rad_s[0] for s in truth], rel=1e-7)


SENDER = textwrap.dedent(
    """
    import os, sys, time
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil
    conn = mavutil.mavlink_connection("udpout:127.0.0.1:" + sys.argv[1], source_system=9, source_component=1, dialect="common")
    gcs = mavutil.mavlink_connection("udpout:127.0.0.1:" + sys.argv[1], source_system=255, source_component=190, dialect="common")
    gcs.mav.heartbeat_send(6, 8, 0, 0, 0)  # a ground station (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID) is heard first
    gcs.mav.highres_imu_send(5, 0.0, 0.0, -9.81, 9.0, 0.0, 0.0, 0.2, 0.0, 0.4, 0, 0, 0, 0, 0x1FF, 0)
    conn.mav.heartbeat_send(2, 3, 0, 0, 4)  # the vehicle: MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA
    for i in range(50):
        conn.mav.highres_imu_send(1_000_000 + 2500 * i, 0.0, 0.0, -9.81, 0.001 * i, 0.0, 0.0, 0.2, 0.0, 0.4, 0, 0, 0, 0, 0x1FF, 0)
        time.sleep(0.001)
    """
)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_udp_from_another_process():
    port = free_udp_port()
    with MavlinkSource(f"udpin:127.0.0.1:{port}") as source:  # receiver first: udpout drops without one
        sender = subprocess.Popen([sys.executable, "-c", SENDER, str(port)])
        got = []
        deadline = time.monotonic() + 20
        while len(got) < 50 and time.monotonic() < deadline:
            got += source.poll(0.2)
        sender.wait(10)
    assert sender.returncode == 0
    assert [s.t_ns for s in got] == [(1_000_000 + 2500 * i) * 1000 for i in range(50)]
    assert [s.gyro_rad_s[0] for s in got] == pytest.approx([0.001 * i for i in range(50)], abs=1e-7)
    assert all(s.source == SourceId("mavlink", 9, 1, 0) for s in got)
    assert source.stats["no_vehicle_yet"] == 2  # the ground station's HEARTBEAT and IMU, before any autopilot
