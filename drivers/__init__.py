"""Decoders, sources and a simulated vehicle for IMU and attitude telemetry (MAVLink, DroneCAN).

The names below are loaded on first use (PEP 562, as scipy loads its submodules): ``dronecan`` parses its DSDL
definitions when imported (about a third of a second), which a command that reads no CAN bus should not pay.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_WHERE = {
    "SampleSource": "base", "SourceError": "base",
    "DroneCanDecoder": "dronecan_decode",
    "encode_dronecan": "dronecan_encode",
    "LinkSettings": "link",
    "MavlinkDecoder": "mavlink_decode",
    "MavlinkEncoder": "mavlink_encode", "encode_mavlink": "mavlink_encode",
    "AttitudeSample": "samples", "GnssSample": "samples", "ImuSample": "samples", "MagSample": "samples",
    "Sample": "samples", "SourceId": "samples",
    "DroneCanSource": "sources", "MavlinkSource": "sources",
    "TlogSource": "tlog",
}
"""Each public name and the submodule that defines it."""

__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from .base import SampleSource, SourceError
    from .dronecan_decode import DroneCanDecoder
    from .dronecan_encode import encode_dronecan
    from .link import LinkSettings
    from .mavlink_decode import MavlinkDecoder
    from .mavlink_encode import MavlinkEncoder, encode_mavlink
    from .samples import AttitudeSample, GnssSample, ImuSample, MagSample, Sample, SourceId
    from .sources import DroneCanSource, MavlinkSource
    from .tlog import TlogSource


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    globals()[name] = value  # once loaded, a plain module attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
