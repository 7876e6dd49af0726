"""Live and recorded sample sources: a MAVLink connection, a CAN bus."""

from __future__ import annotations

import os
import time
from typing import Any

import can

from .base import SampleSource
from .dronecan_decode import DroneCanDecoder
from .mavlink_decode import MavlinkDecoder
from .samples import Sample

# mavutil picks MAVLink 1 unless this is set before its first use (pymavlink's own switch).
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

MAX_BATCH = 1024
"""``poll`` returns after this many samples even if more input is waiting."""


class MavlinkSource(SampleSource):
    """Samples from anything ``mavutil.mavlink_connection`` opens.

    ``connection_string`` is e.g. ``udpin:0.0.0.0:14550``, ``udpout:host:port``,
    ``tcp:host:5760``, ``/dev/ttyUSB0`` (pass ``baud=57600``) or ``flight.tlog``;
    ``connection_options`` go to ``mavlink_connection``. A log file is read as
    fast as ``poll`` is called; ``exhausted`` turns true at its end.
    """

    def __init__(
        self,
        connection_string: str,
        dialect: str = "common",
        system: int | None = None,
        component: int | None = None,
        **connection_options: Any,
    ) -> None:
        self.connection = mavutil.mavlink_connection(connection_string, dialect=dialect, **connection_options)
        self.decoder = MavlinkDecoder(system, component, dialect, parser=self.connection.mav)
        self.stats = self.decoder.stats
        self._is_file = isinstance(self.connection, mavutil.mavlogfile)
        self.exhausted = False

    def poll(self, timeout: float) -> list[Sample]:
        deadline = time.monotonic() + timeout
        samples: list[Sample] = []
        while len(samples) < MAX_BATCH:
            msg = self.connection.recv_msg()
            if msg is not None:
                sample = self.decoder.decode_message(msg)
                if sample is not None:
                    samples.append(sample)
                continue
            if self._is_file:
                self.exhausted = True
                break
            remaining = deadline - time.monotonic()
            if samples or remaining <= 0:
                break
            self.connection.select(remaining)
        return samples

    def close(self) -> None:
        self.connection.close()


class DroneCanSource(SampleSource):
    """Samples from a python-can bus: pass a ``can.BusABC``, or the arguments of ``can.Bus``.

    For example ``DroneCanSource(interface="socketcan", channel="can0")`` or
    ``DroneCanSource(interface="slcan", channel="/dev/ttyACM0", bitrate=1000000)``.
    A bus this source opened is shut down by ``close``; a bus passed in is left open.
    """

    def __init__(self, bus: can.BusABC | None = None, **bus_options: Any) -> None:
        self._owns_bus = bus is None
        self.bus = can.Bus(**bus_options) if bus is None else bus
        self.decoder = DroneCanDecoder()
        self.stats = self.decoder.stats

    def poll(self, timeout: float) -> list[Sample]:
        samples: list[Sample] = []
        msg = self.bus.recv(timeout)
        while msg is not None:
            samples += self.decoder.feed(msg)
            if len(samples) >= MAX_BATCH:
                break
            msg = self.bus.recv(0.0)
        return samples

    def close(self) -> None:
        if self._owns_bus:
            self.bus.shutdown()
