"""Decoders, sources and a simulated vehicle for IMU and attitude telemetry (MAVLink, DroneCAN)."""

from .base import SampleSource, SourceError
from .dronecan_decode import DroneCanDecoder
from .dronecan_encode import encode_dronecan
from .link import LinkSettings
from .mavlink_decode import MavlinkDecoder
from .mavlink_encode import MavlinkEncoder, encode_mavlink
from .samples import AttitudeSample, GnssSample, ImuSample, MagSample, Sample, SourceId
from .sources import DroneCanSource, MavlinkSource
from .tlog import TlogSource

__all__ = [
    "AttitudeSample",
    "DroneCanDecoder",
    "DroneCanSource",
    "GnssSample",
    "ImuSample",
    "LinkSettings",
    "MagSample",
    "MavlinkDecoder",
    "MavlinkEncoder",
    "MavlinkSource",
    "Sample",
    "SampleSource",
    "SourceError",
    "SourceId",
    "TlogSource",
    "encode_dronecan",
    "encode_mavlink",
]
