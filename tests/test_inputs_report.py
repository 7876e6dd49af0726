"""What ``run`` and ``replay`` print at the end about an input (``fuser.inputs``): the IMU messages used and the
refusals, and nothing else under "not used".

* ``run --can`` printed "can:...: 0 of 0 IMU messages used" whatever the bus carried: the IMU messages were counted
  only for a MAVLink decoder, so a bus whose IMU transfers were refused was never warned about. The DroneCAN
  decoder now counts its transfers by data type too, and the line counts its RawIMU transfers.
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


def _feed_raw_imu(decoder: DroneCanDecoder, count: int, gyro: tuple, first: int) -> None:
    for k in range(first, first + count):
        for f in frames(raw_imu(1.0 + 0.005 * k, gyro, (0, 0, -9.8)), 10, k % 32, 1.0 + 0.005 * k):
            decoder.feed(f)


def test_can_imu_transfers_are_counted_as_mavlink_messages_are():
    decoder = DroneCanDecoder()
    _feed_raw_imu(decoder, 50, (0.1, 0, 0), 0)
    for k in range(3):  # a node's status (a message the drivers do not use) and a service request on the bus
        for f in frames(node_status(1.0 + k), 10, k, 1.0 + k):
            decoder.feed(f)
        decoder.feed(can.Message(arbitration_id=(10 << 8) | 0x80 | 11, data=b"\x00\xc0", is_extended_id=True, timestamp=2.0))
    assert decoder.stats["accepted"] == 50
    report = source_report("can:virtual:bus", _can_source(decoder))
    used, not_used = report.lines()
    assert used.startswith("can:virtual:bus: 50 of 50 IMU messages used (100.0%)"), used
    assert not_used == "can:virtual:bus: not used: nothing"  # service requests and NodeStatus are no refusals
    assert report.warning() is None


def test_a_bus_whose_imu_transfers_are_refused_is_warned_about():
    """50 RawIMU transfers decoded, 20 of them out of the gyro's range: 30 of 50 used, a warning (before: "0 of 0")."""
    decoder = DroneCanDecoder()
    _feed_raw_imu(decoder, 30, (0.1, 0, 0), 0)
    _feed_raw_imu(decoder, 20, (100.0, 0, 0), 30)
    report = source_report("can:virtual:bus", _can_source(decoder))
    assert report.lines()[0].startswith("can:virtual:bus: 30 of 50 IMU messages used (60.0%)"), report.lines()
    assert "gyro_out_of_range=20" in report.lines()[1]
    assert report.warning() is not None and "30 of 50" in report.warning()


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


def test_a_link_with_another_vehicle_names_it_and_says_how_to_fuse_it():
    """Two vehicles streaming into one port: ``run`` said only ``other_sender=828``. The decoder names the other
    autopilot from its HEARTBEAT (tests/test_drivers_link.py), and the report says which and what to do."""
    from pymavlink.dialects.v20 import ardupilotmega as apm

    from drivers.link import LinkSettings

    def heartbeat(system: int) -> bytes:
        return bytes(apm.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(apm.MAVLink(None, srcSystem=system, srcComponent=1)))

    decoder = MavlinkDecoder(LinkSettings())
    decoder.feed(heartbeat(1))
    decoder.feed(heartbeat(7) + heartbeat(2))
    lines = source_report("udp", SimpleNamespace(decoder=decoder, stats=decoder.stats)).lines()
    assert lines[2] == ("udp: other vehicles on this link: system 2 component 1, system 7 component 1; their data is left out "
                        "(other_sender): one vehicle is fused, the first autopilot heard unless --system N (and --component C) "
                        "names another")
    assert len(InputReport("x", 1, 1, {"accepted": 1}).lines()) == 2  # one vehicle: no such line
