"""What ``run`` and ``replay`` print at the end about an input (``fuser.inputs``): the IMU messages used and the
refusals, and nothing else under "not used".

* ``run --can`` printed "can:...: 0 of 0 IMU messages used" whatever the bus carried: the IMU messages were counted
  only for a MAVLink decoder. The DroneCAN decoder keeps no count by message type, so the line must say the IMU
  messages were not counted rather than give a count of zero.
* Counts the drivers keep that are not refusals (drivers/README.md, "Counted but not refusals") were listed as "not
  used": a bus's service and standard-id frames (``not_dronecan_message``), a sender's confirmed reboot or clock jump,
  a .tlog's ground-station clock step, the frames ``lost`` in the sequence numbers.
"""

from types import SimpleNamespace

import can

from drivers.dronecan_decode import DroneCanDecoder
from drivers.mavlink_decode import MavlinkDecoder
from drivers.samples import ImuSample, SourceId
from drivers.mavlink_encode import MavlinkEncoder
from dronecan_bus import frames, node_status, raw_imu
from fuser.inputs import InputReport, source_report

NON_REFUSALS = {"accepted": 40, "ignored": 7, "not_dronecan_message": 5, "reboot": 1, "clock_jump": 1,
                "record_clock_step": 1, "lost": 3}


def test_not_used_lists_only_refusals():
    report = InputReport("x", 50, 40, NON_REFUSALS | {"bad_crc": 2, "other_sender": 4})
    assert report.refused == {"bad_crc": 2, "other_sender": 4}
    used, not_used = report.lines()
    assert not_used == "x: not used: bad_crc=2, other_sender=4"
    for name in ("not_dronecan_message=5", "reboot=1", "clock_jump=1", "record_clock_step=1", "lost=3"):
        assert name in used  # still shown, with what was used


def test_nothing_refused_says_nothing():
    assert InputReport("x", 50, 50, NON_REFUSALS).lines()[1] == "x: not used: nothing"


def _can_source(decoder: DroneCanDecoder) -> SimpleNamespace:
    return SimpleNamespace(decoder=decoder, stats=decoder.stats)


def test_can_imu_messages_are_not_reported_as_zero_of_zero():
    decoder = DroneCanDecoder()
    for k in range(50):
        for f in frames(raw_imu(1.0 + 0.005 * k, (0.1, 0, 0), (0, 0, -9.8)), 10, k % 32, 1.0 + 0.005 * k):
            assert len(decoder.feed(f)) == (1 if f.data[-1] & 0x40 else 0)  # the transfer's last frame gives the sample
    for k in range(3):  # a node's status (a message the drivers do not use) and a service request on the bus
        for f in frames(node_status(1.0 + k), 10, k, 1.0 + k):
            decoder.feed(f)
        decoder.feed(can.Message(arbitration_id=(10 << 8) | 0x80 | 11, data=b"\x00\xc0", is_extended_id=True, timestamp=2.0))
    assert decoder.stats["accepted"] == 50
    report = source_report("can:virtual:bus", _can_source(decoder))
    used, not_used = report.lines()
    assert "0 of 0" not in used
    assert used.startswith("can:virtual:bus: IMU messages not counted")
    assert "50 samples accepted" in used
    assert not_used == "can:virtual:bus: not used: nothing"  # service requests and NodeStatus are no refusals
    assert report.warning() is None


def test_mavlink_heartbeats_are_not_refusals():
    encoder = MavlinkEncoder(1, 1)  # sends a HEARTBEAT before its first frame and once a second of sample time
    src = SourceId("mavlink", 1, 1, 0)
    data = b"".join(encoder.encode(ImuSample(k * 10_000_000, (0.01, 0, 0), (0, 0, -9.8), None, src), "HIGHRES_IMU")
                    for k in range(300))
    decoder = MavlinkDecoder()
    decoder.feed(data)
    report = source_report("mavlink:udpin:0.0.0.0:14550", SimpleNamespace(decoder=decoder, stats=decoder.stats))
    assert decoder.stats["ignored"] >= 3  # the heartbeats
    assert report.lines()[0].startswith("mavlink:udpin:0.0.0.0:14550: 300 of 300 IMU messages used (100.0%)")
    assert report.refused == {}
