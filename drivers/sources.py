"""Live sample sources: a MAVLink connection, a CAN bus.

Both check what they are given when they are constructed and raise :class:`~drivers.base.SourceError`
naming the problem (python-can's pattern: a bus that cannot be opened fails in its constructor),
so a typo in a connection string never surfaces later as a traceback from a poll.
"""

from __future__ import annotations

import os
import socket
import time
from typing import Any

import can

from .base import SampleSource, SourceError
from .dronecan_decode import DroneCanDecoder
from .link import LinkSettings
from .mavlink_decode import MavlinkDecoder
from .samples import Sample
from .stream_request import StreamRequester

# mavutil picks MAVLink 1 for what a connection writes unless this is set before its first use.
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

MAX_BATCH = 1024
"""``poll`` returns after this many samples even if more input is waiting."""
MAX_POLL_BYTES = 65_536
"""``poll`` returns after reading this much, samples or not, so a flood cannot hold it (or the real
samples behind the flood) for longer than parsing 64 KiB takes (about 5-15 ms)."""
MAX_POLL_FRAMES = 4_096
"""``DroneCanSource.poll`` returns after this many CAN frames, samples or not (a flooded bus)."""
READ_SIZE = 16_384
"""Bytes asked for per read from a stream (serial, TCP); a UDP read returns one whole datagram."""
NETWORK_SCHEMES = ("udpin", "udpout", "udp", "udpbcast", "tcp", "tcpin")
CONNECTION_FORMS = (
    "udpin:HOST:PORT, udpout:HOST:PORT, udpbcast:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT, "
    "HOST:PORT (UDP, listening), or a serial device such as /dev/ttyUSB0"
)
_LOG_SUFFIXES = (".tlog", ".bin", ".log", ".mcap", ".ulg")


def _endpoint(connection: str, scheme: str, address: str) -> None:
    """Check the HOST:PORT of a network connection string; ``SourceError`` naming the fault."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535 or (int(port) == 0 and scheme != "udpin"):
        raise SourceError(f"MAVLink connection {connection!r}: {scheme} wants HOST:PORT with a port 1-65535")
    try:
        socket.getaddrinfo(host, int(port), socket.AF_INET)
    except (socket.gaierror, UnicodeError) as exc:
        raise SourceError(f"MAVLink connection {connection!r}: unknown host {host!r} ({exc})") from exc


def open_mavlink(connection: str, baud: int = 57600, **options: Any) -> Any:
    """The ``mavutil`` connection of ``connection`` (see CONNECTION_FORMS), checked; ``SourceError`` if it cannot be opened."""
    scheme, sep, rest = connection.partition(":")
    if connection.lower().endswith(_LOG_SUFFIXES):
        raise SourceError(f"MAVLink connection {connection!r} is a log file: replay it (drivers.tlog.TlogSource, bingham-fuser replay)")
    if sep and scheme in NETWORK_SCHEMES:
        _endpoint(connection, scheme, rest)
        if scheme == "tcp":
            options.setdefault("retries", 0)  # one attempt: fail now, not after seconds of silent retries
    elif sep and rest.isdigit():  # HOST:PORT, as pymavlink reads it: UDP, listening
        _endpoint(connection, "udpin", connection)
    elif sep and not os.path.exists(connection):
        raise SourceError(f"MAVLink connection {connection!r}: unknown kind {scheme!r}; expected {CONNECTION_FORMS}")
    elif not (os.path.exists(connection) or (os.name == "nt" and connection.upper().startswith("COM"))):
        raise SourceError(f"MAVLink connection {connection!r}: no such serial device; expected {CONNECTION_FORMS}")
    try:
        return mavutil.mavlink_connection(connection, baud=baud, **options)
    except (OSError, ValueError) as exc:  # serial.SerialException is an OSError
        raise SourceError(f"MAVLink connection {connection!r} cannot be opened: {exc}") from exc


class MavlinkSource(SampleSource):
    """Samples from a live MAVLink link: UDP, TCP or a serial port.

    ``connection_string``: see ``CONNECTION_FORMS`` (``baud`` for serial ports;
    ``connection_options`` go to ``mavutil.mavlink_connection``). ``link`` chooses the vehicle,
    the signing key and the dialect. The connection only moves bytes: the source's own decoder
    frames them (every frame of a datagram), so pymavlink's per-message-type cache
    (``mavfile.messages``) and its parser buffer never grow. UDP is read as a byte stream, as
    pymavlink reads it, so a bridge that splits frames across datagrams loses nothing.
    """

    transport = "mavlink"

    def __init__(self, connection_string: str, link: LinkSettings | None = None, baud: int = 57600, **connection_options: Any) -> None:
        link = LinkSettings() if link is None else link
        self.decoder = MavlinkDecoder(link)
        self.stats = self.decoder.stats
        self.connection = open_mavlink(connection_string, baud, **connection_options)
        self.requester = None if link.request_rate_hz is None else StreamRequester(link, self.connection.write)
        """Asks the vehicle for its messages (``link.request_rate_hz``, :mod:`drivers.stream_request`); None: listen only."""

    def poll(self, timeout: float) -> list[Sample]:
        """Samples read within ``timeout`` s: returns as soon as some have arrived, or after MAX_POLL_BYTES."""
        deadline = time.monotonic() + timeout
        samples: list[Sample] = []
        read = 0
        woken = False
        while len(samples) < MAX_BATCH and read < MAX_POLL_BYTES:
            data = self.connection.recv(READ_SIZE)
            if data:
                woken = False
                read += len(data)
                samples += self.decoder.feed(data, time.monotonic_ns())
                if samples:
                    break
                continue
            remaining = deadline - time.monotonic()
            if woken:  # readable, yet nothing to read (a closed TCP peer): wait out the timeout, do not spin
                time.sleep(max(remaining, 0.0))
                break
            if remaining <= 0 or not self.connection.select(remaining):
                break
            woken = True
        if self.requester is not None:
            self._request()
        return samples

    def _request(self) -> None:
        """Send the stream requests when due; a write that fails is counted (``request_failed``), the link read on."""
        try:
            asked = self.requester.poll(time.monotonic_ns(), self.decoder)  # type: ignore[union-attr]
        except OSError:
            self.stats["request_failed"] += 1
            return
        if asked:
            self.stats["stream_requests"] += asked

    def close(self) -> None:
        self.connection.close()


class DroneCanSource(SampleSource):
    """Samples from a python-can bus: pass a ``can.BusABC``, or the arguments of ``can.Bus``.

    For example ``DroneCanSource(interface="socketcan", channel="can0")`` or
    ``DroneCanSource(interface="slcan", channel="/dev/ttyACM0", bitrate=1000000)``.
    A bus this source opened is shut down by ``close``; a bus passed in is left open.
    An interface or channel python-can cannot open raises ``SourceError``.
    """

    transport = "dronecan"

    def __init__(self, bus: can.BusABC | None = None, **bus_options: Any) -> None:
        self._owns_bus = bus is None
        if bus is None:
            try:
                bus = can.Bus(**bus_options)
            except (can.CanError, OSError, ValueError, TypeError, ImportError, NotImplementedError) as exc:
                described = ", ".join(f"{k}={v!r}" for k, v in bus_options.items())
                raise SourceError(f"CAN bus {described} cannot be opened: {exc}") from exc
        self.bus = bus
        self.decoder = DroneCanDecoder()
        self.stats = self.decoder.stats

    def poll(self, timeout: float) -> list[Sample]:
        samples: list[Sample] = []
        frames = 0
        msg = self.bus.recv(timeout)
        while msg is not None:
            samples += self.decoder.feed(msg)
            frames += 1
            if len(samples) >= MAX_BATCH or frames >= MAX_POLL_FRAMES:
                break
            msg = self.bus.recv(0.0)
        return samples

    def close(self) -> None:
        if self._owns_bus:
            self.bus.shutdown()
