"""A live source that delivers no sample says what it did receive, while the run goes on and at its end.

Found trying it: ``run --mavlink udpin:127.0.0.1:14551`` with nothing sending there, or with a vehicle that sends
heartbeats but does not stream its IMU on that link (ArduPilot's SRn_RAW_SENS at 0, the usual case on a second
telemetry port), ran silently and ended "0 estimates" with exit 0. The expected lines are written here from what
was sent, not taken from the code."""

from __future__ import annotations

import re
import socket
import threading
import time

import pytest
from pymavlink import mavutil

import fuser.cli as cli
import fuser.live as live
from fuser.inputs import silence_hint
from local_net import free_port


def test_the_hint_says_what_was_received_and_what_to_check() -> None:
    assert silence_hint("mavlink:udpin:0.0.0.0:14550", {}) == \
        "mavlink:udpin:0.0.0.0:14550: nothing received; is the vehicle, or a router, sending to this address?"
    assert silence_hint("mavlink:/dev/ttyACM0", {"ignored": 40, "bad_crc": 2}, "mavlink") == (
        "mavlink:/dev/ttyACM0: 40 messages heard, none with IMU, attitude or GNSS data (not used: bad_crc=2); does the "
        "vehicle stream them on this link? (ArduPilot: SRn_RAW_SENS, SRn_EXTRA1, SRn_POSITION; PX4: the MAVLink "
        "instance's mode or MAV_n_RATE; or run --request-rate HZ)")
    assert silence_hint("can:virtual:0", {"ignored": 40, "bad_toggle": 2}, "dronecan") == (
        "can:virtual:0: 40 messages heard, none with IMU, attitude or GNSS data (not used: bad_toggle=2); does a node "
        "on the bus publish uavcan.equipment.ahrs.RawIMU, ahrs.Solution or gnss.Fix2?")
    assert silence_hint("mavlink:/dev/ttyUSB0", {"bad_crc": 900, "garbage": 12_000}) == (
        "mavlink:/dev/ttyUSB0: nothing usable received (not used: bad_crc=900, garbage=12,000) (bytes that are not "
        "MAVLink frames: on a serial link, check --baud)")
    assert silence_hint("mavlink:udpin:0.0.0.0:14550", {"bad_signature": 30}) == \
        "mavlink:udpin:0.0.0.0:14550: nothing usable received (not used: bad_signature=30)"


def _heartbeats(port: int, stop: threading.Event) -> None:
    """A vehicle on the link that streams only HEARTBEAT and SYS_STATUS, ten of each a second."""
    link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    while not stop.is_set():
        link.mav.heartbeat_send(2, 3, 0, 0, 4)  # a quadrotor, ArduPilot, standby
        link.mav.sys_status_send(0, 0, 0, 500, 12000, -1, -1, 0, 0, 0, 0, 0, 0)
        time.sleep(0.1)
    link.close()


@pytest.mark.parametrize("vehicle", ["none", "heartbeats only"])
def test_a_run_without_samples_says_why(vehicle: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture,
                                        caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(live, "SILENT_START_NS", 1_000_000_000)  # the run's 5 s, shortened
    port = free_port(socket.SOCK_DGRAM)
    stop = threading.Event()
    sender = threading.Thread(target=_heartbeats, args=(port, stop), daemon=True)
    if vehicle != "none":
        sender.start()
    try:
        code = cli.main(["run", "--mavlink", f"udpin:127.0.0.1:{port}", "--no-zenoh", "--duration", "2.5"])
    finally:
        stop.set()
    err = capsys.readouterr().err
    name = f"mavlink:udpin:127.0.0.1:{port}"
    if vehicle == "none":
        said = f"{name}: nothing received; is the vehicle, or a router, sending to this address?"
    else:
        said = f"{name}: "
    during = [r.getMessage() for r in caplog.records if r.name == "bingham_fuser.live" and "no sample in 1 s" in r.getMessage()]
    assert len(during) == 1 and said in during[0], (during, err)
    ended = [line for line in err.splitlines() if line.startswith(f"bingham-fuser: warning: {name}")]
    assert len(ended) == 1 and said in ended[0], err
    if vehicle != "none":
        # a SYS_STATUS that overtakes the first HEARTBEAT is counted as heard before the vehicle (no_vehicle_yet)
        assert re.search(r"messages heard, none with IMU, attitude or GNSS data( \(not used: no_vehicle_yet=\d+\))?; "
                         r"does the vehicle stream them on this link\?", ended[0]), ended[0]
    assert code == 0


def test_a_can_bus_with_only_node_status_says_what_to_check(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    """A DroneCAN node alive on the bus (NodeStatus at 2 Hz) that publishes no IMU, attitude or GNSS data."""
    import can

    from dronecan_bus import frames, node_status

    monkeypatch.setattr(live, "SILENT_START_NS", 1_000_000_000)
    channel = f"silent-{free_port()}"
    stop = threading.Event()

    def node() -> None:
        with can.Bus(interface="virtual", channel=channel) as bus:
            k = 0
            while not stop.is_set():
                for frame in frames(node_status(1.0 + k), 10, k % 32, 1.0 + k):
                    bus.send(frame)
                k += 1
                time.sleep(0.5)

    sender = threading.Thread(target=node, daemon=True)
    sender.start()
    try:
        code = cli.main(["run", "--can", f"virtual:{channel}", "--no-zenoh", "--duration", "2.5"])
    finally:
        stop.set()
        sender.join(5)
    err = capsys.readouterr().err
    ended = [line for line in err.splitlines() if line.startswith(f"bingham-fuser: warning: can:virtual:{channel}: ")]
    assert len(ended) == 1, err
    assert "messages heard, none with IMU, attitude or GNSS data; does a node on the bus publish uavcan.equipment.ahrs.RawIMU" in ended[0]
    assert code == 0
