"""ROS 2 output over rmw_zenoh: the fused attitude as ``sensor_msgs/msg/Imu`` and
``geometry_msgs/msg/PoseWithCovarianceStamped``, published through zenoh exactly as a
ROS 2 Jazzy node running ``rmw_zenoh_cpp`` publishes, so that ``ros2 topic echo
/bingham_fuser/attitude`` on a machine with rmw_zenoh sees it. No ROS installation is needed.

Target: ROS 2 Jazzy, ``rmw_zenoh_cpp`` 0.2.4 and later (the release that changed the
attachment to bare fields, ros2/rmw_zenoh#605; Humble's 0.1.2+ and Kilted/Rolling's 0.6+
use the same layout; Jazzy 0.2.0-0.2.3 prefixed each field with its name and is not
supported). Wire format, from rmw_zenoh's ``docs/design.md`` and its sources
(``liveliness_utils.cpp``, ``attachment_helpers.cpp``, ``qos.cpp``) on the ``jazzy`` branch:

* **Data key**: ``<domain_id>/<fully qualified topic without leading slash>/<DDS type
  name>/<type hash>``, e.g. ``0/bingham_fuser/attitude/sensor_msgs::msg::dds_::Imu_/RIHS01_7d9a...``.
* **Payload**: CDR, little-endian, with the 4-byte encapsulation header ``00 01 00 00``
  (rosbags' serializer; the type hashes (REP-2011, RIHS01) are computed by rosbags from
  the Jazzy message definitions).
* **Attachment** (zenoh-ext serialization): ``int64`` sequence number (per publisher,
  from 1), ``int64`` source timestamp (ns since the Unix epoch, the wall clock at publish),
  the 16-byte publisher GID as a sequence (LEB128 length ``0x10``, then 16 bytes): 33 bytes.
* **GID**: XXH3-128 of the publisher's liveliness key expression, low 64 bits then high
  64 bits, little-endian (``Entity::Entity`` in ``liveliness_utils.cpp``).
* **Liveliness tokens** (graph discovery, ``ros2 node list`` / ``ros2 topic list``)::

    @ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>
    @ros2_lv/<domain>/<zid>/<nid>/<eid>/MP/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>

  with ``/`` replaced by ``%`` in enclave, namespace and topic (``%`` alone for the root),
  and the QoS written as its differences from rmw_zenoh's defaults (reliable, volatile,
  keep-last 42, infinite deadline, lifespan and lease): keep-last 10 is ``::,10:,:,:,,``.

Frames follow REP-103: world ENU, body FLU (``fuser.frames``, ``q_enu_flu = Q_ENU_NED (x)
q_ned_frd (x) Q_FRD_FLU``); the orientation covariance is the Bingham's, about the world
(fixed) axes. Header stamps are the estimate's time as it is: Unix time live (the loop's
tick time), the log's own time in a replay or simulation.

Never raises into the loop: failures are counted in ``errors`` and the first is logged once.
"""

from __future__ import annotations

import json
import logging
import re
import struct
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.samples import ImuSample, Sample, SourceId
from fuser.codec import Estimate
from fuser.frames import enu_flu_from_ned_frd, flu_from_frd, orientation_covariance_enu

__all__ = [
    "IMU_TYPE",
    "POSE_TYPE",
    "QOS_KEEP_LAST_10",
    "Ros2Publisher",
    "Ros2Settings",
    "data_key",
    "dds_type_name",
    "mangle",
    "resolve_topic",
]

log = logging.getLogger(__name__)

IMU_TYPE = "sensor_msgs/msg/Imu"
POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
QOS_KEEP_LAST_10 = "::,10:,:,:,,"
"""rmw_zenoh's ``qos_to_keyexpr`` of a reliable, volatile, keep-last-10 publisher (rclcpp's ``QoS(10)``)."""
UNKNOWN_POSITION_VARIANCE_M2 = 1e6
"""The pose's position is not estimated: published at the origin with this variance (effectively ignored)."""
ROUTER_RETRY_S = 5.0
"""Without a reachable router the session is opened again at most this often."""

_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_ADMIN_SPACE = "@ros2_lv"


def _check_name(value: str, key: str, allow_private: bool = False) -> None:
    """ROS 2 name rules (design article "Topic and Service name mapping"): tokens of letters, digits
    and underscores, not starting with a digit, no empty token, no ``__``; ``~`` only as a prefix."""
    body = value[1:] if value.startswith("/") else value[2:] if allow_private and value.startswith("~/") else value
    if value == "/" and not allow_private:
        return
    tokens = body.split("/")
    if not body or any(not _TOKEN.fullmatch(t) or "__" in t for t in tokens):
        raise ValueError(f"ros2.{key}: {value!r} is not a valid ROS 2 name (tokens of letters, digits and '_', "
                         "not starting with a digit, separated by single '/')")


@dataclass(frozen=True)
class Ros2Settings:
    """ROS 2 output (``[fuser.ros2]``; ``--ros2`` switches it on)."""

    enabled: bool = False
    """Publish to ROS 2 (also ``--ros2``)."""
    domain_id: int = 0
    """``ROS_DOMAIN_ID`` of the ROS 2 graph (0-232)."""
    namespace: str = "/"
    """Node namespace, absolute (``/`` or e.g. ``/drone1``)."""
    node_name: str = "bingham_fuser"
    imu_topic: str = "~/attitude"
    """``sensor_msgs/msg/Imu`` topic; ``~`` is the node (``/bingham_fuser/attitude`` by default), a
    relative name is resolved in the namespace."""
    pose_topic: str = "~/pose"
    """``geometry_msgs/msg/PoseWithCovarianceStamped`` topic; empty to publish none."""
    body_frame_id: str = "base_link"
    """``frame_id`` of the Imu message: the vehicle's body frame (FLU)."""
    world_frame_id: str = "world"
    """``frame_id`` of the pose: the world frame (ENU) the orientation is relative to."""
    connect_to_router: bool = True
    """Connect to a ROS 2 zenoh router (``ros2 run rmw_zenoh_cpp rmw_zenohd``) as a client, never
    listening on its port; False: a peer listening on ``listen`` (no router, direct peers only)."""
    router_endpoint: str = "tcp/localhost:7447"
    """Where the router listens (rmw_zenoh's default)."""
    listen: tuple[str, ...] = ()
    """Peer mode only: endpoints to listen on."""

    def __post_init__(self) -> None:
        if not isinstance(self.domain_id, int) or isinstance(self.domain_id, bool) or not 0 <= self.domain_id <= 232:
            raise ValueError(f"ros2.domain_id: must be an integer in 0..232, got {self.domain_id!r}")
        if not self.namespace.startswith("/") or (self.namespace != "/" and self.namespace.endswith("/")):
            raise ValueError(f"ros2.namespace: must be absolute, e.g. '/' or '/drone1', got {self.namespace!r}")
        _check_name(self.namespace, "namespace")
        if not _TOKEN.fullmatch(self.node_name):
            raise ValueError(f"ros2.node_name: {self.node_name!r} is not a valid node name (letters, digits, '_')")
        _check_name(self.imu_topic, "imu_topic", allow_private=True)
        if self.pose_topic:
            _check_name(self.pose_topic, "pose_topic", allow_private=True)
        for key in ("body_frame_id", "world_frame_id"):
            if not getattr(self, key):
                raise ValueError(f"ros2.{key}: must not be empty")
        if not self.router_endpoint:
            raise ValueError("ros2.router_endpoint: must not be empty")
        if not self.connect_to_router and not self.listen:
            raise ValueError("ros2.listen: give at least one endpoint when connect_to_router is false")


def resolve_topic(name: str, namespace: str, node_name: str) -> str:
    """The fully qualified name: ``~/x`` -> ``<ns>/<node>/x``, ``x`` -> ``<ns>/x``, ``/x`` unchanged."""
    base = "" if namespace == "/" else namespace
    if name.startswith("/"):
        return name
    if name.startswith("~/"):
        return f"{base}/{node_name}/{name[2:]}"
    return f"{base}/{name}"


def dds_type_name(ros_type: str) -> str:
    """``sensor_msgs/msg/Imu`` -> ``sensor_msgs::msg::dds_::Imu_`` (rosidl's DDS naming)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    """rmw_zenoh's ``mangle_name``: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def data_key(domain_id: int, fq_topic: str, ros_type: str, type_hash: str) -> str:
    """``<domain_id>/<fully qualified topic without leading slash>/<DDS type name>/<type hash>``."""
    return f"{domain_id}/{fq_topic.lstrip('/')}/{dds_type_name(ros_type)}/{type_hash}"


def _zenoh_config(s: Ros2Settings):
    import zenoh

    scouting = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
    if s.connect_to_router:
        conf: dict[str, Any] = {"mode": "client", "connect": {"endpoints": [s.router_endpoint]}, "scouting": scouting}
    else:
        conf = {"mode": "peer", "listen": {"endpoints": list(s.listen)}, "scouting": scouting}
    return zenoh.Config.from_json5(json.dumps(conf))


def _missing(module: str) -> ImportError:
    return ImportError(f"--ros2 needs the '{module}' package: pip install 'bingham-fuser[ros2]'")


class _Topic:
    """One ROS 2 publisher: its key, liveliness token, GID and sequence counter."""

    def __init__(self, session: Any, settings: Ros2Settings, zid: str, entity_id: int, fq_topic: str, ros_type: str,
                 type_hash: str) -> None:
        import xxhash
        import zenoh

        self.key = data_key(settings.domain_id, fq_topic, ros_type, type_hash)
        self.token_key = "/".join([
            _ADMIN_SPACE, str(settings.domain_id), zid, "0", str(entity_id), "MP", "%", mangle(settings.namespace),
            settings.node_name, mangle(fq_topic), dds_type_name(ros_type), type_hash, QOS_KEEP_LAST_10,
        ])
        digest = xxhash.xxh3_128_intdigest(self.token_key.encode())
        self.gid = struct.pack("<QQ", digest & 0xFFFF_FFFF_FFFF_FFFF, digest >> 64)
        self.sequence = 0
        self.publisher = session.declare_publisher(self.key, congestion_control=zenoh.CongestionControl.DROP, express=True)
        self.token = session.liveliness().declare_token(self.token_key)

    def put(self, payload: bytes) -> None:
        from zenoh.ext import Int64, z_serialize

        self.sequence += 1
        attachment = z_serialize((Int64(self.sequence), Int64(time.time_ns()), self.gid))
        self.publisher.put(payload, attachment=attachment)


class Ros2Publisher:
    """Publish estimates as ROS 2 messages over rmw_zenoh; ``write_sample`` keeps the latest IMU sample.

    Counts ``published`` messages and ``errors`` (the first one logged once); never raises.
    """

    def __init__(self, settings: Ros2Settings, zenoh_config: Any = None) -> None:
        try:
            import xxhash  # noqa: F401
            from rosbags.typesys import Stores, get_typestore
        except ImportError as exc:
            raise _missing((exc.name or "rosbags").split(".")[0]) from exc
        self.settings = settings
        self.published = 0
        self.errors = 0
        self.error: str | None = None
        self._config = zenoh_config
        self._store = get_typestore(Stores.ROS2_JAZZY)
        self._types = self._store.types
        self.imu_topic = resolve_topic(settings.imu_topic, settings.namespace, settings.node_name)
        self.pose_topic = resolve_topic(settings.pose_topic, settings.namespace, settings.node_name) if settings.pose_topic else None
        self.type_hashes = {t: self._store.hash_rihs01(t) for t in (IMU_TYPE, POSE_TYPE)}
        self._imu_source: SourceId | None = None
        self._imu: ImuSample | None = None
        self._session: Any = None
        self._topics: dict[str, _Topic] = {}
        self._node_token: Any = None
        self.zid: str | None = None
        self.node_token_key: str | None = None
        self._next_open_s = 0.0
        self._open()

    # -- session ----------------------------------------------------------------
    def _open(self) -> None:
        import zenoh

        self._next_open_s = time.monotonic() + ROUTER_RETRY_S
        try:
            session = zenoh.open(self._config if self._config is not None else _zenoh_config(self.settings))
        except zenoh.ZError as e:
            where = self.settings.router_endpoint if self.settings.connect_to_router else ", ".join(self.settings.listen)
            self._fail(f"cannot open the zenoh session ({where}); is a ROS 2 router running "
                       f"(ros2 run rmw_zenoh_cpp rmw_zenohd)? retrying every {ROUTER_RETRY_S:g} s: {e}")
            return
        try:
            s = self.settings
            self.zid = str(session.zid())
            self.node_token_key = "/".join([_ADMIN_SPACE, str(s.domain_id), self.zid, "0", "0", "NN", "%", mangle(s.namespace), s.node_name])
            self._node_token = session.liveliness().declare_token(self.node_token_key)
            topics = [(self.imu_topic, IMU_TYPE)] + ([(self.pose_topic, POSE_TYPE)] if self.pose_topic else [])
            self._topics = {ros_type: _Topic(session, s, self.zid, 10 + i, topic, ros_type, self.type_hashes[ros_type])
                            for i, (topic, ros_type) in enumerate(topics)}
        except zenoh.ZError as e:
            self._fail(f"cannot declare the ROS 2 publishers: {e}")
            session.close()
            self._topics = {}
            return
        self._session = session

    def _fail(self, message: str) -> None:
        self.errors += 1
        if self.error is None:
            self.error = message
            log.error("ros2: %s", message)

    # -- sinks ------------------------------------------------------------------
    def write_sample(self, sample: Sample, receive_ns: int) -> None:  # noqa: ARG002 - an InputSink
        """Keep the latest sample of the first IMU that delivered (angular velocity, acceleration)."""
        if isinstance(sample, ImuSample):
            if self._imu_source is None:
                self._imu_source = sample.source
            if sample.source == self._imu_source:
                self._imu = sample

    def publish_estimate(self, est: Estimate) -> None:
        """Publish one estimate on every topic (an EstimateSink)."""
        if self._session is None:
            self.errors += 1
            if time.monotonic() >= self._next_open_s:
                self._open()
            if self._session is None:
                return
        try:
            messages = self.messages(est)
        except ValueError as e:  # an estimate the covariance cannot be computed for (never expected)
            self._fail(f"cannot convert estimate at t_ns={est.t_ns}: {e}")
            return
        for ros_type, msg in messages.items():
            topic = self._topics.get(ros_type)
            if topic is None:
                continue
            try:
                topic.put(bytes(self._store.serialize_cdr(msg, ros_type)))
                self.published += 1
            except Exception as e:  # noqa: BLE001 - zenoh or serializer failure: count it, keep the loop going
                self._fail(f"put on {topic.key} failed: {e}")

    def messages(self, est: Estimate) -> dict[str, Any]:
        """The rosbags message objects for one estimate (REP-103 frames)."""
        t = self._types
        sec, nanosec = divmod(est.t_ns, 1_000_000_000)
        stamp = t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        x_w, x_x, x_y, x_z = enu_flu_from_ned_frd(est.q_wxyz)
        orientation = t["geometry_msgs/msg/Quaternion"](x=x_x, y=x_y, z=x_z, w=x_w)
        cov = orientation_covariance_enu(est.M, est.Z, est.q_wxyz)
        vec3 = t["geometry_msgs/msg/Vector3"]
        no_estimate = np.zeros(9)
        no_estimate[0] = -1.0  # sensor_msgs/Imu: element 0 = -1 means "no estimate"
        unknown = np.zeros(9)  # all zeros means "covariance unknown"
        if self._imu is None:
            gyro, accel, gyro_cov, accel_cov = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), no_estimate, no_estimate
        else:
            gyro, accel = flu_from_frd(self._imu.gyro_rad_s), flu_from_frd(self._imu.accel_m_s2)
            gyro_cov, accel_cov = unknown, unknown
        header = t["std_msgs/msg/Header"]
        out: dict[str, Any] = {
            IMU_TYPE: t[IMU_TYPE](
                header=header(stamp=stamp, frame_id=self.settings.body_frame_id),
                orientation=orientation,
                orientation_covariance=cov.reshape(9),
                angular_velocity=vec3(x=gyro[0], y=gyro[1], z=gyro[2]),
                angular_velocity_covariance=gyro_cov,
                linear_acceleration=vec3(x=accel[0], y=accel[1], z=accel[2]),
                linear_acceleration_covariance=accel_cov,
            )
        }
        if self.pose_topic:
            pose_cov = np.zeros((6, 6))
            pose_cov[:3, :3] = np.eye(3) * UNKNOWN_POSITION_VARIANCE_M2
            pose_cov[3:, 3:] = cov
            point = t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0)
            out[POSE_TYPE] = t[POSE_TYPE](
                header=header(stamp=stamp, frame_id=self.settings.world_frame_id),
                pose=t["geometry_msgs/msg/PoseWithCovariance"](
                    pose=t["geometry_msgs/msg/Pose"](position=point, orientation=orientation),
                    covariance=pose_cov.reshape(36),
                ),
            )
        return out

    @property
    def keys(self) -> dict[str, str]:
        """ROS type -> data key expression."""
        return {ros_type: topic.key for ros_type, topic in self._topics.items()}

    def close(self) -> None:
        if self._session is not None:
            session, self._session = self._session, None
            self._topics = {}
            try:
                session.close()
            except Exception as e:  # noqa: BLE001
                self._fail(f"close failed: {e}")
