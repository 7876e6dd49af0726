"""Samples from files and from the simulator (recorded MCAP inputs come from ``fuser.record.read_log``).

* a MAVLink telemetry log (.tlog: each packet carries the receive time), as
  ``(sample, receive_ns)`` in arrival order;
* the simulated vehicle, encoded as MAVLink bytes or DroneCAN frames and
  decoded by the real drivers, exactly as from an autopilot.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

from drivers.dronecan_decode import DroneCanDecoder
from drivers.mavlink_decode import MavlinkDecoder
from drivers.samples import Sample
from drivers.sim import Flight, dronecan_stream, mavlink_stream

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

__all__ = ["sim_ticks", "tlog_inputs"]

SIM_LINK_LATENCY_NS = 1_000_000
"""Receive time of a simulated sample: its send time plus this link latency."""


def tlog_inputs(path: str | Path, dialect: str = "common") -> Iterator[tuple[Sample, int]]:
    """Samples of a MAVLink .tlog with the receive time each packet was logged at."""
    connection = mavutil.mavlink_connection(str(path), dialect=dialect)
    decoder = MavlinkDecoder(dialect=dialect, parser=connection.mav)
    try:
        while (msg := connection.recv_msg()) is not None:
            sample = decoder.decode_message(msg)
            if sample is not None:
                yield sample, round(msg._timestamp * 1e9)
    finally:
        connection.close()


def sim_ticks(flight: Flight, transport: str = "mavlink") -> Iterator[tuple[int, object, list[Sample]]]:
    """Per simulated IMU tick: (send time ns, true q, samples decoded from the bytes or frames sent)."""
    if transport == "mavlink":
        decoder = MavlinkDecoder()
        for t, q, data in mavlink_stream(flight):
            yield t, q, decoder.feed(data)
    elif transport == "dronecan":
        can_decoder = DroneCanDecoder()
        for t, q, frames in dronecan_stream(flight):
            yield t, q, [s for frame in frames for s in can_decoder.feed(frame)]
    else:
        raise ValueError(f"transport must be 'mavlink' or 'dronecan', got {transport!r}")
