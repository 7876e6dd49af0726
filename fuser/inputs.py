"""Samples from files and from the simulator (recorded MCAP inputs come from ``fuser.record.read_log``),
and the account of what became of an input's messages.

* a MAVLink telemetry log (.tlog: each packet carries the receive time), as
  ``(sample, receive_ns)`` in arrival order, through the live decoder (:class:`TlogInputs`);
* the simulated vehicle, encoded as MAVLink bytes or DroneCAN frames and
  decoded by the real drivers, exactly as from an autopilot;
* :class:`InputReport`: how many of the IMU messages an input carried reached the loop, and
  everything else by reason, for the end of a ``replay`` or a ``run``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

from drivers.link import LinkSettings
from drivers.mavlink_decode import MavlinkDecoder
from drivers.samples import ImuSample, Sample
from drivers.sim import Flight, dronecan_stream, mavlink_stream
from drivers.tlog import TlogSource

__all__ = ["InputReport", "TlogInputs", "silence_hint", "sim_ticks", "source_report"]

SIM_LINK_LATENCY_NS = 1_000_000
"""Receive time of a simulated sample: its send time plus this link latency."""
USED_WARNING_FRACTION = 0.9
"""Below this fraction of the decodable IMU messages reaching the loop, the report warns."""
NOT_REFUSALS = ("accepted", "ignored", "not_dronecan_message", "reboot", "clock_jump", "record_clock_step", "lost",
                "stream_requests", "request_failed")
"""Counts in a decoder's (and a .tlog reader's) ``stats`` that are not refusals (drivers/README.md, "Counted but not
refusals"): what was used, valid messages and frames the drivers do not use (heartbeats, a bus's service traffic),
events confirmed in a sender's clock or a log's, the frames missing in MAVLink's sequence numbers, and the stream
requests sent to the vehicle (``link.request_rate_hz``) and those that could not be written."""


@dataclass(frozen=True)
class InputReport:
    """What an input gave: its decodable IMU messages, how many reached the loop, and every count by reason.

    ``imu_decodable`` counts the valid IMU messages on the input (every sender, as pymavlink alone
    decodes them); ``imu_used`` the IMU samples the loop took in time, or for a live source the
    decoder's IMU samples accepted (each decoder counts its own IMU types: MAVLink's messages, DroneCAN's
    RawIMU). ``stats`` is the decoder's (and the log reader's).
    """

    name: str
    imu_decodable: int
    imu_used: int
    stats: Mapping[str, int]
    other_vehicles: tuple[tuple[int, int], ...] = ()
    """(system, component) of other vehicles heard on the link, whose data was left out (``other_sender``)."""

    @property
    def refused(self) -> dict[str, int]:
        return {k: v for k, v in sorted(self.stats.items()) if k not in NOT_REFUSALS and v}

    def lines(self) -> list[str]:
        """One line of use, one of refusals by reason (what ``replay`` and ``run`` print at the end)."""
        share = f" ({100 * self.imu_used / self.imu_decodable:.1f}%)" if self.imu_decodable else ""
        used = f"{self.name}: {self.imu_used:,} of {self.imu_decodable:,} IMU messages used{share}; "
        used += f"{self.stats.get('accepted', 0):,} samples accepted, {self.stats.get('ignored', 0):,} messages ignored"
        counted = [f"{k}={self.stats[k]:,}" for k in NOT_REFUSALS if k not in ("accepted", "ignored") and self.stats.get(k)]
        used += f"; also counted: {', '.join(counted)}" if counted else ""
        refused = ", ".join(f"{k}={v:,}" for k, v in self.refused.items())
        lines = [used, f"{self.name}: not used: {refused or 'nothing'}"]
        if self.other_vehicles:
            heard = ", ".join(f"system {s} component {c}" for s, c in self.other_vehicles)
            lines.append(f"{self.name}: other vehicles on this link: {heard}; their data is left out (other_sender): one vehicle "
                         "is fused, the first autopilot heard unless --system N (and --component C) names another")
        return lines

    def warning(self) -> str | None:
        """A warning when less than 90% of the decodable IMU messages reached the loop."""
        if not self.imu_decodable or self.imu_used >= USED_WARNING_FRACTION * self.imu_decodable:
            return None
        return (f"warning: {self.name}: only {self.imu_used:,} of {self.imu_decodable:,} decodable IMU messages "
                f"({100 * self.imu_used / self.imu_decodable:.0f}%) reached the loop; see 'not used' for why")


def _imu_decodable(decoder: MavlinkDecoder | Any) -> int:
    """The decoder's valid IMU messages (or DroneCAN transfers), every sender's, used or not."""
    return sum(decoder.received[m] for m in decoder.imu_types)


class TlogInputs:
    """A .tlog's samples with their receive times (iterate), through the live decoder with ``link``.

    Feed them with :meth:`feed` to count the IMU samples the loop takes in time for :meth:`report`.
    """

    def __init__(self, path: str | Path, link: LinkSettings | None = None) -> None:
        self.source = TlogSource(path, link)
        self.name = Path(path).name
        self.imu_used = 0

    def __iter__(self) -> Iterator[tuple[Sample, int]]:
        try:
            yield from self.source.samples()
        finally:
            self.source.close()

    def feeder(self, pipeline: Any) -> Callable[[Sample, int], None]:
        """``pipeline.feed`` that also counts the IMU samples the loop did not drop as late."""
        counters = pipeline.loop.counters

        def feed(sample: Sample, receive_ns: int) -> None:
            late = counters["late"]
            pipeline.feed(sample, receive_ns)
            if isinstance(sample, ImuSample) and counters["late"] == late:
                self.imu_used += 1

        return feed

    def report(self) -> InputReport:
        decoder = self.source.decoder
        return InputReport(self.name, _imu_decodable(decoder), self.imu_used, dict(self.stats), _other_vehicles(decoder))

    @property
    def stats(self) -> Counter[str]:
        return self.source.stats


STREAMING = {
    "mavlink": "does the vehicle stream them on this link? (ArduPilot: SRn_RAW_SENS, SRn_EXTRA1, SRn_POSITION; PX4: the "
               "MAVLink instance's mode or MAV_n_RATE; or run --request-rate HZ)",
    "dronecan": "does a node on the bus publish uavcan.equipment.ahrs.RawIMU, ahrs.Solution or gnss.Fix2?",
}
"""What to check when a source hears valid traffic without data, by transport."""


def silence_hint(name: str, stats: Mapping[str, int], transport: str = "") -> str:
    """For a live source that has delivered no sample: what it did receive, by its decoder's ``stats``, and what to
    check. Nothing at all is the link (an address nobody sends to); valid messages without data (heartbeats,
    status; a bus's node status) are what the vehicle streams (:data:`STREAMING`, by ``transport``); bytes that
    are no frame at all, on a serial port, are most often a wrong baud rate."""
    if not any(stats.values()):
        return f"{name}: nothing received; is the vehicle, or a router, sending to this address?"
    refused = ", ".join(f"{k}={v:,}" for k, v in sorted(stats.items()) if k not in NOT_REFUSALS and v)
    if stats.get("ignored"):
        return (f"{name}: {stats['ignored']:,} messages heard, none with IMU, attitude or GNSS data"
                + (f" (not used: {refused})" if refused else "") + f"; {STREAMING.get(transport, 'does the vehicle send them?')}")
    garbled = " (bytes that are not MAVLink frames: on a serial link, check --baud)" if stats.get("garbage") else ""
    return f"{name}: nothing usable received (not used: {refused}){garbled}"


def source_report(name: str, source: Any) -> InputReport:
    """The decoder's view of a live source (IMU samples accepted, not what the loop took): its IMU messages (DroneCAN
    RawIMU transfers) decoded and used; under 90 % used, the report warns (it said "0 of 0" for a CAN bus)."""
    decoder = source.decoder
    return InputReport(name, _imu_decodable(decoder), decoder.imu_used, dict(source.stats), _other_vehicles(decoder))


def _other_vehicles(decoder: MavlinkDecoder | Any) -> tuple[tuple[int, int], ...]:
    """The other vehicles a MAVLink decoder heard, in order (a DroneCAN bus names none)."""
    return tuple(sorted(getattr(decoder, "other_vehicles", ())))


def sim_ticks(flight: Flight, transport: str = "mavlink") -> Iterator[tuple[int, object, list[Sample]]]:
    """Per simulated IMU tick: (send time ns, true q, samples decoded from the bytes or frames sent)."""
    if transport == "mavlink":
        decoder = MavlinkDecoder()
        for t, q, data in mavlink_stream(flight):
            yield t, q, decoder.feed(data)
    elif transport == "dronecan":
        from drivers.dronecan_decode import DroneCanDecoder  # here: importing dronecan parses its DSDL

        can_decoder = DroneCanDecoder()
        for t, q, frames in dronecan_stream(flight):
            yield t, q, [s for frame in frames for s in can_decoder.feed(frame)]
    else:
        raise ValueError(f"transport must be 'mavlink' or 'dronecan', got {transport!r}")
