"""Asking the vehicle for its messages (``run --request-rate HZ``, drivers/stream_request.py).

A vehicle that sends only HEARTBEATs on a link (ArduPilot's SRn_RAW_SENS at 0, the usual case on a second
telemetry port) gives the fuser nothing to fuse. With a request rate, the fuser asks as a ground station does:
MAV_CMD_SET_MESSAGE_INTERVAL (MAVLink common.xml, #511: param1 the message id, param2 the interval in
microseconds) for each message it reads, chosen by the HEARTBEAT's autopilot, until the IMU data comes.

The frames are read back here by pymavlink's own parser (not the project's decoder), the ids and intervals
checked against the MAVLink message definitions and the rate; a fake vehicle on UDP streams only what it is
asked for, and ``run`` fuses it."""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

import fuser.cli as cli
from drivers import stream_request
from drivers.link import LinkSettings
from drivers.mavlink_decode import MavlinkDecoder
from drivers.mavlink_encode import MavlinkEncoder
from drivers.samples import ImuSample, SourceId
from drivers.stream_request import StreamRequester
from local_net import free_port

SECOND = 1_000_000_000
ARDUPILOT = {"RAW_IMU": 27, "SCALED_IMU2": 116, "SCALED_IMU3": 129, "ATTITUDE": 30, "GPS_RAW_INT": 24}
"""Message ids from common.xml, written out."""
PX4 = {"HIGHRES_IMU": 105, "ATTITUDE_QUATERNION": 31, "GPS_RAW_INT": 24}


def _commands(data: bytes, key: bytes | None = None) -> list[tuple[int, int, int, int, float]]:
    """(target system, target component, command, message id, interval us) of each COMMAND_LONG in ``data``,
    as pymavlink's parser reads them (with ``key``: only frames whose signature verifies)."""
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True  # a frame that does not verify is a BAD_DATA message, not an exception
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.allow_unsigned_callback = lambda *_: False
    out = []
    for msg in mav.parse_buffer(data) or []:
        if msg.get_type() == "BAD_DATA":
            continue
        assert msg.get_type() == "COMMAND_LONG"
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == (255, 191)
        out.append((msg.target_system, msg.target_component, msg.command, int(msg.param1), msg.param2))
    return out


class Written:
    def __init__(self) -> None:
        self.data = b""

    def __call__(self, data: bytes) -> None:
        self.data += data


def _heartbeat(autopilot: int) -> bytes:
    """A HEARTBEAT of system 1, component 1: a quadrotor of ``autopilot``, in standby (pymavlink's encoder)."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    return bytes(mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, autopilot, 0, 0, mavlink.MAV_STATE_STANDBY).pack(mav))


def _heard(autopilot: int) -> MavlinkDecoder:
    """A decoder (the first autopilot's data) that has heard the vehicle's HEARTBEAT."""
    decoder = MavlinkDecoder(LinkSettings())
    decoder.feed(_heartbeat(autopilot))
    return decoder


@pytest.mark.parametrize("autopilot, asked", [(3, ARDUPILOT), (12, PX4), (0, {"HIGHRES_IMU": 105, "ATTITUDE": 30, "GPS_RAW_INT": 24})])
def test_the_request_names_what_the_fuser_reads_at_the_rate(autopilot: int, asked: dict[str, int]) -> None:
    written = Written()
    requester = StreamRequester(LinkSettings(request_rate_hz=50.0), written)
    assert requester.poll(0, MavlinkDecoder(LinkSettings())) == 0 and written.data == b""  # no vehicle heard: nobody to ask
    assert requester.poll(1, _heard(autopilot)) == len(asked)
    intervals = {ARDUPILOT.get(n, PX4.get(n)): (1e6 / 10 if n == "GPS_RAW_INT" else 1e6 / 50) for n in asked}
    intervals[30] = 1e6 / 50
    assert _commands(written.data) == [(1, 1, 511, message_id, intervals[message_id]) for message_id in asked.values()]


def test_asked_again_until_the_imu_comes_and_again_when_it_stops() -> None:
    written = Written()
    requester = StreamRequester(LinkSettings(request_rate_hz=100.0), written)
    decoder = _heard(3)
    asked = [t for t in range(0, 30 * SECOND, SECOND // 10) if requester.poll(t, decoder)]
    assert asked == [0, 5 * SECOND, 10 * SECOND, 15 * SECOND, 20 * SECOND, 25 * SECOND]  # lost, or not honoured: every 5 s
    encoder = MavlinkEncoder(1, 1, "ardupilotmega", autopilot=3)
    imu = ImuSample(0, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), None, SourceId("mavlink", 1, 1, 0))
    asked = []
    for k, t in enumerate(range(30 * SECOND, 60 * SECOND, SECOND // 10)):
        if t < 45 * SECOND:  # the data comes for 15 s, then stops (a reboot: the rates are the parameters' again)
            decoder.feed(encoder.encode(replace(imu, t_ns=k * SECOND // 10), "RAW_IMU"))
        if requester.poll(t, decoder):
            asked.append(t)
    # the last sample at 44.9 s; 2 s without one (DATA_TIMEOUT_NS), then every 5 s again
    assert asked == [46_900_000_000, 51_900_000_000, 56_900_000_000], asked


def test_with_a_signing_key_the_requests_are_signed_with_it(tmp_path: Path) -> None:
    key = bytes(range(32))
    (tmp_path / "key").write_bytes(key)
    link = LinkSettings(signing_key_file=str(tmp_path / "key"), request_rate_hz=20.0)
    written = Written()
    StreamRequester(link, written).poll(0, _heard(3))  # the heartbeat unsigned: the decoder here has no key
    assert len(_commands(written.data, key)) == 5  # every frame verifies with the key
    assert _commands(written.data, bytes(32)) == []  # and none with another
    written_plain = Written()
    StreamRequester(LinkSettings(request_rate_hz=20.0), written_plain).poll(0, _heard(3))
    assert _commands(written_plain.data, key) == []  # unsigned ones are refused by a vehicle that requires signing


class FakeVehicle(threading.Thread):
    """An ArduPilot quadrotor on UDP: HEARTBEAT at 10 Hz; each message asked for by SET_MESSAGE_INTERVAL streamed
    at its interval (RAW_IMU at rest), nothing else; ignores the first ``ignore`` requests (a lossy radio)."""

    def __init__(self, port: int, ignore: int = 0) -> None:
        super().__init__(daemon=True)
        self.link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, dialect="ardupilotmega")
        self.intervals: dict[int, float] = {}
        self.requests: list[tuple[int, float]] = []
        self.ignore = ignore
        self.stop = threading.Event()

    def run(self) -> None:
        start, next_heartbeat, next_imu = time.monotonic(), 0.0, 0.0
        while not self.stop.is_set():
            now = time.monotonic() - start
            if now >= next_heartbeat:
                self.link.mav.heartbeat_send(2, 3, 0, 0, 4)
                next_heartbeat = now + 0.1
            interval = self.intervals.get(27)
            if interval and now >= next_imu:
                self.link.mav.raw_imu_send(int(now * 1e6), 0, 0, 1000, 0, 0, 0, 200, 0, 400, 0, 0)
                next_imu = now + interval / 1e6
            msg = self.link.recv_match(type="COMMAND_LONG", blocking=False)
            if msg is not None and msg.command == 511:
                self.requests.append((int(msg.param1), msg.param2))
                if len(self.requests) > self.ignore * 5:
                    self.intervals[int(msg.param1)] = msg.param2
            time.sleep(0.001)
        self.link.close()


@pytest.mark.parametrize("rate, ignore", [(None, 0), (50.0, 0), (50.0, 1)])
def test_run_asks_the_vehicle_and_fuses_what_comes(rate: float | None, ignore: int, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture) -> None:
    monkeypatch.setattr(stream_request, "REPEAT_NS", SECOND)  # the 5 s between requests, shortened
    port = free_port(socket.SOCK_DGRAM)
    vehicle = FakeVehicle(port, ignore)
    vehicle.start()
    try:
        code = cli.main(["run", "--mavlink", f"udpin:127.0.0.1:{port}", "--no-zenoh", "--duration", "3"]
                        + ([] if rate is None else ["--request-rate", str(rate)]))
    finally:
        vehicle.stop.set()
        vehicle.join(5)
    out = capsys.readouterr().out
    assert code == 0
    if rate is None:  # only listening: the vehicle was never asked, and sent no IMU
        assert vehicle.requests == [] and "0 samples accepted" in out, out
        return
    assert vehicle.requests[:5] == [(m, 1e6 / (10 if m == 24 else 50)) for m in ARDUPILOT.values()]
    assert len(vehicle.requests) == 5 * (1 + ignore), vehicle.requests  # asked again after the lost one, then no more
    estimates = int(out.split("run: ")[1].split()[0])
    accepted = int(out.split(" samples accepted")[0].rsplit(" ", 1)[1].replace(",", ""))
    assert estimates > 100 and accepted > 50, out
    assert f"stream_requests={5 * (1 + ignore)}" in out, out


def test_nothing_is_asked_before_the_vehicle_says_which_autopilot_it_is() -> None:
    """With ``--system`` the vehicle is known before its HEARTBEAT; the messages are not: a guess (HIGHRES_IMU) sent to
    an ArduPilot, then RAW_IMU once its HEARTBEAT names it, would stream its IMU twice."""
    written = Written()
    link = LinkSettings(system=1, request_rate_hz=50.0)
    decoder = MavlinkDecoder(link)
    requester = StreamRequester(link, written)
    assert [requester.poll(t * SECOND, decoder) for t in range(10)] == [0] * 10 and written.data == b""
    decoder.feed(_heartbeat(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA))
    assert requester.poll(10 * SECOND, decoder) == 5
    assert [c[3] for c in _commands(written.data)] == list(ARDUPILOT.values())
