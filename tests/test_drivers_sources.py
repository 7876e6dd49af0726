"""Sources check what they are given at construction: one exception type, a message naming the fault."""

from __future__ import annotations

import socket

import pytest

from drivers import DroneCanSource, MavlinkSource, SourceError


def closed_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # nothing listens there once the socket is closed


@pytest.mark.parametrize(
    "connection, says",
    [
        ("notaport", "no such serial device"),
        ("999.1.1.1", "no such serial device"),
        ("/dev/ttyNOSUCH0", "no such serial device"),
        ("udpin:999.1.1.1:14550", "unknown host"),
        ("udpout:127.0.0.1:notaport", "port 1-65535"),
        ("udpout:127.0.0.1:70000", "port 1-65535"),
        ("tcp:127.0.0.1", "HOST:PORT"),
        ("tcp:127.0.0.1:{closed}", "cannot be opened"),
        ("serial:/dev/ttyUSB0", "unknown kind 'serial'"),
        ("flight.tlog", "is a log file"),
    ],
)
def test_a_bad_mavlink_connection_is_a_source_error(connection, says):
    connection = connection.format(closed=closed_tcp_port())
    with pytest.raises(SourceError, match=says) as info:
        MavlinkSource(connection)
    assert connection in str(info.value)


@pytest.mark.parametrize(
    "options, says",
    [
        ({"interface": "nosuchbus", "channel": "x"}, "nosuchbus"),
        ({"interface": "socketcan", "channel": "nosuchcan9"}, "nosuchcan9"),
        ({"interface": "slcan", "channel": "/dev/ttyNOSUCH0", "bitrate": 1_000_000}, "ttyNOSUCH0"),
    ],
)
def test_a_can_bus_that_cannot_be_opened_is_a_source_error(options, says):
    with pytest.raises(SourceError, match=says):
        DroneCanSource(**options)


def test_good_connections_open():
    with MavlinkSource("udpin:127.0.0.1:0") as src:
        assert src.poll(0.0) == []
    with DroneCanSource(interface="virtual", channel="sources-test") as src:
        assert src.poll(0.0) == []
