"""Asking a MAVLink vehicle to stream what the fuser reads (``[fuser.link] request_rate_hz``, ``run --request-rate``).

An autopilot sends each message at the rate its link is configured for (ArduPilot's ``SRn_*`` parameters, PX4's
MAVLink instance mode and ``MAV_n_RATE``), and a second telemetry port often streams no IMU at all. A ground
station asks for what it shows; so can the fuser, when told to: ``MAV_CMD_SET_MESSAGE_INTERVAL`` (#511, MAVLink
common.xml; ArduPilot 4.0 and later, PX4) in a ``COMMAND_LONG`` for each message it reads. By default it never
writes to a vehicle link: asking changes what the vehicle sends on that link, for every other reader too.

Which messages, by the autopilot of the vehicle's HEARTBEAT, one IMU message type each so that no IMU is read twice:
ArduPilot ``RAW_IMU``, ``SCALED_IMU2``, ``SCALED_IMU3`` (its three IMU instances) and ``ATTITUDE``; PX4
``HIGHRES_IMU`` and ``ATTITUDE_QUATERNION``; any other autopilot ``HIGHRES_IMU`` and ``ATTITUDE``; all
``GPS_RAW_INT`` at most at ``GNSS_MAX_HZ``. The request goes out once the vehicle's HEARTBEAT has been heard
(with ``link.system`` set too: asking for HIGHRES_IMU before knowing an ArduPilot would later add RAW_IMU beside
it), and again every ``REPEAT_NS`` for as long as no IMU sample has arrived in ``DATA_TIMEOUT_NS``:
a command on a radio can be lost, and a rebooted autopilot starts again from its parameters. Signed with the
link's key when it has one (MAVLink 2 signing, the timestamp from the clock as ``mavutil.setup_signing`` sets it),
from system ``GCS_SYSTEM_ID``, component ``MAV_COMP_ID_ONBOARD_COMPUTER``.
"""

from __future__ import annotations

import time
from typing import Any, Callable

from .link import LinkSettings
from .mavlink_decode import MavlinkDecoder, dialect_module

__all__ = ["DATA_TIMEOUT_NS", "GCS_SYSTEM_ID", "GNSS_MAX_HZ", "REPEAT_NS", "StreamRequester", "requested_messages"]

REPEAT_NS = 5_000_000_000
"""Time between two requests while the IMU data does not come."""
DATA_TIMEOUT_NS = 2_000_000_000
"""No IMU sample from the vehicle for this long: its data is not coming (again), ask when the next request is due."""
GNSS_MAX_HZ = 10.0
"""GNSS velocity is asked for at the requested rate, but no faster than this (receivers give 1-20 Hz)."""
GCS_SYSTEM_ID = 255
"""The system id the requests come from (a ground station's, as MAVProxy's and QGroundControl's)."""
_SIGNING_EPOCH_S = 1_420_070_400
"""1 January 2015, 00:00 UTC: MAVLink 2 signing timestamps count 10-us units from it."""


def requested_messages(autopilot: int | None, mod: Any) -> tuple[str, ...]:
    """The messages asked for from a vehicle whose HEARTBEAT names ``autopilot`` (a MAV_AUTOPILOT value)."""
    if autopilot == mod.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3", "ATTITUDE", "GPS_RAW_INT")
    if autopilot == mod.MAV_AUTOPILOT_PX4:
        return ("HIGHRES_IMU", "ATTITUDE_QUATERNION", "GPS_RAW_INT")
    return ("HIGHRES_IMU", "ATTITUDE", "GPS_RAW_INT")


class StreamRequester:
    """Asks the vehicle a :class:`~drivers.mavlink_decode.MavlinkDecoder` reads for its messages at
    ``link.request_rate_hz``, through ``write`` (the link's), whenever :meth:`poll` finds it due (module docstring)."""

    def __init__(self, link: LinkSettings, write: Callable[[bytes], Any]) -> None:
        if link.request_rate_hz is None:
            raise ValueError("link.request_rate_hz is not set: nothing to ask for")
        self.rate_hz = float(link.request_rate_hz)
        self._mod = dialect_module(link.dialect)
        self._mav = self._mod.MAVLink(None, srcSystem=GCS_SYSTEM_ID, srcComponent=self._mod.MAV_COMP_ID_ONBOARD_COMPUTER)
        key = link.signing_key()
        if key is not None:
            self._mav.signing.secret_key = key
            self._mav.signing.timestamp = int((time.time() - _SIGNING_EPOCH_S) * 100_000)
            self._mav.signing.sign_outgoing = True
        self._write = write
        self._asked_ns: int | None = None
        """When the last request went out; None before the first."""
        self._imu_seen = 0
        """The decoder's IMU samples used at the last poll."""
        self._imu_ns: int | None = None
        """When the last poll found a new IMU sample; None before the first."""

    def poll(self, now_ns: int, decoder: MavlinkDecoder) -> int:
        """Send the requests if due at ``now_ns`` (a monotonic clock); returns how many messages were asked for."""
        imu = decoder.imu_used
        if imu != self._imu_seen:
            self._imu_seen, self._imu_ns = imu, now_ns
        if decoder.system is None or decoder.autopilot is None:
            return 0  # no vehicle's HEARTBEAT yet: nobody to ask, or not which messages (a guess could double an IMU)
        if self._imu_ns is not None and now_ns - self._imu_ns < DATA_TIMEOUT_NS:
            return 0  # the data comes
        if self._asked_ns is not None and now_ns - self._asked_ns < REPEAT_NS:
            return 0
        self._asked_ns = now_ns
        names = requested_messages(decoder.autopilot, self._mod)
        frames = b"".join(self._request(decoder.system, decoder.component or 0, name) for name in names)
        self._write(frames)
        return len(names)

    def _request(self, system: int, component: int, name: str) -> bytes:
        """The COMMAND_LONG asking ``system``/``component`` for message ``name`` at the rate."""
        rate_hz = min(self.rate_hz, GNSS_MAX_HZ) if name == "GPS_RAW_INT" else self.rate_hz
        message_id = getattr(self._mod, f"MAVLINK_MSG_ID_{name}")
        command = self._mav.command_long_encode(system, component, self._mod.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                message_id, 1e6 / rate_hz, 0, 0, 0, 0, 0)
        frame = bytes(command.pack(self._mav))
        self._mav.seq = (self._mav.seq + 1) % 256
        return frame
