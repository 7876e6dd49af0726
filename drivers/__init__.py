"""Decoders, sources and a simulated vehicle for IMU and attitude telemetry (MAVLink, DroneCAN)."""

from .base import SampleSource
from .dronecan_decode import DroneCanDecoder
from .dronecan_encode import encode_dronecan
from .mavlink_decode import MavlinkDecoder
from .mavlink_encode import MavlinkEncoder, encode_mavlink
from .samples import AttitudeSample, GnssSample, ImuSample, MagSample, Sample, SourceId
from .sources import DroneCanSource, MavlinkSource

__all__ = [
    "AttitudeSample",
    "DroneCanDecoder",
    "DroneCanSource",
    "GnssSample",
    "ImuSample",
    "MagSample",
    "MavlinkDecoder",
    "MavlinkEncoder",
    "MavlinkSource",
    "Sample",
    "SampleSource",
    "SourceId",
    "encode_dronecan",
    "encode_mavlink",
]
