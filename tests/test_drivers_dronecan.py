"""DroneCAN decoding: messages built with dronecan, our encoder, and a python-can virtual bus."""

from __future__ import annotations

import uuid

import can
import numpy as np
import pytest
from dronecan.transport import Transfer

from core import quaternion as cq
from drivers import AttitudeSample, DroneCanDecoder, DroneCanSource, ImuSample, MagSample, SourceId, encode_dronecan
from drivers.dronecan_decode import MAG_FIELD, RAW_IMU, SOLUTION, data_type


def f16(x: float) -> float:
    """x rounded to IEEE half precision, as DroneCAN sends it (numpy is independent of dronecan here)."""
    return float(np.float16(x))


def frames_of(payload, node: int, tid: int = 0, rx_time: float = 0.0) -> list[can.Message]:
    transfer = Transfer(payload=payload, source_node_id=node, transfer_id=tid, transfer_priority=20)
    return [
        can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=rx_time)
        for f in transfer.to_frames()
    ]


def decode(frames, decoder=None) -> list:
    decoder = decoder or DroneCanDecoder()
    out = []
    for f in frames:
        out += decoder.feed(f)
    return out


def stamp(usec: int):
    return data_type("uavcan.Timestamp")(usec=usec)


def test_raw_imu_multi_frame_latest_samples():
    gyro, accel = (0.1, -0.25, 3.3), (0.5, -1.0, -9.81)
    frames = frames_of(data_type(RAW_IMU)(timestamp=stamp(1_500_000), rate_gyro_latest=list(gyro), accelerometer_latest=list(accel)), 21)
    assert len(frames) > 1
    (s,) = decode(frames)
    assert s.t_ns == 1_500_000_000
    assert s.gyro_rad_s == tuple(f16(v) for v in gyro)
    assert s.accel_m_s2 == tuple(f16(v) for v in accel)
    assert s.mag_gauss is None
    assert s.source == SourceId("dronecan", 21, 0, 0)


def test_solution_orientation_xyzw_becomes_wxyz():
    q = cq.from_axis_angle([0.2, 1.0, -0.4], 1.2)  # w, x, y, z
    w, x, y, z = q
    (s,) = decode(frames_of(data_type(SOLUTION)(timestamp=stamp(7_000), orientation_xyzw=[x, y, z, w]), 5))
    expected = cq.normalize([f16(w), f16(x), f16(y), f16(z)])
    assert s.q_wxyz == pytest.approx(tuple(expected), abs=1e-12)
    assert s.t_ns == 7_000_000


def test_magnetic_field_strength2_takes_time_from_its_nodes_time_base():
    decoder = DroneCanDecoder()
    # A RawIMU stamped 5.0 s (sender) received at 1000.0 s: node 60's time base is 995 s behind receive time.
    decode(frames_of(data_type(RAW_IMU)(timestamp=stamp(5_000_000)), 60, rx_time=1000.0), decoder)
    mag = data_type(MAG_FIELD)(sensor_id=3, magnetic_field_ga=[0.21, -0.02, 0.43])
    (s,) = decode(frames_of(mag, 60, rx_time=1000.25), decoder)
    assert isinstance(s, MagSample)
    assert s.t_ns == 5_250_000_000
    assert s.mag_gauss == (f16(0.21), f16(-0.02), f16(0.43))
    assert s.source == SourceId("dronecan", 60, 0, 3)


def test_two_nodes_with_different_clocks_each_time_their_own_magnetometer():
    """Node 21's clock is 995 s behind receive time, node 22's 400 s ahead: interleaved at 50 Hz for 2 s,
    every magnetometer sample of each node is placed on its own node's clock, none refused."""
    decoder = DroneCanDecoder()
    mags: dict[int, list[int]] = {21: [], 22: []}
    for k in range(100):
        rx = 1000.0 + 0.02 * k
        for node, offset_s in ((21, -995.0), (22, 400.0)):  # both IMUs, then both magnetometers
            imu = data_type(RAW_IMU)(timestamp=stamp(round((rx + offset_s) * 1e6)))
            decode(frames_of(imu, node, tid=k % 32, rx_time=rx), decoder)
        for node in (21, 22):
            mag = data_type(MAG_FIELD)(sensor_id=0, magnetic_field_ga=[0.2, 0.0, 0.4])
            (s,) = decode(frames_of(mag, node, tid=k % 32, rx_time=rx + 0.005), decoder)
            mags[node].append(s.t_ns)
    for node, offset_s in ((21, -995.0), (22, 400.0)):
        want = [round((1000.0 + 0.02 * k + 0.005 + offset_s) * 1e9) for k in range(100)]
        assert mags[node] == pytest.approx(want, abs=2_000)  # float seconds of the frame's receive time
    assert decoder.stats["accepted"] == 400 and set(decoder.stats) == {"accepted"}


@pytest.mark.parametrize(
    "sample",
    [
        ImuSample(2_000_000_000, (0.5, -0.1, 2.0), (0.3, 0.2, -9.9), None, SourceId("sim", 1, 1, 0)),
        MagSample(2_000_000_000, (0.2, 0.05, 0.4), SourceId("sim", 1, 1, 2)),
        AttitudeSample(2_000_000_000, tuple(cq.from_axis_angle([1, 1, 0], 2.5)), SourceId("sim", 1, 1, 0)),
    ],
)
def test_encoder_round_trip_within_float16(sample):
    (s,) = decode(encode_dronecan(sample, node_id=11, transfer_id=33))
    assert type(s) is type(sample)
    assert s.t_ns == sample.t_ns
    assert s.source.system == 11 and s.source.instance == sample.source.instance
    for field in ("gyro_rad_s", "accel_m_s2", "mag_gauss", "q_wxyz"):
        if not hasattr(sample, field):
            continue
        want = getattr(sample, field)
        if want is None:  # an IMU sample without a magnetometer decodes without one
            assert getattr(s, field) is None
        else:
            assert getattr(s, field) == pytest.approx(want, rel=2**-10, abs=2**-14)


def test_imu_sample_with_mag_becomes_two_transfers():
    sample = ImuSample(3_000_000_000, (0.0, 0.0, 0.1), (0.0, 0.0, -9.8), (0.2, 0.0, 0.4), SourceId("sim", 1, 1, 0))
    out = decode(encode_dronecan(sample, node_id=12, transfer_id=0))
    assert [type(s) for s in out] == [ImuSample, MagSample]
    assert out[1].t_ns == sample.t_ns


def test_source_receives_multi_frame_transfers_on_a_virtual_bus():
    channel = f"drivers-test-{uuid.uuid4()}"
    sent = [
        ImuSample(1_000_000_000 + i * 2_500_000, (0.01 * i, 0.0, 0.0), (0.0, 0.0, -9.81), None, SourceId("sim", 1, 1, 0))
        for i in range(40)
    ]
    with can.Bus(interface="virtual", channel=channel) as tx, DroneCanSource(interface="virtual", channel=channel) as source:
        for i, s in enumerate(sent):
            for frame in encode_dronecan(s, node_id=25, transfer_id=i):
                tx.send(frame)
        got = []
        while len(got) < len(sent):
            batch = source.poll(1.0)
            assert batch, source.stats
            got += batch
    assert [s.t_ns for s in got] == [s.t_ns for s in sent]
    assert [s.gyro_rad_s[0] for s in got] == [f16(0.01 * i) for i in range(40)]
    assert source.stats["accepted"] == 40


def test_interleaved_transfers_from_two_nodes():
    a = frames_of(data_type(RAW_IMU)(timestamp=stamp(1_000), rate_gyro_latest=[1.0, 0, 0]), 1)
    b = frames_of(data_type(RAW_IMU)(timestamp=stamp(2_000), rate_gyro_latest=[2.0, 0, 0]), 2)
    mixed = [f for pair in zip(a, b) for f in pair]
    out = decode(mixed)
    assert sorted((s.source.system, s.gyro_rad_s[0]) for s in out) == [(1, 1.0), (2, 2.0)]
