"""The outputs for other programs, opened from flags and settings: ROS 2 (``--ros2``), Foxglove live
(``--foxglove [PORT]``) and MAVLink out (``--mavlink-out CONN``), for ``run`` and ``sim``.

:func:`add_options` adds the flags to a subcommand; :func:`open_outputs` opens what they ask for
and hands back its sinks, grouped by the interface each takes (the pipeline's ``EstimateSink`` and
``InputSink``, the simulator's truth sinks, the live runner's status sinks) with a health entry per
output for the status.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from contextlib import ExitStack
from dataclasses import dataclass, field
from typing import Any
from collections.abc import Callable

from drivers.link import check_connection
from fuser import argtypes
from fuser.config import FuserConfig

__all__ = ["Outputs", "add_options", "mavlink_connection", "open_outputs"]

FOXGLOVE_PORT = 8765


def mavlink_connection(text: str) -> str:
    """argparse type of a MAVLink connection string (``--mavlink-out``, and ``run --mavlink``): its form checked
    (:func:`drivers.link.check_connection`), so a malformed one is a usage error before anything opens."""
    try:
        return check_connection(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_options(parser: argparse.ArgumentParser) -> None:
    """``--ros2``, ``--foxglove [PORT]``, ``--mavlink-out CONN``."""
    g = parser.add_argument_group("outputs for other programs", "ROS 2, Foxglove and ground stations (see the README)")
    g.add_argument("--ros2", action="store_true", help="publish sensor_msgs/Imu on /bingham_fuser/attitude and PoseWithCovarianceStamped "
                   "on /bingham_fuser/pose over rmw_zenoh, via the ROS 2 router on tcp/localhost:7447 (settings: [fuser.ros2])")
    g.add_argument("--foxglove", nargs="?", const=FOXGLOVE_PORT, type=argtypes.integer(0, 65535), metavar="PORT",
                   help=f"serve a live Foxglove view on ws://127.0.0.1:PORT (default {FOXGLOVE_PORT})")
    g.add_argument("--mavlink-out", type=mavlink_connection, metavar="CONN", help="send the fused attitude (ATTITUDE_QUATERNION, "
                   "ATTITUDE, 1 Hz HEARTBEAT) to a ground station, e.g. udpout:127.0.0.1:14550 (settings: [fuser.mavlink_out])")


@dataclass
class Outputs:
    """The sinks of the outputs opened, by interface."""

    estimates: list[Callable[..., None]] = field(default_factory=list)
    inputs: list[Callable[..., None]] = field(default_factory=list)
    truth: list[Callable[..., None]] = field(default_factory=list)
    status: list[Callable[..., None]] = field(default_factory=list)
    health: dict[str, Callable[[], dict[str, Any]]] = field(default_factory=dict)

    def health_status(self) -> dict[str, Any]:
        """Each output's counters, for the live status."""
        return {name: f() for name, f in self.health.items()}


def _port(endpoint: str) -> str:
    return endpoint.rsplit(":", 1)[-1]


def open_outputs(stack: ExitStack, config: FuserConfig, args: argparse.Namespace) -> Outputs:
    """Open what ``args`` (flags of :func:`add_options`) and ``config`` ask for, each closed by ``stack``.

    Raises ImportError, with a message naming the extra to install, when a package is missing, and
    :class:`~fuser.errors.FuserError` naming the output when one cannot be opened (``--mavlink-out``).
    """
    out = Outputs()
    if args.ros2 or config.ros2.enabled:
        from fuser.ros2 import Ros2Publisher

        s = config.ros2
        if s.connect_to_router and not getattr(args, "no_zenoh", False) and any(_port(e) == _port(s.router_endpoint) for e in config.zenoh.listen):
            print(f"warning: the fuser's own zenoh peer listens on {', '.join(config.zenoh.listen)}, the ROS 2 router's port "
                  f"({s.router_endpoint}): move it (--zenoh-listen tcp/127.0.0.1:7448) or pass --no-zenoh", file=sys.stderr)
        ros2 = Ros2Publisher(s)
        stack.callback(ros2.close)
        out.estimates.append(ros2.publish_estimate)
        out.inputs.append(ros2.write_sample)
        out.health["ros2"] = lambda: {"published": ros2.published, "errors": ros2.errors}
    if args.foxglove is not None:
        from fuser.foxglove_live import FoxgloveLive

        fox = FoxgloveLive(args.foxglove)
        stack.callback(fox.close)
        if fox.port is not None:  # the port bound: with --foxglove 0, the one the system chose
            print(f"foxglove: live view on ws://127.0.0.1:{fox.port} (Foxglove: Open connection, Foxglove WebSocket)", file=sys.stderr)
        out.estimates.append(fox.write_estimate)
        out.inputs.append(fox.write_sample)
        out.truth.append(fox.write_truth)
        out.status.append(fox.write_status)
        out.health["foxglove"] = lambda: {"subscribed": fox.subscribed_topics(), "errors": fox.errors}
    if args.mavlink_out or config.mavlink_out.connection:
        from fuser.mavlink_out import MavlinkOut

        settings = dataclasses.replace(config.mavlink_out, connection=args.mavlink_out) if args.mavlink_out else config.mavlink_out
        mav = MavlinkOut(settings)
        stack.callback(mav.close)
        out.estimates.append(mav.publish_estimate)
        out.inputs.append(mav.write_sample)
        out.health["mavlink_out"] = lambda: {"sent": mav.sent, "errors": mav.errors, "withheld": mav.withheld}
    return out
